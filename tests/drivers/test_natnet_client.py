"""NatNetSource end to end against the fake NatNet server on loopback."""

from __future__ import annotations

import socket
import struct
import threading
import time

import numpy as np
import pytest

from calibration.kinematics import so3
from drivers.errors import DriverError, DriverTimeout, ProtocolError
from drivers.natnet import FakeBody, FakeFrame, FakeMotive, FakeNatNetServer, MessageId, NatNetSource, encode_frame

GROUP = "239.255.42.99"


def _frame(n: int, valid: bool = True) -> FakeFrame:
    bodies = (FakeBody(1, (0.001 * n, 0.0, 1.0), tracking_valid=valid), FakeBody(2, (0.0, 0.002 * n, 1.0)))
    return FakeFrame(n, bodies, timestamp=n / 240.0)


def _read_until(src: NatNetSource, count: int, timeout_s: float = 2.0) -> list:
    frames, deadline = [], time.monotonic() + timeout_s
    while len(frames) < count and time.monotonic() < deadline:
        frames += src.read(0.1)
    return frames


def _unicast(server: FakeNatNetServer, **kwargs) -> NatNetSource:
    return NatNetSource("127.0.0.1", local_address="127.0.0.1", command_port=server.command_port, data_port=0,
                        multicast_group=None, connect_timeout_s=kwargs.pop("connect_timeout_s", 2.0), **kwargs)


@pytest.mark.parametrize("version", [(3, 1), (4, 1)])
def test_unicast_learns_version_and_streams_frames_in_order(version):
    with FakeNatNetServer(version) as server, _unicast(server) as src:
        assert src.version == version and src.server_info.app_name == "FakeMotive"
        for n in range(1, 51):
            server.send_frame(_frame(n, valid=n % 10 != 0))
        frames = _read_until(src, 100)
        assert len(frames) == 100
        assert [f.frame_number for f in frames[::2]] == list(range(1, 51))
        assert [f.body_id for f in frames[:4]] == [1, 2, 1, 2]
        np.testing.assert_allclose(frames[-2].position_mm, [50.0, 0.0, 1000.0], atol=1e-3)
        assert frames[-2].capture_time == pytest.approx(50 / 240.0)
        assert [f.tracking_valid for f in frames[::2]].count(False) == 5
        stats = src.stats
        assert (stats.frames_parsed, stats.packets_rejected, stats.frames_dropped) == (50, 0, 0)


def test_malformed_packets_are_counted_and_stream_continues():
    with FakeNatNetServer((4, 1)) as server, _unicast(server) as src:
        good = encode_frame(_frame(1), (4, 1))
        server.send_raw(good[:-30])  # header declares more than was sent
        server.send_raw(good[:4] + good[4:60])  # header consistent with nothing
        server.send_raw(b"\x07\x00" + bytes(np.random.default_rng(0).integers(0, 256, 200, dtype=np.uint8)))
        server.send_raw(b"\x07")
        server.send_frame(_frame(2))
        frames = _read_until(src, 2)
        assert [f.frame_number for f in frames] == [2, 2]
        time.sleep(0.05)
        stats = src.stats
        assert stats.packets_rejected == 4 and stats.frames_parsed == 1
        assert stats.last_error


def test_configured_version_does_not_wait_for_the_server():
    with FakeNatNetServer((3, 1), answer_connect=False) as server:
        src = _unicast(server, version=(3, 1))
        t0 = time.monotonic()
        with src:
            assert time.monotonic() - t0 < 0.5 and src.server_info is None
            server.send_frame(_frame(7), to=("127.0.0.1", src.data_port))
            assert [f.frame_number for f in _read_until(src, 2)] == [7, 7]


def test_bad_constructor_arguments():
    with pytest.raises(DriverError, match="max_buffered_frames must be >= 1, got 0"):
        NatNetSource(max_buffered_frames=0)
    with pytest.raises(ProtocolError, match="supported: 3.0 to 4.x"):
        NatNetSource(version=(2, 10))


def test_silent_server_times_out_with_a_clear_message():
    with FakeNatNetServer(answer_connect=False) as server:
        src = _unicast(server, connect_timeout_s=0.2)
        with pytest.raises(DriverTimeout, match="NAT_SERVERINFO"):
            src.connect()
        with pytest.raises(DriverError, match="not connected"):
            src.read(0.01)


