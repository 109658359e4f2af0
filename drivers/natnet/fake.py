"""A fake NatNet server (Motive stand-in) that speaks the wire protocol on loopback.

It builds frame and model-definition packets field by field for NatNet 3.x and 4.x, answers
``NAT_CONNECT`` with ``NAT_SERVERINFO`` and ``NAT_REQUEST_MODELDEF`` with ``NAT_MODELDEF``, counts every request
(``request_counts``; an SDK client sends about 240 a second, so only the last ``MAX_KEPT_REQUESTS`` are kept in
order), streams to each unicast client in the NatNet version its ``NAT_CONNECT`` asked for (bytes 265..268 of the
SDK's request) when it can encode it (3.0 up to its own), and streams frames to the clients that connected (unicast, to the socket their
``NAT_CONNECT`` came from, as Motive does), to its multicast group, or to any address given. It can also send
truncated or garbage datagrams to exercise error paths. :class:`drivers.natnet.fake_motive.FakeMotive`
streams moving bodies through it at a fixed rate.
The encoders here are written independently of :mod:`drivers.natnet.packets` so tests compare two
implementations of the layout rather than one with itself.
"""

from __future__ import annotations

import collections
import logging
import socket
import struct
import threading
from collections.abc import Mapping
from dataclasses import dataclass

from drivers.errors import DriverError
from drivers.natnet.messages import MessageId

log = logging.getLogger("cellcal.drivers")

#: Requests kept in order (``FakeNatNetServer.requests``); ``request_counts`` counts every one.
MAX_KEPT_REQUESTS = 1000
#: Where the SDK's ``NAT_CONNECT`` body holds the requested NatNet version (major, minor, 0, 0).
_CONNECT_VERSION_AT = 265


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
    precision_timestamp: tuple[int, int] = (0, 0)  # seconds, fraction [2**-32 s]; sent from 4.1 on
    assets: int = 0  # assets (4.1+), each with no bodies and no markers; Motive sends none unless some are defined


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
    if version >= (4, 1):  # assets: ids 7, 8, ..., no bodies, no markers
        out += _section(frame.assets, b"".join(struct.pack("<iii", 7 + k, 0, 0) for k in range(frame.assets)),
                        version)
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
    if version >= (4, 1):
        out += struct.pack("<II", *frame.precision_timestamp)
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


def _desc(kind: int, body: bytes, version: tuple[int, int]) -> bytes:
    size = struct.pack("<i", len(body)) if version >= (4, 1) else b""
    return struct.pack("<i", kind) + size + body


def _rigid_body_desc(name: str, body_id: int, version: tuple[int, int], parent_id: int = -1) -> bytes:
    """A rigid-body description with three markers 50 mm apart on x, y, z (active labels 1..3)."""
    out = name.encode() + b"\0" + struct.pack("<ii3f", body_id, parent_id, 0.0, 0.0, 0.0)
    if version >= (4, 2):
        out += struct.pack("<4f", 0.0, 0.0, 0.0, 1.0)
    markers = ((0.05, 0.0, 0.0), (0.0, 0.05, 0.0), (0.0, 0.0, 0.05))
    out += struct.pack("<i", len(markers)) + b"".join(struct.pack("<3f", *m) for m in markers)
    out += b"".join(struct.pack("<i", k + 1) for k in range(len(markers)))
    if version >= (4, 0):
        out += b"".join(f"{name}_{k + 1}".encode() + b"\0" for k in range(len(markers)))
    return out


def _strings(names: tuple[str, ...]) -> bytes:
    return struct.pack("<i", len(names)) + b"".join(n.encode() + b"\0" for n in names)


def _others(version: tuple[int, int]) -> bytes:
    """One skeleton, force plate, device, camera and (4.1+) asset, so parsers must skip them."""
    out = _desc(2, b"skel\0" + struct.pack("<ii", 40, 1) + _rigid_body_desc("bone", 41, version), version)
    plate = (struct.pack("<i", 3) + b"FP-001\0" + struct.pack("<2f3f", 0.6, 0.4, 0.0, 0.0, 0.0)
             + struct.pack("<144f", *range(144)) + struct.pack("<12f", *range(12)) + struct.pack("<ii", 1, 0)
             + _strings(("Fx", "Fy", "Fz")))
    out += _desc(3, plate, version)
    out += _desc(4, struct.pack("<i", 5) + b"daq\0SN-5\0" + struct.pack("<ii", 1, 0) + _strings(("ai0",)), version)
    out += _desc(5, b"cam1\0" + struct.pack("<3f4f", 1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 1.0), version)
    if version >= (4, 1):
        asset = (b"asset\0" + struct.pack("<iii", 1, 60, 1) + _rigid_body_desc("asset_rb", 61, version)
                 + struct.pack("<i", 1) + b"asset_m\0" + struct.pack("<i3ffh", 62, 0.1, 0.2, 0.3, 0.014, 0))
        out += _desc(6, asset, version)
    return out


