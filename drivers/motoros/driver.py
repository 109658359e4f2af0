"""``RobotDriver`` for one motion group of a MotoROS controller.

A joint move is a two-point trajectory: point 0 is the current feedback at t = 0 (MotoROS rejects a start
more than 30 encoder pulses from the commanded position: MotionServer.c, Ros_MotionServer_InitTrajPointFull,
START_MAX_PULSE_DEVIATION), point 1 is the target at t = T. Both points have zero velocity. MotoROS joins
points with a cubic Hermite, whose peak speed with zero end velocities is 1.5 times the mean speed, so
T = 1.5 * max_j |dq_j| / (speed_fraction * max_speed_j) keeps every joint at or below ``speed_fraction`` of
its maximum speed. Points go out as JointTrajPtFull (14) or, if asked, JointTrajPtFullEx (2016) with one
group; a BUSY reply (the group's point buffer still being interpolated) is retried until the reply timeout.

Before a move, as motoman_driver does it:

1. Refuse at once, sending nothing, on e-stop or teach mode (RobotStatus ``e_stopped``, ``mode``) or on an
   alarm (unless ``reset_alarms``): START_TRAJ_MODE cannot clear the first two and would silently reset
   the third. Servo off is *not* refused: START_TRAJ_MODE turns the servos on.
2. Refuse, sending nothing, when the joint feedback is NaN or infinite.
3. If RobotStatus says motion is not possible (or CHECK_MOTION_READY says FALSE for a cause it can fix),
   send START_TRAJ_MODE (resets alarms, servo on, starts the INIT_ROS job; may take ~10 s, hence its own
   ``start_traj_timeout_s``).
4. CHECK_MOTION_READY; FALSE carries the cause as a NOT_READY subcode (not remote, hold, ...).

MotoROS's STOP_MOTION stops every group on the controller, not only this one.
"""

from __future__ import annotations

import logging
import time
from typing import Literal

import numpy as np

from drivers.base import JointState, RobotDriver, RobotStatus
from drivers.errors import DriverDisconnected, DriverError, DriverTimeout, InvalidArgument, RobotFault
from drivers.motoros.codec import (
    JointFeedback,
    JointTrajPtFull,
    JointTrajPtFullEx,
    MotionCtrl,
    MotionReply,
    RobotStatusMsg,
    ValidFields,
)
from drivers.motoros.codes import OPERATOR_SUBCODES, Command, MsgType, NotReadySubcode, Result
from drivers.motoros.errors import ControllerNotReady, NonFiniteFeedback
from drivers.motoros.link import MotorosLink

log = logging.getLogger("cellcal.drivers")

