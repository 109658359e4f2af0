"""NatNet message framing and the command channel: message ids, versions, requests, server info.

Every datagram starts with ``uint16 message_id, uint16 payload_size`` (little-endian). A client sends
``NAT_CONNECT`` to the server's command port and gets ``NAT_SERVERINFO`` back; the layouts follow the NatNet
SDK (``NatNetClient.py``'s ``send_request``, ``NatNetTypes.h``'s ``sSender_Server``).
"""

from __future__ import annotations

import enum
import struct
from dataclasses import dataclass

from drivers.errors import ProtocolError
from drivers.natnet.reader import DEVICE, Reader

HEADER = struct.Struct("<HH")
_SERVER_NAME_SIZE = 256
_SERVER_INFO = struct.Struct(f"<{_SERVER_NAME_SIZE}s4B4B")  # name, app version, NatNet version
_CONNECTION_INFO = struct.Struct("<QH?4B")  # clock frequency [Hz], data port, multicast, group


class MessageId(enum.IntEnum):
    """NatNet message ids (first two bytes of every datagram)."""

    CONNECT = 0
    SERVER_INFO = 1
    REQUEST = 2
    RESPONSE = 3
    REQUEST_MODEL_DEF = 4
    MODEL_DEF = 5
    REQUEST_FRAME_OF_DATA = 6
    FRAME_OF_DATA = 7
    MESSAGE_STRING = 8
    DISCONNECT = 9
    KEEP_ALIVE = 10
    UNRECOGNIZED_REQUEST = 100


def has_byte_counts(version: tuple[int, int]) -> bool:
    """True when each frame section carries an ``int32`` byte count (NatNet 4.1 and later)."""
    return version >= (4, 1)


def has_precision_timestamp(version: tuple[int, int]) -> bool:
    """True when the frame suffix carries the precision timestamp (NatNet 4.1 and later)."""
    return version >= (4, 1)


def check_version(version: tuple[int, int]) -> tuple[int, int]:
    """Validate a (major, minor) NatNet stream version; raises ProtocolError below 3.0."""
    if len(version) != 2 or version < (3, 0) or version[0] > 4:
        raise ProtocolError(DEVICE, f"unsupported NatNet version {version}; supported: 3.0 to 4.x")
    return (int(version[0]), int(version[1]))


@dataclass(frozen=True)
class ServerInfo:
    """Reply to ``NAT_CONNECT``.

    The first 264 bytes (name, app version, NatNet version) are what ``NatNetClient.py`` reads; the
    connection info after them is ``sSender_Server`` of the SDK's ``NatNetTypes.h`` (packed: ``uint64``
    high-resolution clock frequency, ``uint16`` data port, ``bool`` multicast, 4 bytes of group address).

    Attributes:
        app_name: server application name (``Motive``).
        app_version: application version, 4 numbers.
        natnet_version: NatNet stream version, 4 numbers.
        clock_frequency_hz: tick rate of the camera timestamps [Hz], 0 when not sent.
        data_port: UDP data port announced by the server, 0 when not sent.
        multicast: whether the server streams to a multicast group.
        multicast_group: the group address (dotted quad), ``""`` when not sent.
    """

    app_name: str
    app_version: tuple[int, int, int, int]
    natnet_version: tuple[int, int, int, int]
    clock_frequency_hz: int = 0
    data_port: int = 0
    multicast: bool = False
    multicast_group: str = ""


def parse_server_info(payload: bytes | memoryview) -> ServerInfo:
    """Parse the payload of a ``NAT_SERVERINFO`` packet (the reply to ``NAT_CONNECT``).

    Raises:
        ProtocolError: the payload is shorter than the 264-byte fixed part.
    """
    r = Reader(payload)
    name, *versions = r.unpack(_SERVER_INFO, "server info")
    app_name = name.split(b"\0", 1)[0].decode("utf-8", errors="replace")
    info = dict(app_name=app_name, app_version=tuple(versions[:4]), natnet_version=tuple(versions[4:]))
    if len(r.data) - r.offset >= _CONNECTION_INFO.size:
        freq, port, multicast, *group = r.unpack(_CONNECTION_INFO, "connection info")
        info.update(clock_frequency_hz=freq, data_port=port, multicast=multicast,
                    multicast_group=".".join(map(str, group)))
    return ServerInfo(**info)


def split_packet(packet: bytes | memoryview) -> tuple[int, memoryview]:
    """Split a datagram into (message id, payload), checking the declared payload size.

    Raises:
        ProtocolError: shorter than the header or than the declared payload size.
    """
    view = memoryview(packet)
    if len(view) < HEADER.size:
        raise ProtocolError(DEVICE, f"packet of {len(view)} bytes is shorter than the 4-byte header")
    message_id, size = HEADER.unpack(view[:HEADER.size])
    payload = view[HEADER.size:]
    if len(payload) < size:
        raise ProtocolError(DEVICE, f"truncated packet: header declares {size} payload bytes, got {len(payload)}")
    return message_id, payload[:size]


def build_request(message_id: MessageId, body: bytes = b"") -> bytes:
    """Frame a client request as the SDK's ``send_request`` does: header, body, then one NUL byte.

    A command string (``NAT_REQUEST``) declares its length plus the NUL; an empty body
    (``NAT_REQUEST_MODELDEF``, ``NAT_KEEPALIVE``) declares 0 payload bytes yet still sends the NUL.
    """
    size = len(body) + 1 if body else 0
    return HEADER.pack(int(message_id), size) + body + b"\0"


_CONNECT_BODY_SIZE = 270  # "Ping", zeros, version bytes at 265..268, one more zero
_CONNECT_VERSION_AT = 265


def build_connect(version: tuple[int, int] = (4, 1)) -> bytes:
    """A ``NAT_CONNECT`` request laid out as the NatNet 4.1 SDK builds it.

    The body is 270 bytes: ``Ping`` at 0..3, zeros, the requested NatNet version (major, minor, 0, 0) at
    bytes 265..268, a zero; the SDK then appends a NUL and declares all 271 bytes as the payload size.
    """
    body = bytearray(_CONNECT_BODY_SIZE)
    body[0:4] = b"Ping"
    body[_CONNECT_VERSION_AT:_CONNECT_VERSION_AT + 4] = bytes([version[0], version[1], 0, 0])
    body += b"\0"
    return HEADER.pack(int(MessageId.CONNECT), len(body)) + bytes(body)
