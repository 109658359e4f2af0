"""Encode and decode the simple_message packets MotoROS speaks.

Every packet is little-endian: an int32 *length* (bytes that follow it), an int32 header triple
``msg_type, comm_type, reply_type``, then a body whose layout depends on ``msg_type``. Joint data always
carries ``MAX_JOINTS`` (10) float32 slots per group; unused slots are zero. Layouts, as MotoROS packs them:

==================  =====  ============================================================================
message             type   body (i = int32, f = float32)
==================  =====  ============================================================================
RobotStatus           13   i drives_powered, e_stopped, error_code, in_error, in_motion, mode,
                           motion_possible (tri-state: -1 unknown, 0 false, 1 true)            28 B
JointTrajPtFull       14   i group, sequence, valid_fields; f time; f pos[10], vel[10], acc[10]  136 B
JointFeedback         15   i group, valid_fields; f time; f pos[10], vel[10], acc[10]            132 B
MotoMotionCtrl      2001   i group, sequence, command; f data[10]                                 52 B
MotoMotionReply     2002   i group, sequence, command, result, subcode; f data[10]                60 B
JointTrajPtFullEx   2016   i n_groups, sequence; then n_groups x (i group, valid_fields; f time;
                           f pos[10], vel[10], acc[10])                               8 + 132 n B
JointFeedbackEx     2017   i n_groups; then 4 slots shaped like JointFeedback (unused zeroed)    532 B
==================  =====  ============================================================================

Type 11 (industrial_core's JointTrajPt) is not accepted by MotoROS, so it is not implemented here. The
numbers (types, commands, results, subcodes) live in ``codes.py`` and are re-exported here.
"""

from __future__ import annotations

import enum
import struct
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from drivers.errors import ProtocolError
from drivers.motoros.codes import (
    SUBCODE_NAMES,
    Command,
    CommType,
    InvalidSubcode,
    MsgType,
    NotReadySubcode,
    ReplyType,
    Result,
    describe,
)

MAX_JOINTS = 10
MAX_GROUPS = 4
CODEC_DEVICE = "simple_message"

_PREFIX = struct.Struct("<i")
_HEADER = struct.Struct("<iii")
_JOINTS = struct.Struct(f"<{3 * MAX_JOINTS}f")
_FEEDBACK_HEAD = struct.Struct("<iif")
_FEEDBACK_SIZE = _FEEDBACK_HEAD.size + _JOINTS.size


__all__ = ["CODEC_DEVICE", "Command", "CommType", "InvalidSubcode", "JointFeedback", "JointFeedbackEx",
           "JointTrajPtFull", "JointTrajPtFullEx", "MAX_GROUPS", "MAX_JOINTS", "Message", "MotionCtrl",
           "MotionReply", "MsgType", "NotReadySubcode", "Packet", "ReplyType", "Result", "RobotStatusMsg",
           "SUBCODE_NAMES", "ValidFields", "decode"]


class ValidFields(enum.IntFlag):
    """Which optional fields of a joint packet carry data (``FlagsValidFields``)."""

    TIME = 1
    POSITION = 2
    VELOCITY = 4
    ACCELERATION = 8


def _joints(values: np.ndarray | None) -> np.ndarray:
    """Pad joint values to ``MAX_JOINTS`` float slots; raises ProtocolError when there are too many."""
    out = np.zeros(MAX_JOINTS)
    if values is not None:
        arr = np.asarray(values, dtype=float).ravel()
        if arr.size > MAX_JOINTS:
            raise ProtocolError(CODEC_DEVICE, f"{arr.size} joint values, at most {MAX_JOINTS} fit a packet")
        out[: arr.size] = arr
    return out


def _check_size(body: bytes, expected: int, what: str) -> None:
    if len(body) != expected:
        raise ProtocolError(CODEC_DEVICE, f"{what} body is {len(body)} bytes, expected {expected}")