_SETTLE_SAMPLES = 3
CUBIC_PEAK_RATIO = 1.5  # peak / mean speed of a cubic Hermite segment with zero end velocities
MAX_TRAJECTORY_TIME_S = 14400.0  # MotionServer.h MAX_TRAJECTORY_TIME_LENGTH: later points are INVALID (3016)
MODE_TEACH = 1  # RobotStatus.mode: 1 manual (TEACH), 2 auto (PLAY)
_BUSY_RETRY_S = 0.01
# [s] an alarm status this long after START_TRAJ_MODE's reply is live even if no clear status came between:
# many of the state server's periods (StateServer.c: one status per loop, then Ros_Sleep(STATE_UPDATE_MIN_PERIOD)),
# so not a stale packet still in flight
_STALE_STATUS_S = 0.5
_POINT_FIELDS = ValidFields.TIME | ValidFields.POSITION | ValidFields.VELOCITY  # the minimum MotoROS accepts


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
        reset_alarms: let START_TRAJ_MODE reset an active alarm (MotoROS does so); off by default, so an
            alarm refuses motion until someone has looked at it.
        start_traj_timeout_s: longest wait for START_TRAJ_MODE [s]; None uses the link's.

    Raises:
        InvalidArgument: a non-positive speed, a negative group or an unknown ``trajectory_message``.
    """

    def __init__(self, link: MotorosLink, group: int, max_speed_rad_s: np.ndarray, name: str | None = None,
                 trajectory_message: Literal["full", "full_ex"] = "full", *, reset_alarms: bool = False,
                 start_traj_timeout_s: float | None = None) -> None:
        self.name = name or f"R{group + 1}"
        self.device = f"{link.motion_device}/{self.name}"
        self.max_speed_rad_s = np.asarray(max_speed_rad_s, dtype=float).ravel()
        if self.max_speed_rad_s.size == 0 or not np.all(self.max_speed_rad_s > 0):
            raise InvalidArgument(self.device, "max_speed_rad_s", self.max_speed_rad_s, "positive [rad/s]")
        if trajectory_message not in ("full", "full_ex"):
            raise InvalidArgument(self.device, "trajectory_message", trajectory_message, "'full' or 'full_ex'")
        if group < 0:
            raise InvalidArgument(self.device, "group", group, ">= 0")
        if start_traj_timeout_s is not None and not start_traj_timeout_s > 0:
            raise InvalidArgument(self.device, "start_traj_timeout_s", start_traj_timeout_s, "positive [s] or None")
        self.start_traj_timeout_s = start_traj_timeout_s
        self.link = link
        self.group = group
        self.n_joints = self.max_speed_rad_s.size
        self.trajectory_message = trajectory_message
        self.reset_alarms = reset_alarms
        self._connected = False
        self._sequence = 0
        self._target: np.ndarray | None = None
        self._fresh_after = 0.0  # [s, monotonic] statuses older than this predate the last START_TRAJ_MODE
        self._clear_seen = True  # a status without alarm or e-stop arrived since the last START_TRAJ_MODE

    def connect(self) -> None:
        """Connect the shared link and wait for this group's first feedback.

        Called again on a connected driver (a collector recovering from a lost connection), it waits up to
        ``connect_timeout_s`` for the link's state connection to deliver fresh feedback again: the link
        reconnects by itself, e.g. after the controller was restarted.

        Raises:
            DriverDisconnected: the controller cannot be reached (again, within ``connect_timeout_s``).
            DriverTimeout: no feedback for this group (the controller may not have it).
        """
        if self._connected:
            self._await_feedback(reconnecting=True)
            return
        self.link.connect()
        try:
            self._await_feedback(reconnecting=False)
        except DriverError:
            self.link.close()
            raise
        self._connected = True

    def _await_feedback(self, reconnecting: bool) -> None:
        deadline = time.monotonic() + self.link.connect_timeout_s
        while True:
            try:
                self.link.feedback(self.group)
                return
            except DriverError as e:
                if time.monotonic() > deadline:
                    if reconnecting:
                        raise DriverDisconnected(self.device, f"no fresh feedback within "
                                                              f"{self.link.connect_timeout_s:g} s ({e.reason})") from e
                    raise DriverTimeout(self.device, f"feedback of motion group {self.group}",
                                        self.link.connect_timeout_s) from None
                self.link.wait_state(0.05)

    def close(self) -> None:
        """Release the link; the last driver on it ends trajectory mode (STOP_TRAJ_MODE)."""
        if self._connected:
            self._connected = False
            self.link.close()

    def read_joints(self) -> JointState:
        """Latest joint angles [rad]; raises NonFiniteFeedback when the controller reports NaN or inf."""
        feedback, stamp = self.link.feedback(self.group)
        q = feedback.pos[: self.n_joints].copy()
        if not np.all(np.isfinite(q)):
            raise NonFiniteFeedback(self.device, self.group, q)
        return JointState(q=q, stamp=stamp)

    def status(self) -> RobotStatus:
        return to_robot_status(self.link.status()[0])

    def queue_count(self) -> int:
        """Interpolation increments queued on the controller for this group (CHECK_QUEUE_CNT).

        MotoROS answers in the reply's subcode: TRUE with the count, or FAILURE with a negative count
        (invalid group, queue locked).
        """
        reply = self._command(Command.CHECK_QUEUE_CNT, check=False)
        if reply.result != Result.TRUE or reply.subcode < 0:
            raise DriverError(self.device, f"CHECK_QUEUE_CNT failed: {reply.describe()}")
        return reply.subcode

    def _refuse_early(self, msg: RobotStatusMsg) -> None:
        """Raise ControllerNotReady, before anything is sent, for what START_TRAJ_MODE must not (or cannot) fix."""
        st = to_robot_status(msg)
        why = [w for w, bad in (("e-stop", st.e_stopped), ("pendant in TEACH mode", msg.mode == MODE_TEACH),
                                (f"alarm {st.error_code}", st.alarm and not self.reset_alarms)) if bad]
        if why:
            raise ControllerNotReady(self.device, "motion refused", cause=", ".join(why))

    def _next_sequence(self) -> int:
        self._sequence += 1
        return self._sequence

    def _command(self, command: Command, check: bool = True, timeout_s: float | None = None) -> MotionReply:
        seq = self._next_sequence()
        reply = self.link.request(MotionCtrl(self.group, seq, command).encode(), self.group, seq, command,
                                  timeout_s=timeout_s)
        if check:
            self._raise_for(reply, command.name)
        return reply

    def _raise_for(self, reply: MotionReply, what: str) -> None:
        if reply.result == Result.SUCCESS:
            return
        if reply.result in (Result.NOT_READY, Result.ALARM):
            raise ControllerNotReady(self.device, f"{what} refused", reply.subcode, cause=reply.describe())
        raise DriverError(self.device, f"{what} rejected: {reply.describe()}")

    def _enter_trajectory_mode(self, msg: RobotStatusMsg) -> None:
        """START_TRAJ_MODE unless motion is possible, then CHECK_MOTION_READY (motoman_driver's order).

        The status may lag the controller: when it says motion is possible, CHECK_MOTION_READY is asked
        first, and a FALSE that START_TRAJ_MODE may fix (trajectory mode ended, servo off) starts it.
        """
        if msg.motion_possible == 1:
            ready = self._command(Command.CHECK_MOTION_READY, check=False)
            if ready.result == Result.TRUE:
                return
            self._refuse_unfixable(ready.subcode)
        self._command(Command.START_TRAJ_MODE, timeout_s=self.start_traj_timeout_s)
        self._fresh_after = time.monotonic()  # an alarm it reset may still be in the last status
        self._clear_seen = False
        ready = self._command(Command.CHECK_MOTION_READY, check=False)
        if ready.result != Result.TRUE:
            raise ControllerNotReady(self.device, "CHECK_MOTION_READY is FALSE", ready.subcode)

    def _refuse_unfixable(self, subcode: int) -> None:
        """ControllerNotReady for a CHECK_MOTION_READY subcode START_TRAJ_MODE cannot or must not fix."""
        resettable = (NotReadySubcode.ALARM, NotReadySubcode.ERROR)
        if subcode in OPERATOR_SUBCODES or (subcode in resettable and not self.reset_alarms):
            raise ControllerNotReady(self.device, "CHECK_MOTION_READY is FALSE", subcode)

    def _send_point(self, sequence: int, time_s: float, q: np.ndarray) -> None:
        if self.trajectory_message == "full":
            payload = JointTrajPtFull(self.group, sequence, time_s, q, valid_fields=_POINT_FIELDS).encode()
            msg_type = MsgType.JOINT_TRAJ_PT_FULL
        else:
            point = JointFeedback(self.group, q, time=time_s, valid_fields=_POINT_FIELDS)
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

    def _duration_s(self, q_from: np.ndarray, q_to: np.ndarray, speed_fraction: float) -> float:
        duration = CUBIC_PEAK_RATIO * float(np.max(np.abs(q_to - q_from) / (self.max_speed_rad_s * speed_fraction)))
        if duration >= MAX_TRAJECTORY_TIME_S:
            raise InvalidArgument(self.device, "speed_fraction", speed_fraction,
                                  f"large enough for a move shorter than {MAX_TRAJECTORY_TIME_S:g} s "
                                  f"(MotoROS limit; this one takes {duration:.0f} s)")
        return max(duration, 1e-3)

    def move_to(self, q: np.ndarray, speed_fraction: float) -> None:
        """Start a joint move to ``q`` [rad] at ``speed_fraction`` of the maximum joint speeds.

        Raises:
            InvalidArgument: ``q`` has the wrong shape or is not finite, or ``speed_fraction`` is outside (0, 1].
            NonFiniteFeedback: the joint feedback is NaN or inf (nothing is sent).
            ControllerNotReady: (a RobotFault) e-stop, teach mode or alarm (nothing sent), CHECK_MOTION_READY
                FALSE, or START_TRAJ_MODE / a point answered NOT_READY; ``subcode`` holds MotoROS's reason.
            DriverError: the controller rejected a trajectory point (its subcode says why).
        """
        q = np.asarray(q, dtype=float)
        if q.shape != (self.n_joints,) or not np.all(np.isfinite(q)):
            raise InvalidArgument(self.device, "q", q, f"{self.n_joints} finite joint angles [rad]")
        if not 0.0 < speed_fraction <= 1.0:
            raise InvalidArgument(self.device, "speed_fraction", speed_fraction, "in (0, 1]")
        msg, _ = self.link.status()
        self._refuse_early(msg)
        self._duration_s(self.read_joints().q, q, speed_fraction)  # NaN feedback / too long: before sending
        self._enter_trajectory_mode(msg)
        q_now = self.read_joints().q  # after a servo-on the arm may have settled on its brakes
        duration = self._duration_s(q_now, q, speed_fraction)
        self._sequence = 0
        self._send_point(0, 0.0, q_now)
        self._send_point(1, duration, q)
        self._target = q
        log.info("%s: moving to %s in %.3f s", self.name, np.round(q, 4), duration)

    def wait_settled(self, timeout_s: float, tolerance_rad: float = 1e-4) -> JointState:
        """Block until the arm is still (and at the last ``move_to`` target, if any, and no ``stop`` since).

        Still means ``_SETTLE_SAMPLES`` consecutive feedback samples within ``tolerance_rad`` of each other.

        Raises:
            DriverTimeout: not settled within ``timeout_s`` [s].
            RobotFault: an alarm or e-stop appeared while waiting.
            NonFiniteFeedback: the feedback became NaN or inf.
        """
        deadline = time.monotonic() + timeout_s
        previous: JointState | None = None
        still = 0
        while time.monotonic() < deadline:
            state = self.read_joints()
            if previous is not None and state.stamp == previous.stamp:
                self.link.wait_state(min(0.05, max(deadline - time.monotonic(), 0.0)))
                continue
            msg, stamp = self.link.status()
            st = to_robot_status(msg)
            if not (st.alarm or st.e_stopped):
                self._clear_seen = self._clear_seen or stamp >= self._fresh_after
            elif self._live_fault(stamp):
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

    def _live_fault(self, stamp: float) -> bool:
        """Whether an alarm or e-stop status that arrived at ``stamp`` [s, monotonic] is live.

        The state connection is not the motion connection: a status the controller sent just before
        START_TRAJ_MODE reset its alarm can arrive after the reply. Such a status is stale. After a
        START_TRAJ_MODE an alarm counts once a clear status has been seen since, or once it has lasted
        ``_STALE_STATUS_S`` (the reset did not take).
        """
        if stamp < self._fresh_after:
            return False
        return self._clear_seen or stamp - self._fresh_after >= _STALE_STATUS_S

    def stop(self) -> None:
        """Stop motion now (MotoROS stops every group on the controller) and forget the target."""
        self._target = None
        self._command(Command.STOP_MOTION)
