"""A simulated motion-capture system measuring the true tool-marker pose of simulated arms.

Frames are produced at ``rate_hz`` on the arms' :class:`SimClock` (frame k is captured at k / rate_hz) and
delivered ``latency_s`` later. Each rigid body is expressed in the base frame of the robot carrying it by
default (what a recording stores: the mocap-to-base registration already applied); pass ``T_ref_base`` to
express it in another frame (e.g. the cell frame, ``CellRobot.T_cell_base``).

Noise, bias, dropouts (``tracking_valid`` False, reported at the origin as real systems do), missing frames
and marker-error spikes are configurable. Noise is a function of the seed and the frame number only, so the
same seed gives the same measurement for the same frame, whatever the reading pattern.
"""

from __future__ import annotations

import logging
import math
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from calibration.kinematics import so3
from drivers.base import MocapSource, RigidBodyFrame
from drivers.errors import DriverDisconnected, InvalidArgument
from drivers.sim.robot import SimRobotDriver

log = logging.getLogger("cellcal.drivers")


@dataclass(frozen=True)
class SimMocapConfig:
    """Measurement model of the simulated mocap.

    Attributes:
        rate_hz: frame rate [Hz].
        noise_pos_mm: per-frame position noise, standard deviation per axis [mm].
        noise_rot_deg: per-frame orientation noise, standard deviation per axis of the rotation vector [deg].
        bias_pos_mm: constant position offset added to every frame [mm], shape (3,).
        bias_rot_deg: constant rotation vector applied in the body frame [deg], shape (3,).
        latency_s: delay between capture and delivery [s].
        dropout_prob: probability that a frame is delivered with ``tracking_valid`` False.
        missing_prob: probability that a frame is never delivered.
        marker_error_mm: typical mean marker residual [mm].
        marker_spike_prob: probability of a frame with a large marker error.
        marker_spike_mm: marker residual of such a frame [mm].
        buffer_frames: frames kept for a slow reader (older ones are dropped, like a network buffer).
        seed: random seed.
    """

    rate_hz: float = 240.0
    noise_pos_mm: float = 0.02
    noise_rot_deg: float = 0.005
    bias_pos_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    bias_rot_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    latency_s: float = 0.005
    dropout_prob: float = 0.0
    missing_prob: float = 0.0
    marker_error_mm: float = 0.1
    marker_spike_prob: float = 0.0
    marker_spike_mm: float = 2.0
    buffer_frames: int = 480
    seed: int = 0