@dataclass(frozen=True)
class Packet:
    """One framed packet: the header triple and the raw body."""

    msg_type: int
    comm_type: int
    reply_type: int
    body: bytes

    def to_bytes(self) -> bytes:
        """The packet with its length prefix, ready for the socket."""
        return (_PREFIX.pack(_HEADER.size + len(self.body))
                + _HEADER.pack(self.msg_type, self.comm_type, self.reply_type) + self.body)

    @classmethod
    def from_frame(cls, frame: bytes) -> Packet:
        """Parse the bytes after the length prefix; raises ProtocolError when shorter than a header."""
        if len(frame) < _HEADER.size:
            raise ProtocolError(CODEC_DEVICE, f"frame of {len(frame)} bytes is shorter than a header")
        msg_type, comm_type, reply_type = _HEADER.unpack_from(frame)
        return cls(msg_type, comm_type, reply_type, body=bytes(frame[_HEADER.size:]))


@dataclass(frozen=True)
class RobotStatusMsg:
    """Controller status (type 13); each flag is -1 unknown, 0 false, 1 true; ``mode`` 1 teach, 2 play."""

    TYPE: ClassVar[MsgType] = MsgType.ROBOT_STATUS
    _S: ClassVar[struct.Struct] = struct.Struct("<7i")
    drives_powered: int = -1
    e_stopped: int = -1
    error_code: int = 0
    in_error: int = -1
    in_motion: int = -1
    mode: int = -1
    motion_possible: int = -1

    def encode(self) -> bytes:
        body = self._S.pack(self.drives_powered, self.e_stopped, self.error_code, self.in_error,
                            self.in_motion, self.mode, self.motion_possible)
        return Packet(self.TYPE, CommType.TOPIC, ReplyType.INVALID, body).to_bytes()

    @classmethod
    def decode(cls, body: bytes) -> RobotStatusMsg:
        _check_size(body, cls._S.size, "RobotStatus")
        return cls(*cls._S.unpack(body))


@dataclass(frozen=True, eq=False)
class JointFeedback:
    """Joint feedback of one group (type 15, and one slot of type 2017).

    Attributes:
        group: motion group index (0 = first robot).
        time: controller time stamp [s] (valid when ``ValidFields.TIME`` is set).
        pos, vel, acc: [rad], [rad/s], [rad/s^2], shape (10,).
    """

    TYPE: ClassVar[MsgType] = MsgType.JOINT_FEEDBACK
    group: int
    pos: np.ndarray
    vel: np.ndarray = field(default_factory=lambda: np.zeros(MAX_JOINTS))
    acc: np.ndarray = field(default_factory=lambda: np.zeros(MAX_JOINTS))
    time: float = 0.0
    valid_fields: int = ValidFields.POSITION

    def body(self) -> bytes:
        return (_FEEDBACK_HEAD.pack(self.group, self.valid_fields, self.time)
                + _JOINTS.pack(*_joints(self.pos), *_joints(self.vel), *_joints(self.acc)))

    def encode(self) -> bytes:
        return Packet(self.TYPE, CommType.TOPIC, ReplyType.INVALID, self.body()).to_bytes()

    @classmethod
    def decode(cls, body: bytes) -> JointFeedback:
        _check_size(body, _FEEDBACK_SIZE, "JointFeedback")
        group, valid, time = _FEEDBACK_HEAD.unpack_from(body)
        j = np.array(_JOINTS.unpack_from(body, _FEEDBACK_HEAD.size))
        return cls(group, j[:10], j[10:20], j[20:], float(time), valid)


