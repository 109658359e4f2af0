"""Bus payload layouts, key expressions and session settings (no zenoh session needed)."""

from __future__ import annotations

import dataclasses
import struct

import numpy as np
import pytest

from cell_config.devices import ZenohConfig
from drivers.base import JointState, RigidBodyFrame
from drivers.bus import (
    decode_joints,
    decode_mocap,
    encode_joints,
    encode_mocap,
    joints_key,
    mocap_key,
    session_settings,
)
from drivers.errors import DriverError, ProtocolError

FRAME = RigidBodyFrame(body_id=3, position_mm=np.array([1250.5, -42.125, 3.0e3]),
                       quat_wxyz=np.array([0.5, -0.5, 0.5, -0.5]), marker_error_mm=0.0375, tracking_valid=False,
                       capture_time=1234.5678901234, frame_number=2**40 + 7)


def test_mocap_round_trip_is_exact_and_layout_is_as_documented():
    payload = encode_mocap(FRAME, publish_time=1.7e9 + 0.123456)
    assert len(payload) == 96
    assert payload[:3] == b"CM\x01" and payload[3] == 0  # invalid tracking clears bit 0
    assert struct.unpack_from("<iqdd", payload, 4) == (3, 2**40 + 7, 1234.5678901234, 1.7e9 + 0.123456)
    assert struct.unpack_from("<3d", payload, 32) == (1250.5, -42.125, 3.0e3)
    assert struct.unpack_from("<4dd", payload, 56) == (0.5, -0.5, 0.5, -0.5, 0.0375)
    frame, publish = decode_mocap(payload)
    assert publish == 1.7e9 + 0.123456
    assert (frame.body_id, frame.frame_number, frame.capture_time, frame.tracking_valid) == \
        (3, 2**40 + 7, 1234.5678901234, False)
    np.testing.assert_array_equal(frame.position_mm, FRAME.position_mm)
    np.testing.assert_array_equal(frame.quat_wxyz, FRAME.quat_wxyz)
    valid = dataclasses.replace(FRAME, tracking_valid=True)
    assert decode_mocap(encode_mocap(valid, 0.0))[0].tracking_valid


def test_joint_round_trip_and_layout():
    q = np.array([0.1, -1.2, 2.3, -3.1, 0.0, 1e-9])
    payload = encode_joints(JointState(q=q, stamp=55.25), publish_time=99.5)
    assert len(payload) == 72 and payload[:3] == b"CJ\x01" and payload[3:8] == bytes(5)
    assert struct.unpack_from("<dd6d", payload, 8) == (55.25, 99.5, *q)
    state, publish = decode_joints(payload)
    np.testing.assert_array_equal(state.q, q)
    assert (state.stamp, publish) == (55.25, 99.5)
    with pytest.raises(ProtocolError, match="6 angles"):
        encode_joints(JointState(q=np.zeros(7), stamp=0.0), 0.0)


@pytest.mark.parametrize("payload, message", [
    (b"", "must be 96 bytes, got 0"),
    (encode_mocap(FRAME, 0.0)[:-1], "must be 96 bytes, got 95"),
    (b"XX" + encode_mocap(FRAME, 0.0)[2:], "expected b'CM'"),
    (b"CM\x02" + encode_mocap(FRAME, 0.0)[3:], "version 2 unsupported; supported: 1"),
    (encode_joints(JointState(np.zeros(6), 0.0), 0.0), "must be 96 bytes, got 72"),
])
def test_bad_mocap_payloads(payload, message):
    with pytest.raises(ProtocolError, match=message):
        decode_mocap(payload)


def test_bad_joint_payloads():
    with pytest.raises(ProtocolError, match="expected b'CJ'"):
        decode_joints(b"CM" + bytes(70))
    with pytest.raises(ProtocolError, match="must be 72 bytes"):
        decode_joints(encode_mocap(FRAME, 0.0))


def test_key_expressions():
    assert mocap_key("motoman_cell", "weldgun") == "cellcal/motoman_cell/mocap/weldgun"
    assert mocap_key("motoman_cell", "*") == "cellcal/motoman_cell/mocap/*"
    assert joints_key("motoman_cell", "R1") == "cellcal/motoman_cell/robot/R1/joints"
    for bad in ("", "a/b", "we*ld", "x y", "$a"):
        with pytest.raises(DriverError, match="not a valid key chunk"):
            mocap_key("cell", bad)
    with pytest.raises(DriverError, match="cell name"):
        joints_key("bad/cell", "R1")


def test_session_settings_defaults_and_errors():
    default = session_settings(ZenohConfig())
    assert default == {"mode": "peer", "listen/endpoints": ["tcp/127.0.0.1:0"], "connect/endpoints": [],
                       "scouting/multicast/enabled": False}
    remote = session_settings(ZenohConfig(listen=("tcp/0.0.0.0:7447",), connect=("tcp/10.0.0.2:7447",)))
    assert remote["listen/endpoints"] == ["tcp/0.0.0.0:7447"] and remote["connect/endpoints"] == ["tcp/10.0.0.2:7447"]
    client = session_settings(ZenohConfig(mode="client", connect=("tcp/10.0.0.1:7447",)))
    assert client["listen/endpoints"] == []
    with pytest.raises(DriverError, match="client mode needs at least one connect endpoint"):
        session_settings(ZenohConfig(mode="client"))
    with pytest.raises(DriverError, match="not one of peer, client, router"):
        session_settings(ZenohConfig(mode="broker"))
