"""NatNet parser against packets built field by field, for the 3.x and 4.x layouts."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from drivers.errors import ProtocolError
from drivers.natnet import (FakeBody, FakeFrame, MessageId, encode_frame, encode_server_info, parse_frame,
                            parse_server_info, split_packet)

VERSIONS = [(3, 0), (3, 1), (4, 0), (4, 1), (4, 2)]

FRAME = FakeFrame(
    frame_number=4242,
    bodies=(
        FakeBody(1, (0.125, -0.5, 1.25), (0.0, 0.0, 0.70710678, 0.70710678), 0.0003, True),
        FakeBody(2, (2.0, 0.25, -0.75), (0.5, 0.5, 0.5, 0.5), 0.0001, False),
        FakeBody(17, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0), 0.0, True),
    ),
    timestamp=123.456789,
    marker_sets=(("weldgun", ((0.1, 0.2, 0.3), (0.4, 0.5, 0.6))), ("all", ())),
    unlabeled_m=((1.0, 2.0, 3.0),),
    skeletons=((5, (FakeBody(50, (0.1, 0.1, 0.1)), FakeBody(51, (0.2, 0.2, 0.2)))),),
    labeled_marker_count=3,
    stamps=(1_000_000_001, 1_000_000_500, 1_000_000_900),
    timecode=(0x01020304, 7),
    params=0x02,
    force_plates=((3, ((1.0, 2.0, 3.0), (4.0,))),),
)


def _payload(frame: FakeFrame, version: tuple[int, int]) -> memoryview:
    message_id, payload = split_packet(encode_frame(frame, version))
    assert message_id == MessageId.FRAME_OF_DATA
    return payload


@pytest.mark.parametrize("version", VERSIONS)
def test_frame_fields_units_and_quaternion_order(version):
    f = parse_frame(_payload(FRAME, version), version)
    assert f.frame_number == 4242
    assert f.timestamp == pytest.approx(123.456789, abs=1e-12)
    assert (f.stamp_camera_mid_exposure, f.stamp_data_received, f.stamp_transmit) == FRAME.stamps
    assert (f.timecode, f.timecode_sub, f.params) == (0x01020304, 7, 0x02)
    assert [b.body_id for b in f.rigid_bodies] == [1, 2, 17]
    np.testing.assert_allclose(f.rigid_bodies[0].position_mm, [125.0, -500.0, 1250.0], atol=1e-4)
    np.testing.assert_allclose(f.rigid_bodies[1].position_mm, [2000.0, 250.0, -750.0], atol=1e-4)
    np.testing.assert_allclose(f.rigid_bodies[0].quat_wxyz, [0.70710678, 0.0, 0.0, 0.70710678], atol=1e-7)
    np.testing.assert_allclose(f.rigid_bodies[2].quat_wxyz, [0.0, 1.0, 0.0, 0.0], atol=0)
    np.testing.assert_allclose([b.marker_error_mm for b in f.rigid_bodies], [0.3, 0.1, 0.0], atol=1e-6)
    assert [b.tracking_valid for b in f.rigid_bodies] == [True, False, True]
    assert all(b.capture_time == f.timestamp and b.frame_number == 4242 for b in f.rigid_bodies)
    assert [name for name, _ in f.marker_sets] == ["weldgun", "all"]
    np.testing.assert_allclose(f.marker_sets[0][1], [[100, 200, 300], [400, 500, 600]], atol=1e-4)
    assert f.marker_sets[1][1].shape == (0, 3)
    np.testing.assert_allclose(f.unlabeled_markers_mm, [[1000, 2000, 3000]])
    assert (f.skeleton_count, f.labeled_marker_count) == (1, 3)


def test_hand_built_4_1_packet():
    """One rigid body written out by hand, with the 4.1 byte counts, independent of the fake encoder."""
    body = struct.pack("<i3f4ffh", 9, 1.0, 2.0, 3.0, 0.1, 0.2, 0.3, 0.9, 0.0005, 0x05)
    empty = struct.pack("<ii", 0, 0)
    payload = (struct.pack("<i", 77) + empty + empty + struct.pack("<ii", 1, len(body)) + body
               + empty + empty + empty + empty + empty
               + struct.pack("<IIdQQQIIh", 0, 0, 9.5, 1, 2, 3, 1_700_000_000, 3 << 30, 0))
    f = parse_frame(payload, (4, 1))
    (b,) = f.rigid_bodies
    assert (f.frame_number, b.body_id, b.tracking_valid, f.timestamp) == (77, 9, True, 9.5)
    assert (f.precision_timestamp_sec, f.precision_timestamp_frac) == (1_700_000_000, 3 << 30)
    assert b.capture_time == f.capture_time == 1_700_000_000.75  # the precision timestamp wins
    np.testing.assert_allclose(b.position_mm, [1000, 2000, 3000])
    np.testing.assert_allclose(b.quat_wxyz, [0.9, 0.1, 0.2, 0.3], atol=1e-7)
    np.testing.assert_allclose(b.marker_error_mm, 0.5, atol=1e-6)
    with pytest.raises(ProtocolError):  # the same bytes read with the 3.x layout do not add up
        parse_frame(payload, (3, 1))


@pytest.mark.parametrize("version", [(3, 1), (4, 1)])
def test_every_truncation_is_rejected(version):
    payload = bytes(_payload(FRAME, version))[:-4]  # without the optional end-of-data tag
    parse_frame(payload, version)
    for cut in range(len(payload)):
        with pytest.raises(ProtocolError, match="truncated|bad|byte count"):
            parse_frame(payload[:cut], version)


def test_header_declaring_more_than_received_is_rejected():
    packet = encode_frame(FRAME, (4, 1))
    with pytest.raises(ProtocolError, match="header declares"):
        split_packet(packet[:-10])
    with pytest.raises(ProtocolError, match="shorter than the 4-byte header"):
        split_packet(b"\x07")


def test_garbage_counts_are_rejected_without_allocating():
    payload = struct.pack("<ii", 1, 2_000_000_000) + bytes(64)  # marker set count absurd for 64 bytes
    with pytest.raises(ProtocolError, match="bad marker set count"):
        parse_frame(payload, (3, 1))
    payload = struct.pack("<iii", 1, -5, 0) + bytes(64)
    with pytest.raises(ProtocolError, match="bad marker set count"):
        parse_frame(payload, (3, 1))


def test_byte_count_mismatch_is_rejected():
    payload = bytearray(_payload(FakeFrame(1, (FakeBody(1, (0.0, 0.0, 0.0)),)), (4, 1)))
    # marker sets (0, 0), unlabeled (0, 0), then rigid bodies: count 1, byte count 38 at offset 24
    assert struct.unpack_from("<ii", payload, 20) == (1, 38)
    struct.pack_into("<i", payload, 24, 40)
    with pytest.raises(ProtocolError, match="rigid body byte count says 40, parsed 38"):
        parse_frame(bytes(payload), (4, 1))


def test_unsupported_version_names_the_valid_range():
    with pytest.raises(ProtocolError, match="supported: 3.0 to 4.x"):
        parse_frame(b"", (2, 9))


def test_server_info_round_trip_and_truncation():
    _, payload = split_packet(encode_server_info((3, 1), app_name="Motive", data_port=1511,
                                                 multicast_group="239.255.42.99"))
    info = parse_server_info(payload)
    assert (info.app_name, info.natnet_version, info.data_port) == ("Motive", (3, 1, 0, 0), 1511)
    assert (info.multicast, info.multicast_group, info.clock_frequency_hz) == (True, "239.255.42.99", 10_000_000)
    short = parse_server_info(bytes(payload)[:264])
    assert short.natnet_version == (3, 1, 0, 0) and short.data_port == 0
    with pytest.raises(ProtocolError, match="truncated"):
        parse_server_info(bytes(payload)[:100])
