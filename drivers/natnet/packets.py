"""NatNet wire format: pure functions that turn UDP datagrams into typed frames.

Every datagram starts with ``uint16 message_id, uint16 payload_size`` (little-endian). A frame of data
(``NAT_FRAMEOFDATA``) then holds, in order: frame number, marker sets, unlabeled markers, rigid bodies,
skeletons, assets (4.1+), labeled markers, force plates, devices and the frame suffix (timecode,
timestamp, camera timestamps, parameters). From NatNet 4.1 every section count is followed by an
``int32`` byte count of that section. Rigid bodies carry no per-marker data from NatNet 3.0 on, which is
the oldest layout parsed here.

NatNet streams metres and quaternions ordered (x, y, z, w); the parser converts to millimetres and
(w, x, y, z) so the rest of cellcal never sees the wire conventions. Any short or inconsistent packet
raises :class:`~drivers.errors.ProtocolError`; nothing is returned half-parsed.
"""

from __future__ import annotations

import enum
import struct
from dataclasses import dataclass

import numpy as np

from drivers.base import RigidBodyFrame
from drivers.errors import ProtocolError

DEVICE = "natnet"
M_TO_MM = 1000.0
TRACKING_VALID = 0x01
HEADER = struct.Struct("<HH")
_RIGID_BODY = struct.Struct("<i3f4ffh")  # id, position [m], quaternion xyzw, mean error [m], params
_LABELED_MARKER_SIZE = 4 + 12 + 4 + 2 + 4  # id, position, size, params, residual
_SERVER_NAME_SIZE = 256
_I32 = struct.Struct("<i")
_SUFFIX = struct.Struct("<IId")  # timecode, timecode sub-frame, timestamp [s]
_STAMPS = struct.Struct("<3Q")  # mid-exposure, data received, transmit [clock ticks]
_PARAMS = struct.Struct("<h")
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


def check_version(version: tuple[int, int]) -> tuple[int, int]:
    """Validate a (major, minor) NatNet stream version; raises ProtocolError below 3.0."""
    if len(version) != 2 or version < (3, 0) or version[0] > 4:
        raise ProtocolError(DEVICE, f"unsupported NatNet version {version}; supported: 3.0 to 4.x")
    return (int(version[0]), int(version[1]))