@dataclass(frozen=True, eq=False)
class JointFeedbackEx:
    """Feedback of several groups in one packet (type 2017); MotoROS always sends 4 slots."""

    TYPE: ClassVar[MsgType] = MsgType.JOINT_FEEDBACK_EX
    groups: tuple[JointFeedback, ...]

    def encode(self) -> bytes:
        if len(self.groups) > MAX_GROUPS:
            raise ProtocolError(CODEC_DEVICE, f"{len(self.groups)} groups, at most {MAX_GROUPS}")
        slots = b"".join(g.body() for g in self.groups) + bytes(_FEEDBACK_SIZE * (MAX_GROUPS - len(self.groups)))
        body = _PREFIX.pack(len(self.groups)) + slots
        return Packet(self.TYPE, CommType.TOPIC, ReplyType.INVALID, body).to_bytes()

    @classmethod
    def decode(cls, body: bytes) -> JointFeedbackEx:
        _check_size(body, 4 + MAX_GROUPS * _FEEDBACK_SIZE, "JointFeedbackEx")
        (n,) = _PREFIX.unpack_from(body)
        if not 0 <= n <= MAX_GROUPS:
            raise ProtocolError(CODEC_DEVICE, f"JointFeedbackEx claims {n} groups, expected 0..{MAX_GROUPS}")
        return cls(tuple(JointFeedback.decode(body[4 + i * _FEEDBACK_SIZE: 4 + (i + 1) * _FEEDBACK_SIZE])
                         for i in range(n)))


@dataclass(frozen=True, eq=False)
class JointTrajPtFull:
    """One trajectory point for one group (type 14); ``time`` [s] from the trajectory start."""

    TYPE: ClassVar[MsgType] = MsgType.JOINT_TRAJ_PT_FULL
    _HEAD: ClassVar[struct.Struct] = struct.Struct("<iiif")
    group: int
    sequence: int
    time: float
    pos: np.ndarray
    vel: np.ndarray = field(default_factory=lambda: np.zeros(MAX_JOINTS))
    acc: np.ndarray = field(default_factory=lambda: np.zeros(MAX_JOINTS))
    valid_fields: int = ValidFields.TIME | ValidFields.POSITION | ValidFields.VELOCITY

    def encode(self) -> bytes:
        body = (self._HEAD.pack(self.group, self.sequence, self.valid_fields, self.time)
                + _JOINTS.pack(*_joints(self.pos), *_joints(self.vel), *_joints(self.acc)))
        return Packet(self.TYPE, CommType.SERVICE_REQUEST, ReplyType.INVALID, body).to_bytes()

    @classmethod
    def decode(cls, body: bytes) -> JointTrajPtFull:
        _check_size(body, cls._HEAD.size + _JOINTS.size, "JointTrajPtFull")
        group, seq, valid, time = cls._HEAD.unpack_from(body)
        j = np.array(_JOINTS.unpack_from(body, cls._HEAD.size))
        return cls(group, seq, float(time), j[:10], j[10:20], j[20:], valid)


@dataclass(frozen=True, eq=False)
class JointTrajPtFullEx:
    """One trajectory point for several groups (type 2016); each group entry reuses JointFeedback's shape."""

    TYPE: ClassVar[MsgType] = MsgType.JOINT_TRAJ_PT_FULL_EX
    sequence: int
    groups: tuple[JointFeedback, ...]

    def encode(self) -> bytes:
        if not 1 <= len(self.groups) <= MAX_GROUPS:
            raise ProtocolError(CODEC_DEVICE, f"{len(self.groups)} groups, expected 1..{MAX_GROUPS}")
        body = struct.pack("<ii", len(self.groups), self.sequence) + b"".join(g.body() for g in self.groups)
        return Packet(self.TYPE, CommType.SERVICE_REQUEST, ReplyType.INVALID, body).to_bytes()

    @classmethod
    def decode(cls, body: bytes) -> JointTrajPtFullEx:
        if len(body) < 8:
            raise ProtocolError(CODEC_DEVICE, f"JointTrajPtFullEx body is {len(body)} bytes, expected >= 8")
        n, seq = struct.unpack_from("<ii", body)
        if not 1 <= n <= MAX_GROUPS:
            raise ProtocolError(CODEC_DEVICE, f"JointTrajPtFullEx claims {n} groups, expected 1..{MAX_GROUPS}")
        if len(body) != 8 + MAX_GROUPS * _FEEDBACK_SIZE:  # MotoROS accepts all 4 slots or just n of them
            _check_size(body, 8 + n * _FEEDBACK_SIZE, "JointTrajPtFullEx")
        return cls(seq, tuple(JointFeedback.decode(body[8 + i * _FEEDBACK_SIZE: 8 + (i + 1) * _FEEDBACK_SIZE])
                              for i in range(n)))


