"""NatNetSource end to end against the fake NatNet server on loopback."""

from __future__ import annotations

import socket
import time

import numpy as np
import pytest

from drivers.errors import DriverError, DriverTimeout, ProtocolError
from drivers.natnet import FakeBody, FakeFrame, FakeNatNetServer, NatNetSource, encode_frame

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