def test_read_timeout_returns_empty_and_buffer_overflow_is_counted():
    with FakeNatNetServer((4, 1)) as server, _unicast(server, max_buffered_frames=3) as src:
        assert src.read(0.05) == []
        for n in range(1, 4):
            server.send_frame(_frame(n))
        time.sleep(0.2)
        frames = src.read(0.1)
        assert [(f.frame_number, f.body_id) for f in frames] == [(2, 2), (3, 1), (3, 2)]
        assert src.stats.frames_dropped == 3


def test_close_is_idempotent_and_releases_the_port():
    server = FakeNatNetServer((4, 1))
    src = _unicast(server)
    src.connect()
    port = src.data_port
    src.close()
    src.close()
    server.close()
    server.close()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", port))


def _multicast_loopback_works() -> bool:
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        rx.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        rx.bind(("", 0))
        membership = socket.inet_aton(GROUP) + socket.inet_aton("127.0.0.1")
        rx.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, membership)
        rx.settimeout(0.5)
        tx.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton("127.0.0.1"))
        tx.sendto(b"probe", (GROUP, rx.getsockname()[1]))
        return rx.recv(16) == b"probe"
    except OSError:
        return False
    finally:
        rx.close()
        tx.close()


@pytest.mark.skipif(not _multicast_loopback_works(), reason="multicast is not delivered on loopback here")
def test_multicast_stream():
    with FakeNatNetServer((4, 1), multicast_group=GROUP) as server:
        with NatNetSource("127.0.0.1", local_address="127.0.0.1", command_port=server.command_port,
                          data_port=0, multicast_group=GROUP) as src:
            assert src.server_info.multicast_group == GROUP
            for n in range(1, 11):
                server.send_frame(_frame(n), to=(GROUP, src.data_port))
            assert [f.frame_number for f in _read_until(src, 20)[::2]] == list(range(1, 11))


SDK_CONNECT_4_1 = b"\x00\x00\x0f\x01" + b"Ping" + bytes(261) + bytes([4, 1, 0, 0]) + b"\0\0"


def _server_info(version: tuple[int, int]) -> bytes:
    body = (b"Motive".ljust(256, b"\0") + bytes([3, 1, 0, 0]) + bytes([*version, 0, 0])
            + struct.pack("<QHB4B", 3_515_625, 1511, 0, 0, 0, 0, 0))
    return struct.pack("<HH", 1, len(body)) + body


def test_connect_sends_the_sdk_request_and_reads_the_reply():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as motive:
        motive.bind(("127.0.0.1", 0))
        motive.settimeout(2.0)
        src = NatNetSource("127.0.0.1", local_address="127.0.0.1", command_port=motive.getsockname()[1],
                           data_port=0, multicast_group=None, connect_timeout_s=2.0)
        result: list = []
        thread = threading.Thread(target=lambda: result.append(src.connect()))
        thread.start()
        request, client = motive.recvfrom(1024)
        motive.sendto(_server_info((4, 1)), client)
        thread.join(2.0)
        try:
            assert request == SDK_CONNECT_4_1 and result == [None]
            info = src.server_info
            assert (info.app_name, info.natnet_version, info.clock_frequency_hz) == ("Motive", (4, 1, 0, 0), 3_515_625)
            assert (info.data_port, info.multicast, src.version, src.stats.handshakes) == (1511, False, (4, 1), 1)
        finally:
            src.close()


def test_model_definitions_and_rigid_body_ids_over_udp():
    with FakeNatNetServer((4, 1), bodies={"weldgun": 3, "mti": 7}) as server, _unicast(server) as src:
        defs = src.request_model_definitions(1.0)
        assert [(b.name, b.body_id, b.marker_names) for b in defs.rigid_bodies] == [
            ("weldgun", 3, ("weldgun_1", "weldgun_2", "weldgun_3")), ("mti", 7, ("mti_1", "mti_2", "mti_3"))]
        assert src.rigid_body_ids(1.0) == {"weldgun": 3, "mti": 7}
        assert src.rigid_body_ids(1.0, names=["mti"]) == {"mti": 7}
        with pytest.raises(DriverError, match=r"rigid body 'probe' not defined .*; defined: mti, weldgun"):
            src.rigid_body_ids(1.0, names=["weldgun", "probe"])
        assert server.requests.count(MessageId.REQUEST_MODEL_DEF) >= 4
        assert src.stats.packets_rejected == 0


