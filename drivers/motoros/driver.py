"""``RobotDriver`` for one motion group of a MotoROS controller.

A joint move is a two-point trajectory: point 0 is the current position at t = 0 (MotoROS rejects a start
that differs from where the arm is), point 1 is the target at t = T. Both points have zero velocity.
MotoROS joins points with a cubic Hermite, whose peak speed with zero end velocities is 1.5 times the mean
speed, so T = 1.5 * max_j |dq_j| / (speed_fraction * max_speed_j) keeps every joint at or below
``speed_fraction`` of its maximum speed. Points go out as JointTrajPtFull
(14) or, if asked, JointTrajPtFullEx (2016) with one group; a BUSY reply (queue full) is retried until the
reply timeout.

MotoROS's STOP_MOTION stops every group on the controller, not only this one.
"""

from __future__ import annotations

import logging
import time
from typing import Literal

import numpy as np

from drivers.base import JointState, RobotDriver, RobotStatus
from drivers.errors import DriverError, DriverTimeout, RobotFault
from drivers.motoros.codec import (Command, JointFeedback, JointTrajPtFull, JointTrajPtFullEx, MotionCtrl,
                                   MotionReply, MsgType, Result, RobotStatusMsg)
from drivers.motoros.link import MotorosLink

log = logging.getLogger("cellcal.drivers")

_SETTLE_SAMPLES = 3
CUBIC_PEAK_RATIO = 1.5  # peak / mean speed of a cubic Hermite segment with zero end velocities
_BUSY_RETRY_S = 0.01


def to_robot_status(msg: RobotStatusMsg) -> RobotStatus:
    """Map MotoROS tri-state flags to ``RobotStatus``; unknown (-1) counts as the unsafe value."""
    return RobotStatus(servo_on=msg.drives_powered == 1, alarm=msg.in_error != 0, e_stopped=msg.e_stopped != 0,
                       in_motion=msg.in_motion == 1, error_code=msg.error_code)