@dataclass(frozen=True)
class ServerInfo:
    """Reply to ``NAT_CONNECT``.

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


@dataclass(frozen=True)
class MocapFrame:
    """One parsed ``NAT_FRAMEOFDATA`` packet.

    Attributes:
        frame_number: the server's frame counter.
        rigid_bodies: one RigidBodyFrame per streamed rigid body (mm, wxyz, capture_time = timestamp).
        marker_sets: (name, positions [mm] shape (N, 3)) per marker set.
        unlabeled_markers_mm: positions [mm], shape (N, 3).
        skeleton_count: number of skeletons (their bones are not exposed).
        labeled_marker_count: number of labeled markers.
        timecode: SMPTE timecode word.
        timecode_sub: timecode sub-frame.
        timestamp: server time of the frame [s].
        stamp_camera_mid_exposure: camera mid-exposure time [clock ticks].
        stamp_data_received: time the server received the camera data [clock ticks].
        stamp_transmit: time the server sent the packet [clock ticks].
        params: frame flags (0x01 recording, 0x02 tracked models changed).
    """

    frame_number: int
    rigid_bodies: tuple[RigidBodyFrame, ...]
    marker_sets: tuple[tuple[str, np.ndarray], ...]
    unlabeled_markers_mm: np.ndarray
    skeleton_count: int
    labeled_marker_count: int
    timecode: int
    timecode_sub: int
    timestamp: float
    stamp_camera_mid_exposure: int
    stamp_data_received: int
    stamp_transmit: int
    params: int


class _Reader:
    """Bounds-checked little-endian cursor over a payload; every short read raises ProtocolError."""

    def __init__(self, data: bytes | memoryview) -> None:
        self.data = memoryview(data)
        self.offset = 0

    def take(self, n: int, what: str) -> memoryview:
        if n < 0 or self.offset + n > len(self.data):
            raise ProtocolError(DEVICE, f"truncated packet: {what} needs {n} bytes at offset {self.offset}, "
                                        f"{len(self.data) - self.offset} left")
        chunk = self.data[self.offset:self.offset + n]
        self.offset += n
        return chunk

    def unpack(self, fmt: struct.Struct, what: str) -> tuple:
        return fmt.unpack(self.take(fmt.size, what))

    def count(self, what: str, min_item_size: int) -> int:
        (n,) = self.unpack(_I32, what)
        if n < 0 or n * min_item_size > len(self.data) - self.offset:
            raise ProtocolError(DEVICE, f"bad {what} {n} at offset {self.offset - 4}")
        return n

    def cstring(self, what: str) -> str:
        end = bytes(self.data[self.offset:]).find(b"\0")
        if end < 0:
            raise ProtocolError(DEVICE, f"truncated packet: unterminated {what} at offset {self.offset}")
        raw = bytes(self.take(end + 1, what)[:-1])
        return raw.decode("utf-8", errors="replace")


class _Section:
    """Reads a section header (count, then the 4.1+ byte count) and checks the byte count on exit."""

    def __init__(self, r: _Reader, version: tuple[int, int], what: str, min_item_size: int) -> None:
        self.r, self.what = r, what
        self.n = r.count(f"{what} count", min_item_size)
        self.size = r.count(f"{what} byte count", 1) if has_byte_counts(version) else None
        self.start = r.offset

    def skip(self) -> None:
        if self.size is None:
            raise ProtocolError(DEVICE, f"cannot skip {self.what} without a byte count")
        self.r.take(self.size, self.what)

    def close(self) -> None:
        if self.size is not None and self.r.offset - self.start != self.size:
            raise ProtocolError(DEVICE, f"{self.what} byte count says {self.size}, "
                                        f"parsed {self.r.offset - self.start}")


def _rigid_body(r: _Reader) -> tuple[int, np.ndarray, np.ndarray, float, int]:
    body_id, px, py, pz, qx, qy, qz, qw, err, params = r.unpack(_RIGID_BODY, "rigid body")
    return body_id, np.array([px, py, pz]) * M_TO_MM, np.array([qw, qx, qy, qz]), err * M_TO_MM, params


def _markers(r: _Reader, n: int, what: str) -> np.ndarray:
    raw = r.take(12 * n, what)
    return np.frombuffer(raw, dtype="<f4").reshape(n, 3).astype(float) * M_TO_MM


def parse_frame(payload: bytes | memoryview, version: tuple[int, int]) -> MocapFrame:
    """Parse the payload (after the 4-byte header) of a ``NAT_FRAMEOFDATA`` packet.

    Args:
        payload: packet bytes after the header.
        version: NatNet stream (major, minor), at least (3, 0).

    Returns:
        The frame; rigid-body capture_time is the frame timestamp [s].

    Raises:
        ProtocolError: the payload is truncated or its counts are inconsistent.
    """
    version = check_version(version)
    r = _Reader(payload)
    (frame_number,) = r.unpack(_I32, "frame number")

    s = _Section(r, version, "marker set", 5)
    marker_sets = []
    for _ in range(s.n):
        name = r.cstring("marker set name")
        marker_sets.append((name, _markers(r, r.count("marker count", 12), "marker set")))
    s.close()

    s = _Section(r, version, "unlabeled marker", 12)
    unlabeled = _markers(r, s.n, "unlabeled markers")
    s.close()

    s = _Section(r, version, "rigid body", _RIGID_BODY.size)
    bodies = [_rigid_body(r) for _ in range(s.n)]
    s.close()

    s = _Section(r, version, "skeleton", 8)
    skeleton_count = s.n
    for _ in range(s.n):
        r.take(4, "skeleton id")
        for _ in range(r.count("skeleton bone count", _RIGID_BODY.size)):
            _rigid_body(r)
    s.close()

    if has_byte_counts(version):
        s = _Section(r, version, "asset", 1)
        s.skip()

    s = _Section(r, version, "labeled marker", _LABELED_MARKER_SIZE)
    r.take(_LABELED_MARKER_SIZE * s.n, "labeled markers")
    labeled_count = s.n
    s.close()

    for what in ("force plate", "device"):
        s = _Section(r, version, what, 8)
        for _ in range(s.n):
            r.take(4, f"{what} id")
            for _ in range(r.count(f"{what} channel count", 4)):
                r.take(4 * r.count(f"{what} channel frame count", 4), f"{what} channel data")
        s.close()

    timecode, timecode_sub, timestamp = r.unpack(_SUFFIX, "frame suffix")
    stamps = r.unpack(_STAMPS, "camera timestamps")
    if version[0] >= 4:
        r.take(8, "precision timestamp")
    (params,) = r.unpack(_PARAMS, "frame params")

    rigid_bodies = tuple(
        RigidBodyFrame(body_id=i, position_mm=p, quat_wxyz=q, marker_error_mm=e,
                       tracking_valid=bool(f & TRACKING_VALID), capture_time=timestamp,
                       frame_number=frame_number)
        for i, p, q, e, f in bodies
    )
    return MocapFrame(frame_number, rigid_bodies, tuple(marker_sets), unlabeled, skeleton_count,
                      labeled_count, timecode, timecode_sub, timestamp, *stamps, params)


def parse_server_info(payload: bytes | memoryview) -> ServerInfo:
    """Parse the payload of a ``NAT_SERVERINFO`` packet (the reply to ``NAT_CONNECT``).

    Raises:
        ProtocolError: the payload is shorter than the 264-byte fixed part.
    """
    r = _Reader(payload)
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
    """Frame a client request: header plus body."""
    return HEADER.pack(int(message_id), len(body)) + body


def build_connect(version: tuple[int, int] = (4, 1)) -> bytes:
    """A ``NAT_CONNECT`` request: client name ``Ping`` padded to 256 bytes, app and NatNet versions."""
    body = struct.pack(f"<{_SERVER_NAME_SIZE}s4B4B", b"Ping", 0, 0, 0, 0, version[0], version[1], 0, 0)
    return build_request(MessageId.CONNECT, body)