def test_model_definitions_time_out_and_need_a_connection():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as silent:
        silent.bind(("127.0.0.1", 0))
        src = NatNetSource("127.0.0.1", local_address="127.0.0.1", command_port=silent.getsockname()[1],
                           data_port=0, multicast_group=None, version=(4, 1))
        with pytest.raises(DriverError, match="not connected"):
            src.request_model_definitions(0.1)
        with src, pytest.raises(DriverTimeout, match="NAT_MODELDEF"):
            src.request_model_definitions(0.3)


def test_unicast_client_sends_keepalives():
    with FakeNatNetServer((4, 1)) as server, _unicast(server, keepalive_s=0.05):
        time.sleep(0.4)
        assert server.requests.count(MessageId.KEEP_ALIVE) >= 3


def test_close_then_connect_works_repeatedly_on_one_object():
    with FakeNatNetServer((4, 1)) as server:
        src = _unicast(server)
        for n in range(1, 4):
            src.connect()
            server.send_frame(_frame(n), to=("127.0.0.1", src.data_port))
            assert [f.frame_number for f in _read_until(src, 2)] == [n, n]
            src.close()
        assert server.requests.count(MessageId.CONNECT) == 3


def _poses(t_s: float) -> dict:
    c, s = np.cos(t_s), np.sin(t_s)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return {"weldgun": (R, np.array([100.0 + 10.0 * t_s, -50.0, 500.0])), "mti": None}


BODIES = {"weldgun": 3, "mti": 7}


def test_fake_motive_streams_the_callback_poses():
    bodies = BODIES
    with FakeMotive(bodies, _poses, rate_hz=240.0) as motive, _unicast(motive.server) as src:
        assert src.rigid_body_ids(1.0, names=["weldgun", "mti"]) == bodies
        frames = _read_until(src, 2 * 120, timeout_s=5.0)
    gun = [f for f in frames if f.body_id == 3]
    numbers = [f.frame_number for f in gun]
    assert numbers == list(range(numbers[0], numbers[0] + len(numbers)))  # consecutive, none lost on loopback
    for f in gun[::10]:
        R, p = _poses((f.frame_number - 1) / 240.0)["weldgun"]
        np.testing.assert_allclose(f.position_mm, p, atol=1e-3)
        np.testing.assert_allclose(so3.quat_to_R(f.quat_wxyz), R, atol=1e-6)
        assert f.tracking_valid and f.marker_error_mm == pytest.approx(0.2, abs=1e-6)
    assert all(not f.tracking_valid for f in frames if f.body_id == 7)
    stamps = np.array([f.capture_time for f in gun])  # the frame time since the fake's start
    np.testing.assert_allclose(stamps, (np.array(numbers) - 1) / 240.0, atol=1e-9)


def test_fake_motive_noise():
    period_s = 1 / 240.0
    with FakeMotive(BODIES, _poses, noise_pos_mm=1.0, noise_rot_deg=0.5, seed=4) as motive, \
            _unicast(motive.server) as src:
        frames = [f for f in _read_until(src, 2 * 240, timeout_s=5.0) if f.body_id == 3]
    truth = [_poses((f.frame_number - 1) * period_s)["weldgun"] for f in frames]
    err_p = np.array([f.position_mm - p for f, (_, p) in zip(frames, truth)])
    err_r = so3.log(np.array([R.T @ so3.quat_to_R(f.quat_wxyz) for f, (R, _) in zip(frames, truth)]))
    assert len(frames) >= 200
    assert 0.85 < err_p.std() < 1.15 and 0.85 < np.degrees(err_r).std() / 0.5 < 1.15
    assert np.abs(err_p.mean(axis=0)).max() < 0.3  # zero-mean