class MotorosDriver(RobotDriver):
    """One arm (motion group) on a MotoROS controller.

    Args:
        link: the controller's shared connections; several drivers may share one.
        group: motion group index (0 = R1, 1 = R2).
        max_speed_rad_s: maximum joint speeds [rad/s], shape (n_joints,).
        name: robot name used in messages; defaults to ``R{group + 1}``.
        trajectory_message: ``"full"`` sends JointTrajPtFull (14), ``"full_ex"`` JointTrajPtFullEx (2016).
    """

    def __init__(self, link: MotorosLink, group: int, max_speed_rad_s: np.ndarray, name: str | None = None,
                 trajectory_message: Literal["full", "full_ex"] = "full") -> None:
        self.max_speed_rad_s = np.asarray(max_speed_rad_s, dtype=float).ravel()
        if self.max_speed_rad_s.size == 0 or not np.all(self.max_speed_rad_s > 0):
            raise ValueError(f"max_speed_rad_s must be positive, got {self.max_speed_rad_s}")
        if trajectory_message not in ("full", "full_ex"):
            raise ValueError(f"trajectory_message must be 'full' or 'full_ex', got {trajectory_message!r}")
        if group < 0:
            raise ValueError(f"group must be >= 0, got {group}")
        self.link = link
        self.group = group
        self.name = name or f"R{group + 1}"
        self.n_joints = self.max_speed_rad_s.size
        self.trajectory_message = trajectory_message
        self.device = f"{link.motion_device}/{self.name}"
        self._connected = False
        self._sequence = 0
        self._target: np.ndarray | None = None

    def connect(self) -> None:
        """Connect the shared link and wait for this group's first feedback.

        Raises:
            DriverDisconnected: the controller cannot be reached.
            DriverTimeout: no feedback for this group (the controller may not have it).
        """
        if self._connected:
            return
        self.link.connect()
        deadline = time.monotonic() + self.link.connect_timeout_s
        while True:
            try:
                self.link.feedback(self.group)
                break
            except DriverError:
                if time.monotonic() > deadline:
                    self.link.close()
                    raise DriverTimeout(self.device, f"feedback of motion group {self.group}",
                                        self.link.connect_timeout_s) from None
                self.link.wait_state(0.05)
        self._connected = True

    def close(self) -> None:
        if self._connected:
            self._connected = False
            self.link.close()

    def read_joints(self) -> JointState:
        feedback, stamp = self.link.feedback(self.group)
        return JointState(q=feedback.pos[: self.n_joints].copy(), stamp=stamp)

    def status(self) -> RobotStatus:
        return to_robot_status(self.link.status()[0])

    def _check_ready(self) -> None:
        st = self.status()
        if not st.ready:
            why = [w for w, bad in (("servo off", not st.servo_on), (f"alarm {st.error_code}", st.alarm),
                                    ("e-stop", st.e_stopped)) if bad]
            raise RobotFault(self.device, f"motion refused: {', '.join(why)}")

    def _next_sequence(self) -> int:
        self._sequence += 1
        return self._sequence

    def _command(self, command: Command) -> MotionReply:
        seq = self._next_sequence()
        payload = MotionCtrl(self.group, seq, command).encode()
        reply = self.link.request(payload, self.group, seq, command)
        self._raise_for(reply, command.name)
        return reply

    def _raise_for(self, reply: MotionReply, what: str) -> None:
        if reply.result == Result.SUCCESS:
            return
        if reply.result in (Result.NOT_READY, Result.ALARM):
            raise RobotFault(self.device, f"{what} refused: {reply.describe()}")
        raise DriverError(self.device, f"{what} rejected: {reply.describe()}")

    def _send_point(self, sequence: int, time_s: float, q: np.ndarray) -> None:
        if self.trajectory_message == "full":
            payload = JointTrajPtFull(self.group, sequence, time_s, q).encode()
            msg_type = MsgType.JOINT_TRAJ_PT_FULL
        else:
            point = JointFeedback(self.group, q, time=time_s, valid_fields=7)
            payload = JointTrajPtFullEx(sequence, (point,)).encode()
            msg_type = MsgType.JOINT_TRAJ_PT_FULL_EX
        deadline = time.monotonic() + self.link.reply_timeout_s
        while True:
            reply = self.link.request(payload, self.group, sequence, msg_type)
            if reply.result != Result.BUSY:
                self._raise_for(reply, f"trajectory point {sequence}")
                return
            if time.monotonic() > deadline:
                raise DriverTimeout(self.device, f"room in the trajectory queue (point {sequence})",
                                    self.link.reply_timeout_s)
            time.sleep(_BUSY_RETRY_S)

    def move_to(self, q: np.ndarray, speed_fraction: float) -> None:
        """Start a joint move to ``q`` [rad] at ``speed_fraction`` of the maximum joint speeds.

        Raises:
            ValueError: ``q`` has the wrong shape or is not finite, or ``speed_fraction`` is outside (0, 1].
            RobotFault: servo off, alarm or e-stop (checked before anything is sent), or the controller
                refused trajectory mode.
            DriverError: the controller rejected a trajectory point (its subcode says why).
        """
        q = np.asarray(q, dtype=float)
        if q.shape != (self.n_joints,) or not np.all(np.isfinite(q)):
            raise ValueError(f"{self.name}: q must be {self.n_joints} finite joint angles [rad], got {q!r}")
        if not 0.0 < speed_fraction <= 1.0:
            raise ValueError(f"{self.name}: speed_fraction must be in (0, 1], got {speed_fraction}")
        self._check_ready()
        q_now = self.read_joints().q
        duration = CUBIC_PEAK_RATIO * float(np.max(np.abs(q - q_now) / (self.max_speed_rad_s * speed_fraction)))
        self._command(Command.START_TRAJ_MODE)
        self._sequence = 0
        self._send_point(0, 0.0, q_now)
        self._send_point(1, max(duration, 1e-3), q)
        self._target = q
        log.info("%s: moving to %s in %.3f s", self.name, np.round(q, 4), duration)

    def wait_settled(self, timeout_s: float, tolerance_rad: float = 1e-4) -> JointState:
        """Block until the arm is still (and at the last ``move_to`` target, if any, and no ``stop`` since).

        Still means ``_SETTLE_SAMPLES`` consecutive feedback samples within ``tolerance_rad`` of each other.

        Raises:
            DriverTimeout: not settled within ``timeout_s`` [s].
            RobotFault: an alarm or e-stop appeared while waiting.
        """
        deadline = time.monotonic() + timeout_s
        previous: JointState | None = None
        still = 0
        while time.monotonic() < deadline:
            state = self.read_joints()
            if previous is not None and state.stamp == previous.stamp:
                self.link.wait_state(min(0.05, max(deadline - time.monotonic(), 0.0)))
                continue
            st = self.status()
            if st.alarm or st.e_stopped:
                raise RobotFault(self.device, f"fault while moving (alarm={st.alarm}, "
                                              f"e_stopped={st.e_stopped}, code {st.error_code})")
            moved = previous is None or np.max(np.abs(state.q - previous.q)) > tolerance_rad
            at_target = self._target is None or np.max(np.abs(state.q - self._target)) <= tolerance_rad
            still = 0 if moved or not at_target else still + 1
            if still >= _SETTLE_SAMPLES:
                return state
            previous = state
            self.link.wait_state(min(0.05, max(deadline - time.monotonic(), 0.0)))
        raise DriverTimeout(self.device, f"{self.name} to settle within {tolerance_rad:g} rad", timeout_s)

    def stop(self) -> None:
        """Stop motion now (MotoROS stops every group on the controller) and forget the target."""
        self._target = None
        self._command(Command.STOP_MOTION)
