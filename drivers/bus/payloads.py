"""Binary payloads of the cellcal Zenoh bus: one mocap frame or one joint state per sample.

Both are fixed-size little-endian structs that start with a 2-byte magic and a version byte, so a
subscriber can reject anything else with a ProtocolError instead of misreading it.

Mocap frame, key ``cellcal/<cell>/mocap/<rigid_body>``, 96 bytes, version 1::

    offset  size  type        field
    0       2     char[2]     magic b"CM"
    2       1     uint8       version (1)
    3       1     uint8       flags: bit 0 tracking valid
    4       4     int32       rigid-body id
    8       8     int64       frame number
    16      8     float64     capture time [s], clock of the mocap source
    24      8     float64     publish time [s], ``time.time()`` of the publisher (latency measurement)
    32      24    float64[3]  position [mm]
    56      32    float64[4]  quaternion (w, x, y, z)
    88      8     float64     mean marker error [mm]

Joint state, key ``cellcal/<cell>/robot/<name>/joints``, 72 bytes, version 1::

    offset  size  type        field
    0       2     char[2]     magic b"CJ"
    2       1     uint8       version (1)
    3       5     -           zero padding
    8       8     float64     stamp [s], clock of the robot reader
    16      8     float64     publish time [s], ``time.time()`` of the publisher
    24      48    float64[6]  joint angles [rad]
"""

from __future__ import annotations

import struct

import numpy as np

from drivers.base import JointState, RigidBodyFrame
from drivers.errors import ProtocolError

DEVICE = "zenoh-bus"
PAYLOAD_VERSION = 1
MOCAP_MAGIC = b"CM"
JOINTS_MAGIC = b"CJ"
MOCAP = struct.Struct("<2sBBiqdd3d4dd")
JOINTS = struct.Struct("<2sB5xdd6d")
_VALID = 0x01


def encode_mocap(frame: RigidBodyFrame, publish_time: float) -> bytes:
    """Pack one rigid-body frame; ``publish_time`` [s] is the publisher's ``time.time()``."""
    p = np.asarray(frame.position_mm, dtype=float).reshape(3)
    q = np.asarray(frame.quat_wxyz, dtype=float).reshape(4)
    return MOCAP.pack(MOCAP_MAGIC, PAYLOAD_VERSION, _VALID if frame.tracking_valid else 0, frame.body_id,
                      frame.frame_number, frame.capture_time, publish_time, *p, *q, frame.marker_error_mm)


def _check_header(payload: bytes, size: int, magic: bytes, what: str) -> None:
    if len(payload) != size:
        raise ProtocolError(DEVICE, f"{what} payload must be {size} bytes, got {len(payload)}")
    if payload[:2] != magic:
        raise ProtocolError(DEVICE, f"{what} payload starts with {bytes(payload[:2])!r}, expected {magic!r}")
    if payload[2] != PAYLOAD_VERSION:
        raise ProtocolError(DEVICE, f"{what} payload version {payload[2]} unsupported; supported: {PAYLOAD_VERSION}")


def decode_mocap(payload: bytes) -> tuple[RigidBodyFrame, float]:
    """Unpack a mocap payload into (frame, publish time [s]).

    Raises:
        ProtocolError: wrong size, magic or version.
    """
    _check_header(payload, MOCAP.size, MOCAP_MAGIC, "mocap")
    _, _, flags, body_id, frame_number, capture, publish, *rest = MOCAP.unpack(payload)
    frame = RigidBodyFrame(body_id=body_id, position_mm=np.array(rest[0:3]), quat_wxyz=np.array(rest[3:7]),
                           marker_error_mm=rest[7], tracking_valid=bool(flags & _VALID), capture_time=capture,
                           frame_number=frame_number)
    return frame, publish


def encode_joints(state: JointState, publish_time: float) -> bytes:
    """Pack one joint state (6 angles [rad]); raises ProtocolError for another number of joints."""
    q = np.asarray(state.q, dtype=float).ravel()
    if q.shape != (6,):
        raise ProtocolError(DEVICE, f"joint state must have 6 angles, got shape {np.shape(state.q)}")
    return JOINTS.pack(JOINTS_MAGIC, PAYLOAD_VERSION, state.stamp, publish_time, *q)


def decode_joints(payload: bytes) -> tuple[JointState, float]:
    """Unpack a joint-state payload into (state, publish time [s]).

    Raises:
        ProtocolError: wrong size, magic or version.
    """
    _check_header(payload, JOINTS.size, JOINTS_MAGIC, "joint state")
    _, _, stamp, publish, *q = JOINTS.unpack(payload)
    return JointState(q=np.array(q), stamp=stamp), publish