def test_fake_motive_schedules_by_absolute_time():
    """A callback taking half a period would make a sleep-one-period loop fall ~120 frames behind in 1 s."""
    def slow_poses(t_s: float) -> dict:
        time.sleep(0.002)
        return _poses(t_s)

    motive = FakeMotive(BODIES, slow_poses, rate_hz=240.0)
    t0 = time.monotonic()
    motive.start()
    time.sleep(1.0)
    sent, elapsed_s = motive.frames_sent, time.monotonic() - t0
    motive.close()
    print(f"{sent} frames in {elapsed_s:.3f} s (due {elapsed_s * 240:.0f})")
    assert motive.frames_skipped == 0
    assert abs(sent - elapsed_s * 240) < 24


def test_fake_motive_rejects_bad_arguments_and_reports_callback_errors():
    with pytest.raises(DriverError, match="rate_hz must be a positive number, got 0"):
        FakeMotive({"a": 1}, _poses, rate_hz=0)
    with pytest.raises(DriverError, match="ids must be unique"):
        FakeMotive({"a": 1, "b": 1}, _poses)
    motive = FakeMotive({"a": 1}, lambda t: {"b": (np.eye(3), np.zeros(3))})
    motive.start()
    time.sleep(0.1)
    with pytest.raises(DriverError, match=r"unknown bodies \['b'\]; known: \['a'\]"):
        motive.close()
    assert motive.frames_sent == 0


def test_client_re_handshakes_when_motive_restarts_on_the_same_port():
    bodies = BODIES
    first = FakeMotive(bodies, _poses, rate_hz=100.0, version=(4, 1))
    first.start()
    src = _unicast(first.server, reconnect_s=0.2)
    try:
        src.connect()
        assert len(_read_until(src, 5)) >= 5 and src.version == (4, 1)
        port = first.command_port
        first.close()
        time.sleep(0.3)
        src.read(0.05)  # drain what was in flight
        with FakeMotive(bodies, _poses, rate_hz=100.0, version=(4, 2), command_port=port) as second:
            frames = _read_until(src, 5, timeout_s=5.0)
            assert len(frames) >= 5 and frames[0].frame_number < 100  # the new server's counter
            assert second.server.requests.count(MessageId.CONNECT) >= 1
            # a 4.2 server streams the 4.1 the client's NAT_CONNECT asks for, re-learnt from its NAT_SERVERINFO
            assert src.version == (4, 1) and src.stats.handshakes >= 2
            assert second.server.client_versions[("127.0.0.1", src._link.cmd.getsockname()[1])] == (4, 1)
            assert src.stats.packets_rejected == 0
            assert src.rigid_body_ids(1.0) == bodies
    finally:
        src.close()


@pytest.mark.skipif(not _multicast_loopback_works(), reason="multicast is not delivered on loopback here")
def test_fake_motive_multicast():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        data_port = probe.getsockname()[1]
    with FakeMotive(BODIES, _poses, multicast_group=GROUP, data_port=data_port) as motive, \
            NatNetSource("127.0.0.1", local_address="127.0.0.1", command_port=motive.command_port,
                         data_port=data_port, multicast_group=GROUP) as src:
        assert src.server_info.multicast and src.server_info.data_port == data_port
        assert len(_read_until(src, 40)) >= 40


# -- only the server is heard, and only usable poses pass (issue 30) ----------------------------------------------


def test_datagrams_from_another_sender_are_dropped_unread():
    """NatNet accepted datagrams from any sender: a host of the mocap network could inject frames. A second sender
    on loopback (127.0.0.2) sends well-formed frames to the client's command and data sockets; none is read."""
    with FakeNatNetServer((4, 1)) as server, _unicast(server) as src:
        forged = encode_frame(FakeFrame(999, (FakeBody(1, (9.0, 9.0, 9.0)),)), (4, 1))
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as attacker:
            attacker.bind(("127.0.0.2", 0))
            for port in (src._link.cmd.getsockname()[1], src.data_port):
                for _ in range(5):
                    attacker.sendto(forged, ("127.0.0.1", port))
            time.sleep(0.1)
            for n in range(1, 4):
                server.send_frame(_frame(n))
            frames = _read_until(src, 6)
        assert len(frames) == 6 and all(f.frame_number != 999 for f in frames)
        assert src.stats.packets_foreign == 10 and src.stats.frames_parsed == 3


