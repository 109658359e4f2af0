"""Joint motion of one simulated motion group, as MotoROS plays trajectory points (MotoPlus/MotionServer.c).

What is modelled, and where MotoROS does it:

* Point 0 (``sequence == 0``) only sets the start of the trajectory; it is refused (3011) when any joint is
  more than ``START_MAX_PULSE_DEVIATION`` = 30 encoder pulses from the commanded position, both converted to
  pulses by truncating ``rad * pulses_per_rad`` (Ros_MotionServer_InitTrajPointFull, CtrlGroup.c
  Ros_CtrlGroup_ConvertToMotoPos).
* A later point (any ``sequence > 0``: MotoROS does not check that sequences are consecutive) becomes one
  cubic Hermite segment from the previous point's position and velocity to its own over the time difference
  in whole milliseconds (Ros_MotionServer_JointTrajDataToIncQueue). A time that does not increase adds no
  motion (MotoROS prints a warning and accepts the point). A point velocity above the joint's maximum speed
  is refused (3013).
* The controller decomposes a point into increments of one interpolation period into a queue of
  ``QUEUE_SIZE`` = 200 increments (CtrlGroup.h Q_SIZE); while the previous point does not fit into it yet
  the next one is answered BUSY. CHECK_QUEUE_CNT reports the increments queued.
* The commanded position is the feedback (no servo lag), and a segment faster than a joint's maximum speed is
  stretched in time, as the controller's own speed limit would.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from drivers.motoros.codes import InvalidSubcode, Result

START_MAX_PULSE_DEVIATION = 30  # Controller.h
QUEUE_SIZE = 200  # CtrlGroup.h Q_SIZE [increments]
INTERPOLATION_PERIOD_S = 0.004  # the controller's interpolation clock (4 ms on DX200 / YRC1000)
_PEAK_RATIO = 1.5  # peak / mean speed of a cubic segment with zero end velocities


@dataclass(frozen=True)
class TrajPoint:
    """A trajectory point as MotoROS keeps it: time [s] (rounded down to ms), pos [rad], vel [rad/s]."""

    time_s: float
    pos: np.ndarray
    vel: np.ndarray


@dataclass(frozen=True)
class _Segment:
    start: TrajPoint
    end: TrajPoint
    duration_s: float

    def at(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Position [rad] and velocity [rad/s] ``t_s`` [s] into the segment (cubic Hermite)."""
        T = self.duration_s
        tau = min(max(t_s / T, 0.0), 1.0)
        h00, h10, h01, h11 = 2 * tau**3 - 3 * tau**2 + 1, tau**3 - 2 * tau**2 + tau, 3 * tau**2 - 2 * tau**3, \
            tau**3 - tau**2
        d00, d10, d01, d11 = 6 * tau**2 - 6 * tau, 3 * tau**2 - 4 * tau + 1, 6 * tau - 6 * tau**2, 3 * tau**2 - 2 * tau
        a, b, va, vb = self.start.pos, self.end.pos, self.start.vel, self.end.vel
        q = h00 * a + h10 * T * va + h01 * b + h11 * T * vb
        qd = (d00 * a + d01 * b) / T + d10 * va + d11 * vb
        return q, qd


