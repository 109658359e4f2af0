"""A fake NatNet server (Motive stand-in) that speaks the wire protocol on loopback.

It builds frame packets field by field for NatNet 3.x and 4.x, answers ``NAT_CONNECT`` with a
``NAT_SERVERINFO`` packet and streams frames to the clients that connected (unicast, to their command
socket) or to any address given. It can also send truncated or garbage datagrams to exercise error paths.
The encoders here are written independently of :mod:`drivers.natnet.packets` so tests compare two
implementations of the layout rather than one with itself.
"""

from __future__ import annotations

import logging
import socket
import struct
import threading
from dataclasses import dataclass

from drivers.natnet.packets import MessageId

log = logging.getLogger("cellcal.drivers")


@dataclass(frozen=True)
class FakeBody:
    """A rigid body as Motive streams it (wire units).

    Attributes:
        body_id: rigid-body id.
        position_m: position [m], 3 numbers.
        quat_xyzw: unit quaternion in NatNet order (x, y, z, w).
        error_m: mean marker error [m].
        tracking_valid: sets bit 0x01 of the params word.
    """

    body_id: int
    position_m: tuple[float, float, float]
    quat_xyzw: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)
    error_m: float = 0.0002
    tracking_valid: bool = True


@dataclass(frozen=True)
class FakeFrame:
    """Everything a frame packet carries; optional sections default to empty."""

    frame_number: int
    bodies: tuple[FakeBody, ...]
    timestamp: float = 0.0
    marker_sets: tuple[tuple[str, tuple[tuple[float, float, float], ...]], ...] = ()
    unlabeled_m: tuple[tuple[float, float, float], ...] = ()
    skeletons: tuple[tuple[int, tuple[FakeBody, ...]], ...] = ()
    labeled_marker_count: int = 0
    stamps: tuple[int, int, int] = (0, 0, 0)
    timecode: tuple[int, int] = (0, 0)
    params: int = 0
    force_plates: tuple[tuple[int, tuple[tuple[float, ...], ...]], ...] = ()


def _body(b: FakeBody) -> bytes:
    params = 0x01 if b.tracking_valid else 0x00
    return (struct.pack("<i", b.body_id) + struct.pack("<3f", *b.position_m)
            + struct.pack("<4f", *b.quat_xyzw) + struct.pack("<f", b.error_m) + struct.pack("<h", params))


def _section(count: int, body: bytes, version: tuple[int, int]) -> bytes:
    head = struct.pack("<i", count)
    if version >= (4, 1):
        head += struct.pack("<i", len(body))
    return head + body


def encode_frame(frame: FakeFrame, version: tuple[int, int]) -> bytes:
    """A complete ``NAT_FRAMEOFDATA`` datagram (header included) for NatNet ``version`` >= (3, 0)."""
    out = struct.pack("<i", frame.frame_number)
    sets = b"".join(name.encode() + b"\0" + struct.pack("<i", len(pts)) + b"".join(struct.pack("<3f", *p) for p in pts)
                    for name, pts in frame.marker_sets)
    out += _section(len(frame.marker_sets), sets, version)
    out += _section(len(frame.unlabeled_m), b"".join(struct.pack("<3f", *p) for p in frame.unlabeled_m), version)
    out += _section(len(frame.bodies), b"".join(_body(b) for b in frame.bodies), version)
    skels = b"".join(struct.pack("<ii", sid, len(bones)) + b"".join(_body(b) for b in bones)
                     for sid, bones in frame.skeletons)
    out += _section(len(frame.skeletons), skels, version)
    if version >= (4, 1):
        out += _section(1, struct.pack("<iii", 7, 0, 0), version)  # one asset: id 7, no bodies, no markers
    labeled = b"".join(struct.pack("<i3ffhf", (1 << 16) | i, 0.1 * i, 0.0, 0.0, 0.014, 0, 0.0001)
                       for i in range(frame.labeled_marker_count))
    out += _section(frame.labeled_marker_count, labeled, version)
    plates = b"".join(struct.pack("<ii", pid, len(chans))
                      + b"".join(struct.pack(f"<i{len(c)}f", len(c), *c) for c in chans)
                      for pid, chans in frame.force_plates)
    out += _section(len(frame.force_plates), plates, version)
    out += _section(0, b"", version)  # devices
    out += struct.pack("<II", *frame.timecode) + struct.pack("<d", frame.timestamp)
    out += struct.pack("<QQQ", *frame.stamps)
    if version[0] >= 4:
        out += struct.pack("<II", int(frame.timestamp), 0)  # precision timestamp, seconds and fraction
    out += struct.pack("<h", frame.params) + struct.pack("<i", 0)  # params, end-of-data tag
    return struct.pack("<HH", MessageId.FRAME_OF_DATA, len(out)) + out