@pytest.mark.parametrize("position_m, quat_xyzw, error_m", [
    ((float("nan"), 0.0, 1.0), (0.0, 0.0, 0.0, 1.0), 0.0002),
    ((0.0, float("inf"), 1.0), (0.0, 0.0, 0.0, 1.0), 0.0002),
    ((0.0, 0.0, 1.0), (0.0, 0.0, 0.0, 0.0), 0.0002),  # a zero quaternion
    ((0.0, 0.0, 1.0), (0.0, 0.0, 0.0, 2.0), 0.0002),  # not unit
    ((0.0, 0.0, 1.0), (float("nan"), 0.0, 0.0, 1.0), 0.0002),
    ((0.0, 0.0, 1.0), (0.0, 0.0, 0.0, 1.0), float("nan")),
])
@pytest.mark.parametrize("version", [(3, 1), (4, 1)])
def test_a_non_finite_or_non_unit_pose_is_dropped_by_the_parser(position_m, quat_xyzw, error_m, version):
    """Frames with NaN positions or zero quaternions passed as tracking_valid (issue 30)."""
    from drivers.natnet.packets import parse_frame

    bad = FakeBody(5, position_m, quat_xyzw, error_m, tracking_valid=True)
    good = FakeBody(6, (0.1, 0.2, 0.3), (0.0, 0.0, np.sin(0.2), np.cos(0.2)))
    frame = parse_frame(encode_frame(FakeFrame(1, (bad, good)), version)[4:], version)
    assert [b.body_id for b in frame.rigid_bodies] == [6] and frame.bodies_dropped == 1
    np.testing.assert_allclose(frame.rigid_bodies[0].position_mm, [100.0, 200.0, 300.0], atol=1e-4)


def test_dropped_bodies_are_counted_by_the_client():
    with FakeNatNetServer((4, 1)) as server, _unicast(server) as src:
        server.send_frame(FakeFrame(1, (FakeBody(1, (float("nan"), 0.0, 1.0)), FakeBody(2, (0.0, 0.0, 1.0)))))
        frames = _read_until(src, 1)
        time.sleep(0.05)
        assert [f.body_id for f in frames] == [2] and src.stats.bodies_dropped == 1


# -- the fake Motive as strict as Motive (issue 30) -------------------------------------------------------------


def test_the_fake_keeps_a_bounded_request_history_and_counts_every_request():
    """It kept every request in a list that never shrank (an SDK client sends about 240 a second)."""
    from drivers.natnet.fake import MAX_KEPT_REQUESTS
    from drivers.natnet.messages import build_request

    n = 3 * MAX_KEPT_REQUESTS
    with FakeNatNetServer((4, 1)) as server, socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as client:
        for _ in range(n):
            client.sendto(build_request(MessageId.KEEP_ALIVE), ("127.0.0.1", server.command_port))
            if _ % 200 == 0:
                time.sleep(0.005)  # leave the server time to read (the socket buffer is finite)
        deadline = time.monotonic() + 5.0
        while server.request_counts[MessageId.KEEP_ALIVE] < n and time.monotonic() < deadline:
            time.sleep(0.01)
        assert server.request_counts[MessageId.KEEP_ALIVE] == n
        assert len(server.requests) == MAX_KEPT_REQUESTS


def test_the_fake_streams_the_version_a_client_asks_for():
    """A client asking for NatNet 3.1 got 4.1 frames it cannot parse: the fake ignored the requested version."""
    with FakeNatNetServer((4, 1)) as server, _unicast(server, version=(3, 1)) as old, _unicast(server) as new:
        time.sleep(0.1)
        for n in range(1, 6):
            server.send_frame(_frame(n))
        assert len(_read_until(old, 10)) == 10 and len(_read_until(new, 10)) == 10
        assert old.stats.packets_rejected == 0 and new.stats.packets_rejected == 0
        assert sorted(server.client_versions.values()) == [(3, 1), (4, 1)]


def test_a_frame_carries_no_asset_unless_one_is_defined():
    """Motive sends assets only when some are defined; the fake put one in every 4.1 frame."""
    packet = encode_frame(FakeFrame(1, ()), (4, 1))
    (assets,) = struct.unpack_from("<i", packet, 4 + 4 + 4 * 8)  # header, frame number, four (count, bytes) pairs
    assert assets == 0
    with_one = encode_frame(FakeFrame(1, (), assets=1), (4, 1))
    assert struct.unpack_from("<ii", with_one, 4 + 4 + 4 * 8) == (1, 12)