class SimulatedGroup:
    """Joint state and trajectory buffer of one group; not thread-safe (the controller locks around it).

    Args:
        n_joints: number of joints.
        max_speed_rad_s: speed limit [rad/s], scalar or shape (n_joints,).
        pulses_per_rad: encoder pulses per radian [1/rad], scalar or shape (n_joints,).
        q0: starting joint angles [rad], shape (n_joints,); zeros by default.
        interpolation_period_s: the controller's interpolation clock [s].
    """

    def __init__(self, n_joints: int, max_speed_rad_s: float | np.ndarray, pulses_per_rad: float | np.ndarray,
                 q0: np.ndarray | None = None, interpolation_period_s: float = INTERPOLATION_PERIOD_S) -> None:
        self.n_joints = n_joints
        self.max_speed_rad_s = np.broadcast_to(np.asarray(max_speed_rad_s, dtype=float), (n_joints,)).copy()
        self.pulses_per_rad = np.broadcast_to(np.asarray(pulses_per_rad, dtype=float), (n_joints,)).copy()
        self.period_s = interpolation_period_s
        self.q = np.zeros(n_joints) if q0 is None else np.asarray(q0, dtype=float).copy()
        self.qd = np.zeros(n_joints)
        self._pending: deque[_Segment] = deque()
        self._segment: tuple[_Segment, float] | None = None  # running segment and its start [s, monotonic]
        self._last = TrajPoint(0.0, self.q.copy(), np.zeros(n_joints))  # MotoROS's jointMotionData
        self._now: float | None = None

    def pulses(self, q: np.ndarray) -> np.ndarray:
        """Joint angles [rad] as encoder pulses, truncated like MotoROS's ``(int)(rad * PtoR)`` in float32."""
        return np.trunc(np.asarray(q, dtype=np.float32) * self.pulses_per_rad.astype(np.float32)).astype(np.int64)

    @property
    def moving(self) -> bool:
        return self._segment is not None or bool(self._pending)

    def remaining_s(self) -> float:
        """Motion time still queued [s], from the last simulation step."""
        left = sum(s.duration_s for s in self._pending)
        if self._segment is not None and self._now is not None:
            left += max(self._segment[0].duration_s - (self._now - self._segment[1]), 0.0)
        return left

    def queue_count(self) -> int:
        """Increments in the controller's queue, as CHECK_QUEUE_CNT reports them (at most QUEUE_SIZE)."""
        return min(QUEUE_SIZE, math.ceil(self.remaining_s() / self.period_s - 1e-9))

    @property
    def busy(self) -> bool:
        """True while the last accepted point is still being cut into increments (the queue is full)."""
        return self.remaining_s() > QUEUE_SIZE * self.period_s

    def _point(self, time_s: float, pos: np.ndarray, vel: np.ndarray) -> TrajPoint:
        n = self.n_joints
        time_ms = int(time_s * 1000)  # Ros_MotionServer_ConvertToJointMotionData
        return TrajPoint(time_ms / 1000.0, np.asarray(pos, float)[:n].copy(), np.asarray(vel, float)[:n].copy())

    def start_trajectory(self, time_s: float, pos: np.ndarray, vel: np.ndarray) -> tuple[Result, int]:
        """Point 0: the start of a trajectory; returns the MotoROS (result, subcode)."""
        point = self._point(time_s, pos, vel)
        if np.any(np.abs(self.pulses(point.pos) - self.pulses(self.q)) > START_MAX_PULSE_DEVIATION):
            return Result.INVALID, InvalidSubcode.DATA_START_POS
        if np.any(np.abs(point.vel) > self.max_speed_rad_s):
            return Result.INVALID, InvalidSubcode.DATA_SPEED
        self._last = point
        return Result.SUCCESS, 0

    def add_point(self, time_s: float, pos: np.ndarray, vel: np.ndarray) -> tuple[Result, int]:
        """A later point: queue the segment from the previous point; returns the MotoROS (result, subcode)."""
        if self.busy:
            return Result.BUSY, 0
        point = self._point(time_s, pos, vel)
        if np.any(np.abs(point.vel) > self.max_speed_rad_s):
            return Result.INVALID, InvalidSubcode.DATA_SPEED
        interval = point.time_s - self._last.time_s
        if interval <= 0:  # MotoROS: "Time difference ... is 0 or less", nothing is interpolated
            return Result.SUCCESS, 0
        fastest = _PEAK_RATIO * float(np.max(np.abs(point.pos - self._last.pos) / self.max_speed_rad_s))
        self._pending.append(_Segment(self._last, point, max(interval, fastest)))
        self._last = point
        return Result.SUCCESS, 0

    def halt(self) -> None:
        """Clear the queue (MotoROS ClearQ) and stand still where the arm is."""
        self._pending.clear()
        self._segment = None
        self.qd = np.zeros(self.n_joints)

    def step(self, now: float) -> None:
        """Advance the simulation to ``now`` [s, monotonic]."""
        self._now = now
        if self._segment is None and self._pending:
            self._segment = (self._pending.popleft(), now)
        while self._segment is not None:
            segment, t0 = self._segment
            if now - t0 < segment.duration_s:
                self.q, self.qd = segment.at(now - t0)
                return
            self.q = segment.end.pos.copy()
            self._segment = (self._pending.popleft(), t0 + segment.duration_s) if self._pending else None
        self.qd = np.zeros(self.n_joints)