def encode_server_info(version: tuple[int, int], app_name: str = "FakeMotive", data_port: int = 1511,
                       multicast_group: str | None = None, clock_frequency_hz: int = 10_000_000) -> bytes:
    """A complete ``NAT_SERVERINFO`` datagram announcing ``version`` and the connection info."""
    body = app_name.encode().ljust(256, b"\0")
    body += bytes([3, 1, 0, 0]) + bytes([version[0], version[1], 0, 0])
    group = socket.inet_aton(multicast_group or "0.0.0.0")
    body += struct.pack("<QH?", clock_frequency_hz, data_port, multicast_group is not None) + group
    return struct.pack("<HH", MessageId.SERVER_INFO, len(body)) + body


class FakeNatNetServer:
    """A NatNet server on 127.0.0.1 with an ephemeral command port. Use as a context manager.

    Args:
        version: NatNet stream version announced and used to encode frames.
        answer_connect: when False the server ignores ``NAT_CONNECT`` (to test connect timeouts).
        multicast_group: announced in server info; frames go there when ``send_frame(to=...)`` says so.
    """

    def __init__(self, version: tuple[int, int] = (4, 1), answer_connect: bool = True,
                 multicast_group: str | None = None) -> None:
        self.version = version
        self.answer_connect = answer_connect
        self.multicast_group = multicast_group
        self.clients: list[tuple[str, int]] = []
        self.requests: list[int] = []
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.bind(("127.0.0.1", 0))
        self._sock.settimeout(0.05)
        self._sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton("127.0.0.1"))
        self._sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="fake-natnet", daemon=True)
        self._thread.start()

    @property
    def command_port(self) -> int:
        """The UDP port the server answers commands on."""
        return self._sock.getsockname()[1]

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                data, addr = self._sock.recvfrom(65536)
            except (socket.timeout, OSError):
                continue
            if len(data) < 4:
                continue
            (message_id,) = struct.unpack_from("<H", data)
            with self._lock:
                self.requests.append(message_id)
            if message_id == MessageId.CONNECT and self.answer_connect:
                with self._lock:
                    if addr not in self.clients:
                        self.clients.append(addr)
                self._sock.sendto(encode_server_info(self.version, multicast_group=self.multicast_group), addr)

    def send_frame(self, frame: FakeFrame, to: tuple[str, int] | None = None) -> None:
        """Send one frame to ``to``, or to every connected client when None."""
        self.send_raw(encode_frame(frame, self.version), to)

    def send_raw(self, packet: bytes, to: tuple[str, int] | None = None) -> None:
        """Send arbitrary bytes (truncated or garbage packets) like ``send_frame``."""
        with self._lock:
            targets = [to] if to is not None else list(self.clients)
        for addr in targets:
            self._sock.sendto(packet, addr)

    def close(self) -> None:
        """Stop the server thread and release the socket; safe to call twice."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=1.0)
        self._sock.close()

    def __enter__(self) -> "FakeNatNetServer":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