@dataclass(frozen=True)
class MotionCtrl:
    """A motion-control request (type 2001); ``sequence`` is echoed in the reply."""

    TYPE: ClassVar[MsgType] = MsgType.MOTO_MOTION_CTRL
    _HEAD: ClassVar[struct.Struct] = struct.Struct("<iii")
    group: int
    sequence: int
    command: int

    def encode(self) -> bytes:
        body = self._HEAD.pack(self.group, self.sequence, self.command) + bytes(4 * MAX_JOINTS)
        return Packet(self.TYPE, CommType.SERVICE_REQUEST, ReplyType.INVALID, body).to_bytes()

    @classmethod
    def decode(cls, body: bytes) -> MotionCtrl:
        _check_size(body, cls._HEAD.size + 4 * MAX_JOINTS, "MotoMotionCtrl")
        return cls(*cls._HEAD.unpack_from(body))


@dataclass(frozen=True)
class MotionReply:
    """The answer to a MotionCtrl or a trajectory point (type 2002).

    ``command`` is the request's command, or the message type (14, 2016) for a trajectory point.
    """

    TYPE: ClassVar[MsgType] = MsgType.MOTO_MOTION_REPLY
    _HEAD: ClassVar[struct.Struct] = struct.Struct("<iiiii")
    group: int
    sequence: int
    command: int
    result: int
    subcode: int = 0
    data: tuple[float, ...] = ()  # unused by MotoROS ("for future use"); CHECK_QUEUE_CNT answers in subcode

    def encode(self) -> bytes:
        body = (self._HEAD.pack(self.group, self.sequence, self.command, self.result, self.subcode)
                + struct.pack(f"<{MAX_JOINTS}f", *_joints(np.array(self.data))))
        return Packet(self.TYPE, CommType.SERVICE_REPLY, ReplyType.SUCCESS, body).to_bytes()

    @classmethod
    def decode(cls, body: bytes) -> MotionReply:
        _check_size(body, cls._HEAD.size + 4 * MAX_JOINTS, "MotoMotionReply")
        data = struct.unpack_from(f"<{MAX_JOINTS}f", body, cls._HEAD.size)
        group, sequence, command, result, subcode = cls._HEAD.unpack_from(body)
        return cls(group, sequence, command, result, subcode, data=tuple(float(x) for x in data))

    def describe(self) -> str:
        """Human-readable result, e.g. ``NOT_READY (5003: e-stop)``."""
        return describe(self.result, self.subcode)


Message = (RobotStatusMsg | JointFeedback | JointFeedbackEx | JointTrajPtFull | JointTrajPtFullEx
           | MotionCtrl | MotionReply)
_DECODERS: dict[int, Callable[[bytes], Message]] = {cls.TYPE: cls.decode for cls in (RobotStatusMsg, JointFeedback, JointFeedbackEx,
                                              JointTrajPtFull, JointTrajPtFullEx, MotionCtrl, MotionReply)}


def decode(packet: Packet) -> Message:
    """Typed message of a packet; raises ProtocolError for an unknown type or a body of the wrong size."""
    decoder = _DECODERS.get(packet.msg_type)
    if decoder is None:
        known = ", ".join(f"{t.value} ({t.name})" for t in MsgType)
        raise ProtocolError(CODEC_DEVICE, f"unknown message type {packet.msg_type}; known: {known}")
    return decoder(packet.body)
