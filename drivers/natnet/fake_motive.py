"""A Motive stand-in that streams moving rigid bodies as real NatNet frames on loopback.

:class:`FakeMotive` owns a :class:`~drivers.natnet.fake.FakeNatNetServer` (which answers ``NAT_CONNECT``,
``NAT_REQUEST_MODELDEF`` with the configured names and ids, and records ``NAT_KEEPALIVE``) and a thread
that sends one ``NAT_FRAMEOFDATA`` per period. Frame ``k`` (numbered from 1) is due at ``t0 + k / rate_hz``
on the monotonic clock, so the rate does not drift however long it runs; a thread that falls more than
:data:`MAX_LAG_S` behind skips the frames it missed (their numbers too), as a camera system drops frames.

Units: ``poses`` gives millimetres, NatNet carries metres; the conversion happens here, once, when a
frame is encoded (the parser in :mod:`drivers.natnet.packets` converts back to millimetres).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Mapping

import numpy as np

from calibration.kinematics import so3
from drivers.errors import DriverError
from drivers.natnet.fake import FakeBody, FakeFrame, FakeNatNetServer

log = logging.getLogger("cellcal.drivers")

MM_TO_M = 1e-3
MAX_LAG_S = 0.25
DEVICE = "fake-motive"
Pose = tuple[np.ndarray, np.ndarray]  # R (3, 3), p_mm (3,)
PoseFn = Callable[[float], Mapping[str, Pose | None]]


class FakeMotive:
    """Streams ``bodies`` at ``rate_hz`` with poses from a callback. Use as a context manager.

    Args:
        bodies: rigid-body name -> id, as Motive defines them (also answered to ``NAT_REQUEST_MODELDEF``).
        poses: ``poses(t_s) -> {name: (R (3, 3), p_mm (3,)) | None}``; ``t_s`` is the frame time [s] since
            start(); None, or a name left out, streams that body as not tracked (tracking-valid bit clear).
        rate_hz: frame rate [Hz].
        noise_pos_mm: standard deviation of the position noise per axis [mm].
        noise_rot_deg: standard deviation of the rotation noise per axis (rotation vector) [deg].
        seed: seed of the noise generator.
        marker_error_mm: mean marker error streamed with tracked bodies [mm].
        version: NatNet version streamed (4.1: byte counts, precision timestamp).
        command_port: command port of the server (0 picks a free one).
        data_port: data port announced, and the destination port in multicast mode.
        multicast_group: stream to this group instead of to the clients that sent ``NAT_CONNECT``.

    Each frame carries: frame number, the bodies (position, quaternion, marker error, tracking valid),
    ``timestamp`` = frame time [s] since start(), and (4.1+) the precision timestamp = wall-clock time
    (``time.time()`` at start() plus the frame time) as whole seconds and a 2**-32 s fraction.

    Raises:
        DriverError: bad rate, noise, or ids (at construction); from close(), the ``poses`` callback's
            failure if it raised or returned a bad pose (streaming stops at that frame).
    """

    def __init__(self, bodies: Mapping[str, int], poses: PoseFn, *, rate_hz: float = 240.0,
                 noise_pos_mm: float = 0.0, noise_rot_deg: float = 0.0, seed: int = 0,
                 marker_error_mm: float = 0.2, version: tuple[int, int] = (4, 1), command_port: int = 0,
                 data_port: int = 1511, multicast_group: str | None = None) -> None:
        if not rate_hz > 0 or not np.isfinite(rate_hz):
            raise DriverError(DEVICE, f"rate_hz must be a positive number, got {rate_hz}")
        if not (noise_pos_mm >= 0 and noise_rot_deg >= 0):
            raise DriverError(DEVICE, f"noise must be >= 0, got noise_pos_mm={noise_pos_mm}, "
                                      f"noise_rot_deg={noise_rot_deg}")
        if len(set(bodies.values())) != len(bodies):
            raise DriverError(DEVICE, f"rigid-body ids must be unique, got {dict(bodies)}")
        self.bodies = dict(bodies)
        self.poses = poses
        self.rate_hz = float(rate_hz)
        self.noise_pos_mm = float(noise_pos_mm)
        self.noise_rot_deg = float(noise_rot_deg)
        self.marker_error_mm = float(marker_error_mm)
        self.server = FakeNatNetServer(version, multicast_group=multicast_group, bodies=self.bodies,
                                       command_port=command_port, data_port=data_port)
        self.frames_sent = 0
        self.frames_skipped = 0
        self._rng = np.random.default_rng(seed)
        self._failure: DriverError | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    @property
    def command_port(self) -> int:
        """The UDP port the server answers commands on."""
        return self.server.command_port

    def start(self) -> None:
        """Start streaming (the server answers commands from construction on); a second call does nothing."""
        if self._thread is not None:
            return
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="fake-motive", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        t0, wall0 = time.monotonic(), time.time()
        k = 0
        while not self._stop.is_set():
            lag = time.monotonic() - (t0 + k / self.rate_hz)
            if lag < 0:
                if self._stop.wait(-lag):
                    break
            elif lag > MAX_LAG_S:
                skip = int(lag * self.rate_hz)
                self.frames_skipped += skip
                k += skip
                continue
            t_s = k / self.rate_hz
            try:
                frame = self._frame(k + 1, t_s, wall0 + t_s)
            except Exception as e:  # the caller's callback: keep its error for close()
                log.error("%s: poses(%.4f) failed: %s", DEVICE, t_s, e)
                if not isinstance(e, DriverError):
                    e = DriverError(DEVICE, f"poses({t_s:.4f}) failed: {e!r}")
                self._failure = e
                return
            self.server.stream(frame)
            self.frames_sent += 1
            k += 1

    def _frame(self, number: int, t_s: float, wall_s: float) -> FakeFrame:
        poses = self.poses(t_s)
        unknown = sorted(set(poses) - set(self.bodies))
        if unknown:
            raise DriverError(DEVICE, f"poses returned unknown bodies {unknown}; known: {sorted(self.bodies)}")
        bodies = tuple(self._body(name, body_id, poses.get(name)) for name, body_id in self.bodies.items())
        sec = int(wall_s)
        frac = min(int((wall_s - sec) * 2 ** 32), 2 ** 32 - 1)
        return FakeFrame(number, bodies, timestamp=t_s, precision_timestamp=(sec, frac))

    def _body(self, name: str, body_id: int, pose: Pose | None) -> FakeBody:
        if pose is None:
            return FakeBody(body_id, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0), 0.0, tracking_valid=False)
        R, p_mm = np.asarray(pose[0], dtype=float), np.asarray(pose[1], dtype=float)
        if R.shape != (3, 3) or p_mm.shape != (3,) or not (np.isfinite(R).all() and np.isfinite(p_mm).all()):
            raise DriverError(DEVICE, f"pose of {name!r} must be finite R (3, 3) and p_mm (3,), "
                                      f"got shapes {R.shape} and {p_mm.shape}")
        p_mm = p_mm + self._rng.normal(0.0, self.noise_pos_mm, 3)
        R = R @ so3.exp(np.radians(self.noise_rot_deg) * self._rng.normal(0.0, 1.0, 3))
        w, x, y, z = so3.R_to_quat(R)
        p_m = p_mm * MM_TO_M
        return FakeBody(body_id, (p_m[0], p_m[1], p_m[2]), (x, y, z, w), self.marker_error_mm * MM_TO_M)

    def close(self) -> None:
        """Stop streaming and the server; safe to call twice.

        Raises:
            DriverError: the ``poses`` callback failed while streaming.
        """
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        self.server.close()
        failure, self._failure = self._failure, None
        if failure is not None:
            raise failure

    def __enter__(self) -> FakeMotive:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
