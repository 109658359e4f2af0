"""The numbers of the simple_message protocol as MotoROS defines them (``MotoPlus/SimpleMessage.h``).

Message types, header codes, MotoMotionCtrl commands, MotoMotionReply results and their subcodes. The
subcodes are what the controller puts in a reply when it says INVALID or NOT_READY; ``describe`` turns a
(result, subcode) pair into the words an operator needs.
"""

from __future__ import annotations

import enum


class MsgType(enum.IntEnum):
    """Message types MotoROS uses (``SmMsgType``)."""

    ROBOT_STATUS = 13
    JOINT_TRAJ_PT_FULL = 14
    JOINT_FEEDBACK = 15
    MOTO_MOTION_CTRL = 2001
    MOTO_MOTION_REPLY = 2002
    JOINT_TRAJ_PT_FULL_EX = 2016
    JOINT_FEEDBACK_EX = 2017


class CommType(enum.IntEnum):
    """How a packet travels: a topic (no answer) or a service request / reply (``SmCommType``)."""

    INVALID = 0
    TOPIC = 1
    SERVICE_REQUEST = 2
    SERVICE_REPLY = 3


class ReplyType(enum.IntEnum):
    """Header-level reply code; MotoROS always says SUCCESS and puts the real answer in the body."""

    INVALID = 0
    SUCCESS = 1
    FAILURE = 2


class Command(enum.IntEnum):
    """Commands of a MotoMotionCtrl request (``SmCommandType``)."""

    CHECK_MOTION_READY = 200101
    CHECK_QUEUE_CNT = 200102
    STOP_MOTION = 200111
    START_SERVOS = 200112
    STOP_SERVOS = 200113
    RESET_ALARM = 200114
    START_TRAJ_MODE = 200121
    STOP_TRAJ_MODE = 200122
    DISCONNECT = 200130


class Result(enum.IntEnum):
    """Body-level result of a MotoMotionReply (``SmResultType``): SUCCESS doubles as TRUE, FAILURE as FALSE."""

    SUCCESS = 0
    BUSY = 1
    FAILURE = 2
    INVALID = 3
    ALARM = 4
    NOT_READY = 5
    MP_FAILURE = 6

    TRUE = 0  # aliases, as in SimpleMessage.h: CHECK_MOTION_READY answers TRUE / FALSE
    FALSE = 2


class InvalidSubcode(enum.IntEnum):
    """Why a request was INVALID (``SmInvalidSubCode``)."""

    UNSPECIFIED = 3000
    MSGSIZE = 3001
    MSGHEADER = 3002
    MSGTYPE = 3003
    GROUPNO = 3004
    SEQUENCE = 3005
    COMMAND = 3006
    DATA = 3010
    DATA_START_POS = 3011
    DATA_POSITION = 3012
    DATA_SPEED = 3013
    DATA_ACCEL = 3014
    DATA_INSUFFICIENT = 3015
    DATA_TIME = 3016
    DATA_TOOLNO = 3017


class NotReadySubcode(enum.IntEnum):
    """Why the controller is NOT_READY (``SmNotReadySubcode``), in the order Controller.c tests them."""

    UNSPECIFIED = 5000
    ALARM = 5001
    ERROR = 5002
    ESTOP = 5003
    NOT_PLAY = 5004
    NOT_REMOTE = 5005
    SERVO_OFF = 5006
    HOLD = 5007
    NOT_STARTED = 5008
    WAITING_ROS = 5009
    SKILLSEND = 5010
    PFL_ACTIVE = 5011
    INC_MOVE_ERROR = 5012


SUBCODE_NAMES: dict[int, str] = {
    3000: "invalid (unspecified)", 3001: "invalid message size", 3002: "invalid message header",
    3003: "invalid message type", 3004: "invalid group number", 3005: "invalid sequence",
    3006: "invalid command", 3010: "invalid data", 3011: "start position does not match the robot",
    3012: "invalid position", 3013: "invalid speed", 3014: "invalid acceleration",
    3015: "insufficient data", 3016: "invalid time", 3017: "invalid tool number",
    5000: "not ready (unspecified)", 5001: "alarm active", 5002: "error active", 5003: "e-stop",
    5004: "not in play mode", 5005: "not in remote mode", 5006: "servo off", 5007: "hold",
    5008: "trajectory mode not started", 5009: "waiting for ROS", 5010: "skill send",
    5011: "PFL active", 5012: "incremental move rejected",
}

# NOT_READY causes START_TRAJ_MODE cannot fix: MotoROS returns at once and an operator must act
# (MotionServer.c, Ros_MotionServer_StartTrajMode: e-stop, hold, not remote; a job cannot start in teach mode).
OPERATOR_SUBCODES = frozenset({NotReadySubcode.ESTOP, NotReadySubcode.HOLD, NotReadySubcode.NOT_REMOTE,
                               NotReadySubcode.NOT_PLAY})


def describe(result: int, subcode: int) -> str:
    """Human-readable reply, e.g. ``NOT_READY (5003: e-stop)``."""
    name = Result(result).name if result in Result._value2member_map_ else str(result)
    if not subcode:
        return name
    return f"{name} ({subcode}: {SUBCODE_NAMES.get(subcode, 'unknown subcode')})"
