"""What a MotoROS controller answers, without the sockets: the fake controller's protocol logic.

Each answer follows MotoPlus/MotionServer.c and Controller.c (ros-industrial/motoman, MotoROS 1.9):

* NOT_READY subcodes in Ros_Controller_GetNotReadySubcode's order: alarm 5001, e-stop 5003, not play 5004,
  not remote 5005, servo off 5006, hold 5007, trajectory mode not started 5008.
* START_TRAJ_MODE (Ros_MotionServer_StartTrajMode): TRUE at once if motion is already possible; NOT_READY
  on e-stop, hold or not remote (an operator must act); otherwise resets the alarm, turns the servos on
  (waiting for the confirmation: ``servo_on_delay_s`` here, seconds on a real controller) and starts the
  INIT_ROS job, which cannot run in teach mode.
* CHECK_MOTION_READY: TRUE (0), or FALSE (2) with the NOT_READY subcode.
* CHECK_QUEUE_CNT: TRUE with the queued increments *in the subcode*, FAILURE with -1 for a bad group.
* STOP_MOTION clears every queue (trajectory mode stays); STOP_TRAJ_MODE / DISCONNECT fail (FAILURE) while a
  queue holds motion, else end trajectory mode.
* Trajectory points: NOT_READY unless trajectory mode runs, then group (3004), valid fields time + position
  + velocity (3015), time below 4 h (3016, JointTrajPtFull only), sequence >= 0 (3005); see fake_arm for the
  point itself. An alarm, e-stop, servo off, hold, teach mode or leaving remote ends trajectory mode and
  clears the queues (Ros_Controller_StatusUpdate).

Two liberties: an unknown MotoMotionCtrl command is answered INVALID 3006 (MotoROS sends back a stale
buffer), and non-finite point positions are answered INVALID 3012 (MotoROS converts them to garbage pulses).
"""

from __future__ import annotations

import threading
from collections.abc import Callable

import numpy as np

from drivers.motoros.codec import (
    JointFeedback,
    JointTrajPtFull,
    JointTrajPtFullEx,
    Message,
    MotionCtrl,
    MotionReply,
    RobotStatusMsg,
    ValidFields,
)
from drivers.motoros.codes import Command, InvalidSubcode, NotReadySubcode, Result
from drivers.motoros.fake_arm import SimulatedGroup

MAX_TRAJECTORY_TIME_S = 14400.0  # MotionServer.h MAX_TRAJECTORY_TIME_LENGTH
_MIN_FIELDS = ValidFields.TIME | ValidFields.POSITION | ValidFields.VELOCITY
_Answer = tuple[Result, int]