def encode_model_definitions(bodies: Mapping[str, int], version: tuple[int, int], others: bool = True) -> bytes:
    """A complete ``NAT_MODELDEF`` datagram: per body a marker set and a rigid body, then ``others``."""
    descs = [_desc(0, name.encode() + b"\0" + _strings(tuple(f"{name}_{k}" for k in (1, 2, 3))), version)
             for name in bodies]
    descs += [_desc(1, _rigid_body_desc(name, body_id, version), version) for name, body_id in bodies.items()]
    count = len(descs) + (4 + (version >= (4, 1)) if others else 0)
    out = struct.pack("<i", count) + b"".join(descs) + (_others(version) if others else b"")
    return struct.pack("<HH", MessageId.MODEL_DEF, len(out)) + out


class FakeNatNetServer:
    """A NatNet server on 127.0.0.1. Use as a context manager.

    Args:
        version: NatNet stream version announced and used to encode frames.
        answer_connect: when False the server ignores ``NAT_CONNECT`` (to test connect timeouts).
        multicast_group: announced in server info; :meth:`stream` sends there when set.
        bodies: rigid-body name -> id, answered to ``NAT_REQUEST_MODELDEF``.
        command_port: UDP port to answer commands on; 0 picks a free one.
        data_port: data port announced in server info and used by :meth:`stream` in multicast mode.
    """

    def __init__(self, version: tuple[int, int] = (4, 1), answer_connect: bool = True,
                 multicast_group: str | None = None, *, bodies: Mapping[str, int] | None = None,
                 command_port: int = 0, data_port: int = 1511) -> None:
        self.version = version
        self.answer_connect = answer_connect
        self.multicast_group = multicast_group
        self.bodies = dict(bodies or {})
        self.data_port = data_port
        self.clients: list[tuple[str, int]] = []
        self.client_versions: dict[tuple[str, int], tuple[int, int]] = {}  # what each unicast client asked for
        self.requests: collections.deque[int] = collections.deque(maxlen=MAX_KEPT_REQUESTS)  # the latest, in order
        self.request_counts: collections.Counter[int] = collections.Counter()
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self._sock.bind(("127.0.0.1", command_port))
        except OSError as e:  # another fake Motive (or Motive) holds it: one line, not an OSError traceback
            self._sock.close()
            raise DriverError(f"fake-natnet@127.0.0.1:{command_port}", f"cannot listen on the command port "
                                                                      f"{command_port} ({e.strerror or e}); is "
                                                                      "another fake Motive already using it?") from e
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
        port: int = self._sock.getsockname()[1]
        return port

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                data, addr = self._sock.recvfrom(65536)
            except (TimeoutError, OSError):
                continue
            if len(data) < 4:
                continue
            (message_id,) = struct.unpack_from("<H", data)
            with self._lock:
                self.requests.append(message_id)
                self.request_counts[message_id] += 1
            if message_id == MessageId.CONNECT and self.answer_connect:
                version = self._requested_version(data)
                with self._lock:
                    if addr not in self.clients:
                        self.clients.append(addr)
                    self.client_versions[addr] = version
                reply = encode_server_info(version, data_port=self.data_port, multicast_group=self.multicast_group)
                self._sock.sendto(reply, addr)
            elif message_id == MessageId.REQUEST_MODEL_DEF:
                with self._lock:
                    version = self.client_versions.get(addr, self.version)
                self._sock.sendto(encode_model_definitions(self.bodies, version), addr)

    def _requested_version(self, request: bytes) -> tuple[int, int]:
        """The version a ``NAT_CONNECT`` asks for when this server can stream it (3.0 up to its own), else its own."""
        at = 4 + _CONNECT_VERSION_AT
        if len(request) >= at + 2:
            asked = (request[at], request[at + 1])
            if (3, 0) <= asked <= self.version:
                return asked
        return self.version

    def send_frame(self, frame: FakeFrame, to: tuple[str, int] | None = None) -> None:
        """Send one frame to ``to``, or to every connected client when None, each in the version it asked for."""
        with self._lock:
            targets = [to] if to is not None else list(self.clients)
            versions = {addr: self.client_versions.get(addr, self.version) for addr in targets}
        packets: dict[tuple[int, int], bytes] = {}
        for addr in targets:
            version = versions[addr]
            if version not in packets:
                packets[version] = encode_frame(frame, version)
            self._send(packets[version], addr)

    def stream(self, frame: FakeFrame) -> None:
        """Send one frame as Motive streams it: to the multicast group's data port, else to every client."""
        to = (self.multicast_group, self.data_port) if self.multicast_group is not None else None
        self.send_frame(frame, to)

    def send_raw(self, packet: bytes, to: tuple[str, int] | None = None) -> None:
        """Send arbitrary bytes (truncated or garbage packets) like ``send_frame``."""
        with self._lock:
            targets = [to] if to is not None else list(self.clients)
        for addr in targets:
            self._send(packet, addr)

    def _send(self, packet: bytes, addr: tuple[str, int]) -> None:
        try:
            self._sock.sendto(packet, addr)
        except OSError as e:  # a client that went away; Motive keeps streaming to the others
            log.debug("fake natnet: send to %s failed: %s", addr, e)

    def close(self) -> None:
        """Stop the server thread and release the socket; safe to call twice."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=1.0)
        self._sock.close()

    def __enter__(self) -> FakeNatNetServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
