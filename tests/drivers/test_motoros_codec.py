"""simple_message codec and framer: byte-exact layouts, round trips, partial reads, corrupt streams."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from drivers.errors import ProtocolError
from drivers.motoros.codec import (
    JointFeedback,
    JointFeedbackEx,
    JointTrajPtFull,
    JointTrajPtFullEx,
    MotionCtrl,
    MotionReply,
    Packet,
    RobotStatusMsg,
    decode,
)
from drivers.motoros.codes import Command, MsgType, Result
from drivers.motoros.framing import Framer

Q = np.arange(1, 7) * 0.125  # exactly representable in float32


def _roundtrip(raw: bytes):
    packets = Framer("test").feed(raw)
    assert len(packets) == 1
    return decode(packets[0])


def _joints(pos, vel=(), acc=()) -> bytes:
    pad = lambda v: list(v) + [0.0] * (10 - len(v))  # noqa: E731
    return struct.pack("<30f", *pad(pos), *pad(vel), *pad(acc))


def test_robot_status_layout_and_roundtrip() -> None:
    msg = RobotStatusMsg(drives_powered=1, e_stopped=0, error_code=4107, in_error=1, in_motion=0, mode=2,
                         motion_possible=0)
    raw = msg.encode()
    assert raw == struct.pack("<4i7i", 40, 13, 1, 0, 1, 0, 4107, 1, 0, 2, 0)
    assert _roundtrip(raw) == msg


def test_joint_feedback_layout_and_roundtrip() -> None:
    msg = JointFeedback(1, Q, vel=-Q, time=2.5, valid_fields=7)
    raw = msg.encode()
    assert raw == struct.pack("<4iiif", 144, 15, 1, 0, 1, 7, 2.5) + _joints(Q, -Q)
    back = _roundtrip(raw)
    assert (back.group, back.time, back.valid_fields) == (1, 2.5, 7)
    np.testing.assert_array_equal(back.pos[:6], Q)
    np.testing.assert_array_equal(back.vel[:6], -Q)
    np.testing.assert_array_equal(back.pos[6:], 0.0)


def test_joint_feedback_ex_always_carries_four_slots() -> None:
    msg = JointFeedbackEx((JointFeedback(0, Q), JointFeedback(1, -Q)))
    raw = msg.encode()
    assert len(raw) == 4 + 544 and struct.unpack_from("<5i", raw) == (544, 2017, 1, 0, 2)
    slot = 20 + 132  # prefix, header triple and group count, then group 0's slot
    assert raw[slot:slot + 132] == JointFeedback(1, -Q).encode()[16:]
    assert raw[slot + 132:] == bytes(2 * 132)
    back = _roundtrip(raw)
    assert [g.group for g in back.groups] == [0, 1]
    np.testing.assert_array_equal(back.groups[1].pos[:6], -Q)


def test_joint_traj_pt_full_layout_and_roundtrip() -> None:
    msg = JointTrajPtFull(group=1, sequence=3, time=0.75, pos=Q)
    raw = msg.encode()
    assert raw == struct.pack("<4iiiif", 148, 14, 2, 0, 1, 3, 7, 0.75) + _joints(Q)
    back = _roundtrip(raw)
    assert (back.group, back.sequence, back.time, back.valid_fields) == (1, 3, 0.75, 7)
    np.testing.assert_array_equal(back.pos[:6], Q)


def test_joint_traj_pt_full_ex_is_sized_by_its_groups() -> None:
    msg = JointTrajPtFullEx(sequence=1, groups=(JointFeedback(0, Q, time=1.0, valid_fields=7),
                                                JointFeedback(1, -Q, time=1.0, valid_fields=7)))
    raw = msg.encode()
    assert struct.unpack_from("<6i", raw) == (12 + 8 + 2 * 132, 2016, 2, 0, 2, 1)
    assert raw[24:24 + 12] == struct.pack("<iif", 0, 7, 1.0)
    back = _roundtrip(raw)
    assert back.sequence == 1 and [g.group for g in back.groups] == [0, 1]
    np.testing.assert_array_equal(back.groups[1].pos[:6], -Q)


def test_motion_ctrl_and_reply_layouts() -> None:
    ctrl = MotionCtrl(group=1, sequence=9, command=Command.START_TRAJ_MODE)
    assert ctrl.encode() == struct.pack("<7i", 64, 2001, 2, 0, 1, 9, 200121) + bytes(40)
    assert _roundtrip(ctrl.encode()) == ctrl
    reply = MotionReply(1, 9, Command.START_TRAJ_MODE, Result.NOT_READY, 5003, data=(4.0,))
    raw = reply.encode()
    assert raw == struct.pack("<9i", 72, 2002, 3, 1, 1, 9, 200121, 5, 5003) + struct.pack("<10f", 4.0, *[0.0] * 9)
    back = _roundtrip(raw)
    assert (back.group, back.sequence, back.command, back.result, back.subcode) == (1, 9, 200121, 5, 5003)
    assert back.data[0] == 4.0
    assert back.describe() == "NOT_READY (5003: e-stop)"


def test_decode_rejects_unknown_type_and_wrong_size() -> None:
    with pytest.raises(ProtocolError, match="unknown message type 99.*13 \\(ROBOT_STATUS\\)"):
        decode(Packet(99, 1, 0, b""))
    with pytest.raises(ProtocolError, match="RobotStatus body is 8 bytes, expected 28"):
        decode(Packet(MsgType.ROBOT_STATUS, 1, 0, bytes(8)))
    with pytest.raises(ProtocolError, match="claims 9 groups"):
        decode(Packet(MsgType.JOINT_FEEDBACK_EX, 1, 0, struct.pack("<i", 9) + bytes(528)))


def test_too_many_joints_is_refused() -> None:
    with pytest.raises(ProtocolError, match="11 joint values, at most 10"):
        JointTrajPtFull(0, 0, 0.0, np.zeros(11)).encode()


def test_framer_one_byte_chunks() -> None:
    stream = (RobotStatusMsg(1, 0, 0, 0, 0, 2, 1).encode() + JointFeedback(0, Q).encode()
              + MotionReply(0, 1, 200101, 0).encode())
    framer = Framer("test")
    packets = []
    for i in range(len(stream)):
        packets += framer.feed(stream[i:i + 1])
    assert [p.msg_type for p in packets] == [13, 15, 2002]
    assert framer.pending == 0


def test_framer_several_packets_in_one_read_and_a_partial_tail() -> None:
    one = JointFeedback(0, Q).encode()
    framer = Framer("test")
    assert len(framer.feed(one + one + one[:7])) == 2
    assert framer.pending == 7
    assert len(framer.feed(one[7:])) == 1


@pytest.mark.parametrize("length", [1 << 30, -4, 0, 11, 4097])
def test_framer_rejects_absurd_lengths(length: int) -> None:
    framer = Framer("motoros@test")
    with pytest.raises(ProtocolError, match=f"motoros@test: length prefix {length} outside \\[12, 4096\\]"):
        framer.feed(struct.pack("<i", length) + bytes(16))
    assert framer.pending == 0


def test_framer_rejects_ascii_garbage() -> None:
    with pytest.raises(ProtocolError, match="stream is corrupt"):
        Framer("test").feed(b"GET / HTTP/1.1\r\n\r\n")


def test_queue_count_travels_in_the_reply_subcode() -> None:
    """MotionServer.c answers CHECK_QUEUE_CNT with Ros_SimpleMsg_MotionReply(..., TRUE, count, ...)."""
    raw = MotionReply(1, 4, Command.CHECK_QUEUE_CNT, Result.TRUE, 137).encode()
    assert struct.unpack_from("<5i", raw, 16) == (1, 4, 200102, 0, 137)
    back = _roundtrip(raw)
    assert (back.result, back.subcode) == (Result.TRUE, 137) and back.data == (0.0,) * 10
    assert back.describe() == "SUCCESS (137: unknown subcode)"


def test_codes_follow_simple_message_h() -> None:
    from drivers.motoros.codes import InvalidSubcode, NotReadySubcode, describe
    assert [int(c) for c in (Command.START_SERVOS, Command.STOP_SERVOS, Command.RESET_ALARM,
                             Command.DISCONNECT)] == [200112, 200113, 200114, 200130]
    assert (Result.TRUE, Result.FALSE) == (Result.SUCCESS, Result.FAILURE)
    assert (InvalidSubcode.DATA_TIME, InvalidSubcode.DATA_TOOLNO) == (3016, 3017)
    assert (NotReadySubcode.NOT_REMOTE, NotReadySubcode.INC_MOVE_ERROR) == (5005, 5012)
    assert describe(Result.FALSE, 5005) == "FAILURE (5005: not in remote mode)"
    assert describe(99, 0) == "99"


def test_joint_traj_pt_full_ex_may_carry_all_four_slots() -> None:
    """MotoROS accepts the full 4-group body as well as just the groups it names."""
    one = JointTrajPtFullEx(sequence=2, groups=(JointFeedback(0, Q, time=1.0, valid_fields=7),)).encode()
    padded = one[16:] + bytes(3 * 132)
    back = decode(Packet(MsgType.JOINT_TRAJ_PT_FULL_EX, 2, 0, padded))
    assert back.sequence == 2 and len(back.groups) == 1
    np.testing.assert_array_equal(back.groups[0].pos[:6], Q)
    with pytest.raises(ProtocolError, match="JointTrajPtFullEx body is 272 bytes, expected 140"):
        decode(Packet(MsgType.JOINT_TRAJ_PT_FULL_EX, 2, 0, padded[:272]))