class SimMocapSource(MocapSource):
    """Simulated mocap over one or more simulated arms.

    Args:
        bodies: rigid-body id -> the simulated arm carrying that body; all arms share one clock.
        config: measurement model.
        T_ref_base: rigid-body id -> pose (4, 4) [mm] of that arm's base in the reported frame;
            identity (the arm's own base frame) for ids not given.
    """

    def __init__(self, bodies: Mapping[int, SimRobotDriver], config: SimMocapConfig = SimMocapConfig(),
                 T_ref_base: Mapping[int, np.ndarray] | None = None) -> None:
        if not bodies:
            raise InvalidArgument("sim:mocap", "bodies", dict(bodies), "at least one rigid body")
        clocks = {id(d.clock) for d in bodies.values()}
        if len(clocks) != 1:
            raise InvalidArgument("sim:mocap", "bodies", {b: d.device for b, d in bodies.items()},
                                  "arms that all share one SimClock")
        if not config.rate_hz > 0:
            raise InvalidArgument("sim:mocap", "rate_hz", config.rate_hz, "a positive rate [Hz]")
        self.bodies = dict(bodies)
        self.config = config
        self.clock = next(iter(bodies.values())).clock
        self.T_ref_base = {b: np.asarray((T_ref_base or {}).get(b, np.eye(4)), dtype=float) for b in self.bodies}
        self._R_bias = so3.exp(np.radians(config.bias_rot_deg))
        self._lock = threading.Lock()
        self._connected = False
        self._next_frame = 0
        self.delivered = 0  # frames handed to readers so far
        self._blackouts: list[tuple[float, float, bool]] = []

    @property
    def device(self) -> str:
        return "sim:mocap"

    def stamp_clock(self) -> Callable[[], float]:
        """The simulated clock: the frames are stamped with it."""
        return self.clock.now

    def connect(self) -> None:
        with self._lock:
            self._connected = True
            self._next_frame = self._due_frame()

    def close(self) -> None:
        with self._lock:
            self._connected = False

    def blackout(self, duration_s: float, missing: bool = False) -> tuple[float, float]:
        """Lose tracking of every body for ``duration_s`` simulated seconds from now.

        Args:
            duration_s: length of the outage [s, simulated].
            missing: True to deliver no frames at all, False to deliver frames with ``tracking_valid`` False.

        Returns:
            The capture-time window [s, simulated] of the outage.
        """
        now = self.clock.now()
        window = (now - self.config.latency_s, now + duration_s)
        with self._lock:
            self._blackouts.append((*window, missing))
        return window

    def _due_frame(self) -> int:
        """Index one past the last frame delivered by now."""
        return int(math.floor((self.clock.now() - self.config.latency_s) * self.config.rate_hz)) + 1

    def delivered_all_due(self) -> bool:
        """Whether every frame due by now (captured up to ``now - latency_s``) has been handed to a reader."""
        with self._lock:
            return self._next_frame >= self._due_frame()

    def read(self, timeout_s: float) -> list[RigidBodyFrame]:
        """Frames delivered since the last call, waiting up to ``timeout_s`` simulated seconds for at least one."""
        waited = 0.0
        period = 1.0 / self.config.rate_hz
        while True:
            with self._lock:
                if not self._connected:
                    raise DriverDisconnected(self.device, "not connected")
                due = self._due_frame()
                first = max(self._next_frame, due - self.config.buffer_frames)
                self._next_frame = max(self._next_frame, due)
                frames = self._make_frames(first, due) if due > first else []
                self.delivered += len(frames)
            if frames or waited >= timeout_s:
                return frames
            step = min(period, timeout_s - waited)
            self.clock.sleep(step)
            waited += step

    def _uniforms(self, body_index: int, first: int, n: int) -> np.ndarray:
        """12 uniforms in [0, 1) per frame for frames first..first+n-1, a function of seed and frame only."""
        bits = np.random.Philox(key=[self.config.seed, body_index])
        bits.advance(first * 3)  # 3 counter steps x 4 words = 12 draws per frame
        raw = bits.random_raw(n * 12).reshape(n, 12)
        return (raw >> np.uint64(11)).astype(float) * 2.0**-53

    def _make_frames(self, first: int, stop: int) -> list[RigidBodyFrame]:
        c = self.config
        numbers = np.arange(first, stop)
        n = numbers.size
        t = numbers / c.rate_hz
        out: list[RigidBodyFrame] = []
        for b_index, (body, driver) in enumerate(self.bodies.items()):
            R, p = driver.true_pose(t)
            T = self.T_ref_base[body]
            R = T[:3, :3] @ R
            p = p @ T[:3, :3].T + T[:3, 3]
            u = self._uniforms(b_index, first, n)
            r = np.sqrt(-2.0 * np.log1p(-u[:, 3:6]))  # Box-Muller: 6 normals from 6 uniforms
            noise = np.concatenate([r * np.cos(2 * np.pi * u[:, 6:9]), r * np.sin(2 * np.pi * u[:, 6:9])], axis=1)
            pos = p + np.asarray(c.bias_pos_mm) + c.noise_pos_mm * noise[:, :3]
            R_meas = R @ self._R_bias @ so3.exp(np.radians(c.noise_rot_deg) * noise[:, 3:])
            quat = so3.R_to_quat(R_meas)
            err = np.where(u[:, 2] < c.marker_spike_prob, c.marker_spike_mm,
                           c.marker_error_mm * (1.0 + 0.1 * np.abs(u[:, 9] - 0.5)))
            for i in range(n):
                if u[i, 0] < c.missing_prob or self._blacked_out(t[i], missing=True):
                    continue
                if u[i, 1] < c.dropout_prob or self._blacked_out(t[i], missing=False):
                    out.append(RigidBodyFrame(body, np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0]), float(err[i]),
                                              False, float(t[i]), int(numbers[i])))
                else:
                    out.append(RigidBodyFrame(body, pos[i], quat[i], float(err[i]), True, float(t[i]),
                                              int(numbers[i])))
        out.sort(key=lambda f: f.frame_number)
        return out

    def _blacked_out(self, t: float, missing: bool) -> bool:
        return any(t0 <= t < t1 and m == missing for t0, t1, m in self._blackouts)
