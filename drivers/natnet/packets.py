"""NatNet frames of data: pure functions that turn ``NAT_FRAMEOFDATA`` payloads into typed frames.

Message framing, ids and the command channel live in :mod:`drivers.natnet.messages` (re-exported here).
A frame of data (``NAT_FRAMEOFDATA``) holds, in order: frame number, marker sets, unlabeled markers, rigid bodies,
skeletons, assets (4.1+), labeled markers, force plates, devices and the frame suffix (timecode,
timestamp, camera timestamps, the 4.1+ precision timestamp, parameters). From NatNet 4.1 every section
count is followed by an ``int32`` byte count of that section. Rigid bodies carry no per-marker data from
NatNet 3.0 on, which is the oldest layout parsed here.

NatNet streams metres and quaternions ordered (x, y, z, w); the parser converts to millimetres and
(w, x, y, z) so the rest of cellcal never sees the wire conventions. Any short or inconsistent packet
raises :class:`~drivers.errors.ProtocolError`; nothing is returned half-parsed.
"""

from __future__ import annotations

import dataclasses
import math
import struct
from dataclasses import dataclass

import numpy as np

from drivers.base import RigidBodyFrame
from drivers.errors import ProtocolError
from drivers.natnet.messages import (  # noqa: F401
    HEADER,
    MessageId,
    ServerInfo,
    build_connect,
    build_request,
    check_version,
    has_byte_counts,
    has_precision_timestamp,
    parse_server_info,
    split_packet,
)
from drivers.natnet.reader import DEVICE
from drivers.natnet.reader import I32 as _I32
from drivers.natnet.reader import Reader as _Reader

M_TO_MM = 1000.0
TRACKING_VALID = 0x01
_RIGID_BODY = struct.Struct("<i3f4ffh")  # id, position [m], quaternion xyzw, mean error [m], params
_LABELED_MARKER_SIZE = 4 + 12 + 4 + 2 + 4  # id, position, size, params, residual
_SUFFIX = struct.Struct("<IId")  # timecode, timecode sub-frame, timestamp [s]
_STAMPS = struct.Struct("<3Q")  # mid-exposure, data received, transmit [clock ticks]
_PRECISION = struct.Struct("<II")  # precision timestamp: seconds, fraction of a second (4.1+)
PRECISION_FRACTION_PER_S = 2 ** 32  # ASSUMED unit of the fraction word (NTP-style); unverified on Motive
_PARAMS = struct.Struct("<h")


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
        precision_timestamp_sec: whole seconds of the precision timestamp (NatNet 4.1+), 0 when absent.
        precision_timestamp_frac: fraction of a second of the precision timestamp, taken as units of
            2**-32 s (the SDK names it "fractional seconds" without a unit; check against a real Motive
            before relying on sub-second precision time, see :data:`PRECISION_FRACTION_PER_S`).
        bodies_dropped: rigid bodies left out of ``rigid_bodies`` because their pose was not finite or their
            quaternion not of unit norm (a corrupt or forged frame; Motive streams unit quaternions).
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
    precision_timestamp_sec: int = 0
    precision_timestamp_frac: int = 0
    bodies_dropped: int = 0

    @property
    def precision_time_s(self) -> float | None:
        """The precision timestamp [s], None when the server sent none (before 4.1, or both words 0).

        It is the server's precision clock: PTP (IEEE 1588) time when Motive's cameras are synchronised
        to a PTP master (eSync 2 / PTP-enabled cameras), so it is comparable across machines on that
        clock; :attr:`timestamp` instead counts seconds since Motive started streaming. Informational: no
        window is cut on it (see :attr:`capture_time`).
        """
        if self.precision_timestamp_sec == 0 and self.precision_timestamp_frac == 0:
            return None
        return self.precision_timestamp_sec + self.precision_timestamp_frac / PRECISION_FRACTION_PER_S

    @property
    def capture_time(self) -> float:
        """Capture time of the frame [s]: :attr:`timestamp`, Motive's frame time (a double keyed off the hardware
        frame id since NatNet 2.7), on every version.

        Not :attr:`precision_time_s`: the SDK leaves the unit of its fraction word open (2**-32 s or nanoseconds,
        :data:`PRECISION_FRACTION_PER_S`), and read in the wrong one its sub-second part would run at a quarter of
        real time and jump at each whole second, so a measurement window cut on it would hold the wrong frames.
        The collector needs only a clock that keeps the capture instants' rate (it learns the offset to the host
        clock itself, :mod:`app.collection.mocap_window`), which the frame time does.
        """
        return self.timestamp


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
        The frame; each rigid body's capture_time is :attr:`MocapFrame.capture_time` [s], the frame timestamp
        (seconds since Motive started); the 4.1+ precision timestamp is kept as read
        (:attr:`MocapFrame.precision_time_s`).

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
    stamp_mid_exposure, stamp_received, stamp_transmit = r.unpack(_STAMPS, "camera timestamps")
    precision_sec, precision_frac = (r.unpack(_PRECISION, "precision timestamp")
                                     if has_precision_timestamp(version) else (0, 0))
    (params,) = r.unpack(_PARAMS, "frame params")

    frame = MocapFrame(frame_number, (), tuple(marker_sets), unlabeled, skeleton_count, labeled_count,
                       timecode, timecode_sub, timestamp, stamp_mid_exposure, stamp_received, stamp_transmit,
                       params, precision_sec, precision_frac)
    capture_time = frame.capture_time
    kept = [b for b in bodies if _usable_pose(b[1], b[2], b[3])]
    rigid_bodies = tuple(
        RigidBodyFrame(body_id=i, position_mm=p, quat_wxyz=q, marker_error_mm=e,
                       tracking_valid=bool(f & TRACKING_VALID), capture_time=capture_time,
                       frame_number=frame_number)
        for i, p, q, e, f in kept
    )
    return dataclasses.replace(frame, rigid_bodies=rigid_bodies, bodies_dropped=len(bodies) - len(kept))


#: Largest departure of a streamed quaternion's norm from 1 (Motive streams float32 unit quaternions, ~1e-7 off).
QUAT_NORM_TOL = 1e-3


def _usable_pose(p_mm: np.ndarray, quat: np.ndarray, error_mm: float) -> bool:
    """A finite position, marker error and unit quaternion: NaN positions and zero quaternions passed as
    tracking-valid frames (issue 30), whatever their tracking flag said."""
    return bool(np.all(np.isfinite(p_mm)) and np.all(np.isfinite(quat)) and math.isfinite(error_mm)
                and abs(float(np.linalg.norm(quat)) - 1.0) <= QUAT_NORM_TOL)
