"""Cut a TCP byte stream into simple_message packets.

TCP delivers bytes, not packets: a ``recv`` may return half a length prefix or three packets at once. The
framer buffers what it is fed and hands back only whole packets. A length prefix outside
``[HEADER_BYTES, max_length]`` means the stream is corrupt or out of step; there is no way to resynchronise
a length-prefixed stream, so the framer raises ProtocolError and the caller drops the connection.
"""

from __future__ import annotations

import socket
import struct

from drivers.errors import DriverDisconnected, InvalidArgument, ProtocolError
from drivers.motoros.codec import Packet

HEADER_BYTES = 12
# The largest MotoROS packet (JointFeedbackEx) is 544 bytes after the prefix; leave room, reject the absurd.
DEFAULT_MAX_LENGTH = 4096
_PREFIX = struct.Struct("<i")


class Framer:
    """Incremental splitter of a simple_message byte stream.

    Args:
        device: name used in error messages (``motoros@10.0.0.2:50241``).
        max_length: largest accepted length prefix [bytes].
    """

    def __init__(self, device: str, max_length: int = DEFAULT_MAX_LENGTH) -> None:
        if max_length < HEADER_BYTES:
            raise InvalidArgument(device, "max_length", max_length, f">= {HEADER_BYTES} [bytes]")
        self.device = device
        self.max_length = max_length
        self._buffer = bytearray()

    @property
    def pending(self) -> int:
        """Bytes buffered that do not yet form a whole packet."""
        return len(self._buffer)

    def feed(self, data: bytes) -> list[Packet]:
        """Append ``data`` and return every packet now complete, in order.

        Raises:
            ProtocolError: a length prefix is negative, shorter than a header or above ``max_length``.
        """
        self._buffer.extend(data)
        packets: list[Packet] = []
        while len(self._buffer) >= _PREFIX.size:
            (length,) = _PREFIX.unpack_from(self._buffer)
            if not HEADER_BYTES <= length <= self.max_length:
                self._buffer.clear()
                raise ProtocolError(self.device, f"length prefix {length} outside "
                                                 f"[{HEADER_BYTES}, {self.max_length}]; stream is corrupt")
            end = _PREFIX.size + length
            if len(self._buffer) < end:
                break
            packets.append(Packet.from_frame(bytes(self._buffer[_PREFIX.size:end])))
            del self._buffer[:end]
        return packets


def recv_into_framer(sock: socket.socket, framer: Framer, bufsize: int = 4096) -> list[Packet]:
    """One ``recv`` fed to ``framer``; the packets it completed (possibly none).

    Raises:
        DriverDisconnected: the peer closed the connection or the socket failed.
        TimeoutError: the socket's own timeout expired (left to the caller, who knows the deadline).
        ProtocolError: the bytes do not frame.
    """
    try:
        data = sock.recv(bufsize)
    except TimeoutError:
        raise
    except OSError as e:
        raise DriverDisconnected(framer.device, f"receive failed: {e}") from e
    if not data:
        raise DriverDisconnected(framer.device, "peer closed the connection")
    return framer.feed(data)
