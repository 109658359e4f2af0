"""NatNet parser against packets built field by field, for the 3.x and 4.x layouts."""

from __future__ import annotations

import struct
import time

import numpy as np
import pytest

from drivers.errors import ProtocolError
from drivers.natnet import (
    FakeBody,
    FakeFrame,
    MessageId,
    build_connect,
    build_request,
    encode_frame,
    encode_model_definitions,
    encode_server_info,
    parse_frame,
    parse_model_definitions,
    parse_server_info,
    split_packet,
)

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
    body = struct.pack("<i3f4ffh", 9, 1.0, 2.0, 3.0, 0.1, 0.2, 0.3, 0.86 ** 0.5, 0.0005, 0x05)  # a unit quaternion
    empty = struct.pack("<ii", 0, 0)
    payload = (struct.pack("<i", 77) + empty + empty + struct.pack("<ii", 1, len(body)) + body
               + empty + empty + empty + empty + empty
               + struct.pack("<IIdQQQIIh", 0, 0, 9.5, 1, 2, 3, 1_700_000_000, 3 << 30, 0))
    f = parse_frame(payload, (4, 1))
    (b,) = f.rigid_bodies
    assert (f.frame_number, b.body_id, b.tracking_valid, f.timestamp) == (77, 9, True, 9.5)
    assert (f.precision_timestamp_sec, f.precision_timestamp_frac) == (1_700_000_000, 3 << 30)
    assert f.precision_time_s == 1_700_000_000.75
    assert b.capture_time == f.capture_time == 9.5  # the frame time, not the precision timestamp
    np.testing.assert_allclose(b.position_mm, [1000, 2000, 3000])
    np.testing.assert_allclose(b.quat_wxyz, [0.86 ** 0.5, 0.1, 0.2, 0.3], atol=1e-7)
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


def test_connect_request_is_laid_out_as_the_sdk_sends_it():
    """NatNetClient.py 4.1 send_request(NAT_CONNECT): 270 bytes ("Ping", zeros, version at 265..268) + NUL."""
    packet = build_connect((4, 1))
    assert packet == b"\x00\x00\x0f\x01" + b"Ping" + bytes(261) + bytes([4, 1, 0, 0]) + b"\0" + b"\0"
    assert build_connect((3, 1))[4 + 265:4 + 269] == bytes([3, 1, 0, 0])
    # empty requests declare 0 payload bytes but still carry the SDK's trailing NUL
    assert build_request(MessageId.KEEP_ALIVE) == b"\x0a\x00\x00\x00\x00"
    assert build_request(MessageId.REQUEST_MODEL_DEF) == b"\x04\x00\x00\x00\x00"
    assert build_request(MessageId.REQUEST, b"Bitstream") == b"\x02\x00\x0a\x00Bitstream\0"


@pytest.mark.parametrize("multicast", [True, False])
def test_server_info_as_motive_4_1_sends_it(multicast):
    """sSender_Server of NatNetTypes.h, packed: sSender (264 bytes), uint64 clock, uint16 port, bool, 4 bytes."""
    payload = (b"Motive".ljust(256, b"\0") + bytes([3, 1, 2, 7]) + bytes([4, 1, 0, 0])
               + struct.pack("<Q", 3_515_625) + struct.pack("<H", 1511) + bytes([int(multicast)])
               + bytes([239, 255, 42, 99]))
    assert len(payload) == 279
    info = parse_server_info(payload)
    assert (info.app_name, info.app_version, info.natnet_version) == ("Motive", (3, 1, 2, 7), (4, 1, 0, 0))
    assert (info.clock_frequency_hz, info.data_port, info.multicast) == (3_515_625, 1511, multicast)
    assert info.multicast_group == "239.255.42.99"


@pytest.mark.parametrize("version", VERSIONS)
def test_the_frame_timestamp_is_the_capture_time_whatever_the_precision_word_holds(version):
    """The precision timestamp's fraction unit is not documented: a nanosecond fraction (here 0.5 s) read as
    2**-32 s would put the frame 0.38 s early, so capture times never come from it."""
    for fraction in (1 << 31, 500_000_000):
        frame = FakeFrame(3, (FakeBody(1, (0.0, 0.0, 0.0)),), timestamp=12.25,
                          precision_timestamp=(1_700_000_000, fraction))
        f = parse_frame(_payload(frame, version), version)
        assert f.timestamp == f.capture_time == f.rigid_bodies[0].capture_time == 12.25
        if version >= (4, 1):
            assert (f.precision_timestamp_sec, f.precision_timestamp_frac) == (1_700_000_000, fraction)
            assert f.precision_time_s == 1_700_000_000 + fraction / 2 ** 32
        else:  # not on the wire
            assert f.precision_time_s is None
    absent = parse_frame(_payload(FakeFrame(3, (), timestamp=12.25), version), version)
    assert absent.precision_time_s is None and absent.capture_time == 12.25


