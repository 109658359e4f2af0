"""Joint motion of one simulated motion group, as the fake MotoROS controller plays it.

Each accepted trajectory point after point 0 becomes a segment from where the arm is to the point's
position over the point's time step, shaped like MotoROS's cubic interpolation with zero end velocities
(s = 3 tau^2 - 2 tau^3), and stretched if a joint's peak speed would exceed its limit. Point velocities and
accelerations are ignored.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from drivers.motoros.codec import Result

_PEAK_RATIO = 1.5  # peak / mean speed of the cubic profile
START_TOLERANCE_RAD = 1e-3  # MotoROS allows a few encoder pulses between point 0 and the arm
QUEUE_LENGTH = 20


@dataclass(frozen=True)
class _Segment:
    q_from: np.ndarray
    q_to: np.ndarray
    t0: float
    duration_s: float


class SimulatedGroup:
    """Joint state and trajectory queue of one group; not thread-safe (the controller locks around it).

    Args:
        n_joints: number of joints.
        max_speed_rad_s: speed limit [rad/s], scalar or shape (n_joints,).
    """

    def __init__(self, n_joints: int, max_speed_rad_s: float | np.ndarray) -> None:
        self.n_joints = n_joints
        self.max_speed_rad_s = np.broadcast_to(np.asarray(max_speed_rad_s, dtype=float), (n_joints,)).copy()
        self.q = np.zeros(n_joints)
        self.qd = np.zeros(n_joints)
        self.queue: deque[tuple[np.ndarray, float]] = deque()
        self._segment: _Segment | None = None
        self._last_point: tuple[int, float] | None = None  # (sequence, time [s]) of the last accepted point
        self._last_step: float | None = None

    @property
    def moving(self) -> bool:
        return self._segment is not None or bool(self.queue)

    def accept_point(self, sequence: int, time_s: float, pos: np.ndarray) -> tuple[Result, int]:
        """Queue one trajectory point; returns the MotoROS (result, subcode)."""
        target = np.asarray(pos, dtype=float)[: self.n_joints]
        if sequence == 0:
            if self.moving or np.max(np.abs(target - self.q)) > START_TOLERANCE_RAD:
                return Result.INVALID, 3011
            self._last_point = (0, time_s)
            return Result.SUCCESS, 0
        if self._last_point is None or sequence != self._last_point[0] + 1:
            return Result.INVALID, 3005
        if time_s <= self._last_point[1]:
            return Result.INVALID, 3016
        if len(self.queue) >= QUEUE_LENGTH:
            return Result.BUSY, 0
        self.queue.append((target, time_s - self._last_point[1]))
        self._last_point = (sequence, time_s)
        return Result.SUCCESS, 0

    def halt(self) -> None:
        """Drop the queue and stand still where the arm is."""
        self.queue.clear()
        self._segment = None
        self._last_point = None
        self.qd = np.zeros(self.n_joints)

    def step(self, now: float) -> None:
        """Advance the simulation to ``now`` [s, monotonic]."""
        dt = 0.0 if self._last_step is None else now - self._last_step
        self._last_step = now
        q_before = self.q.copy()
        if self._segment is None and self.queue:
            target, duration = self.queue.popleft()
            duration = max(duration, _PEAK_RATIO * float(np.max(np.abs(target - self.q) / self.max_speed_rad_s)))
            self._segment = _Segment(self.q.copy(), target, now, duration)
        if self._segment is not None:
            seg = self._segment
            tau = 1.0 if seg.duration_s <= 0 else min(1.0, (now - seg.t0) / seg.duration_s)
            self.q = seg.q_from + (3 * tau**2 - 2 * tau**3) * (seg.q_to - seg.q_from)
            if tau >= 1.0:
                self._segment = None
        self.qd = (self.q - q_before) / dt if dt > 0 else np.zeros(self.n_joints)