class SimulatedController:
    """Status flags, motion groups and the answers of one MotoROS controller; thread-safe (one lock).

    Args:
        groups: the simulated motion groups, index = MotoROS group number.
        servo_on_delay_s: time START_TRAJ_MODE / START_SERVOS take to turn the servos on [s].
        wait: sleeps for a time [s] and returns True when the fake is shutting down (``Event.wait``).
    """

    def __init__(self, groups: list[SimulatedGroup], servo_on_delay_s: float,
                 wait: Callable[[float], bool]) -> None:
        self.groups = groups
        self.servo_on_delay_s = servo_on_delay_s
        self._wait = wait
        self.lock = threading.RLock()
        self.servo_on = True
        self.e_stopped = False
        self.alarm_code = 0
        self.alarm_resettable = True
        self.play = True
        self.remote = True
        self.hold = False
        self.traj_mode = False  # INIT_ROS job running and waiting for ROS: "motion ready"

    # -- status ------------------------------------------------------------------------------------
    def not_ready_subcode(self) -> int:
        """Ros_Controller_GetNotReadySubcode; 0 when motion is possible (caller holds the lock)."""
        for bad, code in ((self.alarm_code != 0, NotReadySubcode.ALARM), (self.e_stopped, NotReadySubcode.ESTOP),
                          (not self.play, NotReadySubcode.NOT_PLAY), (not self.remote, NotReadySubcode.NOT_REMOTE),
                          (not self.servo_on, NotReadySubcode.SERVO_OFF), (self.hold, NotReadySubcode.HOLD),
                          (not self.traj_mode, NotReadySubcode.NOT_STARTED)):
            if bad:
                return int(code)
        return 0

    def faulted(self) -> bool:
        """A condition that stops the INIT_ROS job is present (caller holds the lock)."""
        return bool(self.alarm_code or self.e_stopped or not self.play or not self.remote or not self.servo_on
                    or self.hold)

    def halt_if_faulted(self) -> None:
        """End trajectory mode and clear the queues when a fault is present (caller holds the lock)."""
        if self.faulted():
            self.traj_mode = False
            self.clear_queues()

    def clear_queues(self) -> None:
        for group in self.groups:
            group.halt()

    def status(self) -> RobotStatusMsg:
        """The RobotStatus MotoROS publishes (Ros_Controller_StatusToMsg)."""
        with self.lock:
            return RobotStatusMsg(drives_powered=int(self.servo_on), e_stopped=int(self.e_stopped),
                                  error_code=self.alarm_code, in_error=int(self.alarm_code != 0),
                                  in_motion=int(any(g.moving for g in self.groups)), mode=2 if self.play else 1,
                                  motion_possible=int(self.traj_mode and not self.faulted()))

    # -- requests ----------------------------------------------------------------------------------
    def answer(self, msg: Message) -> tuple[MotionReply, bool]:
        """The reply to one request, and whether the connection closes after it (DISCONNECT)."""
        if isinstance(msg, MotionCtrl):
            result, sub = self._control(msg.group, msg.command)
            return MotionReply(msg.group, msg.sequence, msg.command, result, sub), \
                msg.command == Command.DISCONNECT and result == Result.SUCCESS
        with self.lock:
            if isinstance(msg, JointTrajPtFull):
                result, sub = self._point(msg.group, msg.sequence, msg, check_time=True)
                return MotionReply(msg.group, msg.sequence, msg.TYPE, result, sub), False
            if isinstance(msg, JointTrajPtFullEx):
                group, (result, sub) = self._points_ex(msg)
                return MotionReply(group, msg.sequence, msg.TYPE, result, sub), False
        return MotionReply(-1, -1, msg.TYPE, Result.INVALID, InvalidSubcode.MSGTYPE), False

    def _control(self, group: int, command: int) -> _Answer:
        if command == Command.START_TRAJ_MODE:
            return self.start_traj_mode()
        if command == Command.START_SERVOS:
            return (Result.SUCCESS, 0) if self.servo_power_on() else (Result.FAILURE, 0)
        with self.lock:
            if command == Command.CHECK_MOTION_READY:
                sub = self.not_ready_subcode()
                return (Result.FALSE, sub) if sub else (Result.TRUE, 0)
            if command == Command.CHECK_QUEUE_CNT:
                if not 0 <= group < len(self.groups):
                    return Result.FAILURE, -1
                return Result.TRUE, self.groups[group].queue_count()
            if command == Command.STOP_MOTION:
                self.clear_queues()
                return Result.SUCCESS, 0
            if command == Command.STOP_SERVOS:
                self.clear_queues()
                self.servo_on = False
                self.halt_if_faulted()
                return Result.SUCCESS, 0
            if command == Command.RESET_ALARM:
                if self.alarm_code and not self.alarm_resettable:
                    return Result.FAILURE, 0
                self.alarm_code = 0
                return Result.SUCCESS, 0
            if command in (Command.STOP_TRAJ_MODE, Command.DISCONNECT):
                if any(g.moving for g in self.groups):
                    return Result.FAILURE, 0
                self.clear_queues()
                self.traj_mode = False
                return Result.SUCCESS, 0
        return Result.INVALID, InvalidSubcode.COMMAND

    def _operator_needed(self) -> bool:
        return self.e_stopped or self.hold or not self.remote

    def servo_power_on(self) -> bool:
        """Turn the servos on after ``servo_on_delay_s``; False on e-stop (the lock is not held while waiting)."""
        with self.lock:
            if self.servo_on:
                return True
            if self.e_stopped:
                return False
        if self._wait(self.servo_on_delay_s):
            return False
        with self.lock:
            self.servo_on = not self.e_stopped
            return self.servo_on

    def start_traj_mode(self) -> _Answer:
        """Ros_MotionServer_StartTrajMode, reply included."""
        with self.lock:
            if self.traj_mode and not self.faulted():
                return Result.SUCCESS, 0
            if self._operator_needed():
                return Result.NOT_READY, self.not_ready_subcode()
            if self.alarm_code and self.alarm_resettable:
                self.alarm_code = 0
            if self.alarm_code:
                return Result.NOT_READY, self.not_ready_subcode()
        if not self.servo_power_on():
            with self.lock:
                return Result.NOT_READY, self.not_ready_subcode() or NotReadySubcode.SERVO_OFF
        with self.lock:
            if self.faulted():  # e.g. teach mode: the INIT_ROS job cannot start
                return Result.NOT_READY, self.not_ready_subcode()
            self.clear_queues()
            self.traj_mode = True
            return Result.SUCCESS, 0

    def _point(self, group: int, sequence: int, point: JointTrajPtFull | JointFeedback,
               check_time: bool) -> _Answer:
        """One group's point (caller holds the lock)."""
        sub = self.not_ready_subcode()
        if sub:
            return Result.NOT_READY, sub
        if not 0 <= group < len(self.groups):
            return Result.INVALID, InvalidSubcode.GROUPNO
        if point.valid_fields & _MIN_FIELDS != _MIN_FIELDS:
            return Result.INVALID, InvalidSubcode.DATA_INSUFFICIENT
        if check_time and point.time >= MAX_TRAJECTORY_TIME_S:
            return Result.INVALID, InvalidSubcode.DATA_TIME
        if not (np.all(np.isfinite(point.pos)) and np.all(np.isfinite(point.vel)) and np.isfinite(point.time)):
            return Result.INVALID, InvalidSubcode.DATA_POSITION
        arm = self.groups[group]
        if sequence == 0:
            return arm.start_trajectory(point.time, point.pos, point.vel)
        if sequence > 0:
            return arm.add_point(point.time, point.pos, point.vel)
        return Result.INVALID, InvalidSubcode.SEQUENCE

    def _points_ex(self, msg: JointTrajPtFullEx) -> tuple[int, _Answer]:
        """Ros_MotionServer_JointTrajPtFullExProcess: pre-check every group, then play them in order."""
        last = msg.groups[-1].group
        sub = self.not_ready_subcode()
        if sub:
            return last, (Result.NOT_READY, sub)
        for point in msg.groups:
            if not 0 <= point.group < len(self.groups):
                return point.group, (Result.INVALID, InvalidSubcode.GROUPNO)
            if self.groups[point.group].busy:
                return point.group, (Result.BUSY, 0)
            if point.valid_fields & _MIN_FIELDS != _MIN_FIELDS:
                return point.group, (Result.INVALID, InvalidSubcode.DATA_INSUFFICIENT)
        answer: _Answer = (Result.SUCCESS, 0)
        for point in msg.groups:
            answer = self._point(point.group, msg.sequence, point, check_time=False)
            if answer[0] != Result.SUCCESS:
                return point.group, answer
        return last, answer