def test_ten_thousand_marker_set_names_parse_in_one_pass():
    """The name search used to copy the rest of the packet per name (0.23 s for this packet)."""
    names = tuple(chr(65 + i % 26) for i in range(10_000))
    frame = FakeFrame(9, (FakeBody(1, (0.1, 0.2, 0.3)),), marker_sets=tuple((n, ()) for n in names),
                      unlabeled_m=((1.0, 2.0, 3.0),))
    packet = encode_frame(frame, (4, 1))
    assert len(packet) < 65536  # still one UDP datagram
    _, payload = split_packet(packet)
    t0 = time.perf_counter()
    f = parse_frame(payload, (4, 1))
    print(f"parsed {len(f.marker_sets)} marker sets in {time.perf_counter() - t0:.4f} s")
    assert tuple(name for name, _ in f.marker_sets) == names
    assert all(m.shape == (0, 3) for _, m in f.marker_sets)
    assert (len(f.rigid_bodies), f.unlabeled_markers_mm.shape) == (1, (1, 3))


BODIES = {"weldgun": 3, "mti": 7}


def _modeldef(version: tuple[int, int], others: bool = True) -> bytes:
    message_id, payload = split_packet(encode_model_definitions(BODIES, version, others))
    assert message_id == MessageId.MODEL_DEF
    return bytes(payload)


@pytest.mark.parametrize("version", VERSIONS)
def test_model_definitions_rigid_bodies_and_skipped_types(version):
    defs = parse_model_definitions(_modeldef(version), version)
    assert defs.rigid_body_ids() == BODIES
    weldgun = defs.rigid_bodies[0]
    assert (weldgun.name, weldgun.body_id, weldgun.parent_id) == ("weldgun", 3, -1)
    np.testing.assert_allclose(weldgun.offset_mm, [0.0, 0.0, 0.0])
    np.testing.assert_allclose(weldgun.marker_offsets_mm, 50.0 * np.eye(3), atol=1e-5)  # metres -> mm
    assert weldgun.marker_ids == (1, 2, 3)
    expected_names = ("weldgun_1", "weldgun_2", "weldgun_3") if version >= (4, 0) else ("", "", "")
    assert weldgun.marker_names == expected_names
    assert defs.marker_sets == (("weldgun", ("weldgun_1", "weldgun_2", "weldgun_3")),
                                ("mti", ("mti_1", "mti_2", "mti_3")))
    assert defs.skeletons == ("skel",)  # its bone is not a top-level rigid body
    expected_counts = {0: 2, 1: 2, 2: 1, 3: 1, 4: 1, 5: 1} | ({6: 1} if version >= (4, 1) else {})
    assert defs.type_counts == expected_counts
    assert defs.missing_rigid_bodies(["mti", "probe", "weldgun"]) == ["probe"]


def test_hand_built_4_1_rigid_body_description():
    """One description written out by hand (type, byte count, fields), independent of the fake encoder."""
    body = (b"tool\0" + struct.pack("<ii3f", 12, 4, 0.01, -0.02, 0.5) + struct.pack("<i", 2)
            + struct.pack("<3f3f", 0.1, 0.0, 0.0, 0.0, 0.2, 0.0) + struct.pack("<ii", 0, 9) + b"m1\0m2\0")
    payload = struct.pack("<iii", 1, 1, len(body)) + body
    (rb,) = parse_model_definitions(payload, (4, 1)).rigid_bodies
    assert (rb.name, rb.body_id, rb.parent_id, rb.marker_ids, rb.marker_names) == ("tool", 12, 4, (0, 9), ("m1", "m2"))
    np.testing.assert_allclose(rb.offset_mm, [10.0, -20.0, 500.0], atol=1e-4)
    np.testing.assert_allclose(rb.marker_offsets_mm, [[100, 0, 0], [0, 200, 0]], atol=1e-4)
    bad = struct.pack("<iii", 1, 1, len(body) + 1) + body + b"\0"
    with pytest.raises(ProtocolError, match="byte count says"):
        parse_model_definitions(bad, (4, 1))


def test_unknown_description_type_is_skipped_by_its_byte_count_from_4_1():
    unknown = struct.pack("<ii", 99, 5) + b"12345"
    payload = _modeldef((4, 1), others=False)
    count = struct.unpack_from("<i", payload)[0]
    defs = parse_model_definitions(struct.pack("<i", count + 1) + unknown + payload[4:], (4, 1))
    assert defs.rigid_body_ids() == BODIES and defs.type_counts[99] == 1
    with pytest.raises(ProtocolError, match=r"unknown data description type 99 .*known: 0 MARKER_SET"):
        parse_model_definitions(struct.pack("<i", 1) + struct.pack("<i", 99) + b"12345", (3, 1))


@pytest.mark.parametrize("version", [(3, 1), (4, 0), (4, 1), (4, 2)])
def test_every_model_definition_truncation_is_rejected(version):
    payload = _modeldef(version)
    for cut in range(0, len(payload), 7):
        with pytest.raises(ProtocolError, match="truncated|bad|byte count"):
            parse_model_definitions(payload[:cut], version)
