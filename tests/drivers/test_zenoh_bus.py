"""The bus with real zenoh sessions on 127.0.0.1: one listens on a free port, the other connects."""

from __future__ import annotations

import socket
import threading
import time

import numpy as np
import pytest

from cell_config.devices import ZenohConfig
from drivers.base import JointState, MocapSource, RigidBodyFrame
from drivers.bus import (
    JointStatePublisher,
    JointStateSubscriber,
    MocapBridge,
    ZenohMocapSource,
    encode_mocap,
    joints_key,
    mocap_key,
    open_session,
    wait_for_subscriber,
)
from drivers.errors import DriverDisconnected, DriverError
from drivers.natnet import FakeBody, FakeFrame, FakeNatNetServer, NatNetSource

CELL = "testcell"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def endpoints():
    port = _free_port()
    return ZenohConfig(listen=(f"tcp/127.0.0.1:{port}",)), ZenohConfig(connect=(f"tcp/127.0.0.1:{port}",))


@pytest.fixture
def publisher_session(endpoints):
    session = open_session(endpoints[0])
    yield session
    session.close()


def _frame(body_id: int, n: int) -> RigidBodyFrame:
    return RigidBodyFrame(body_id, np.array([n, 2.0 * n, 3.0]), np.array([1.0, 0.0, 0.0, 0.0]), 0.05,
                          n % 7 != 0, n / 240.0, n)


def _drain(source, count: int, timeout_s: float = 5.0, samples: bool = False) -> list:
    out, deadline = [], time.monotonic() + timeout_s
    while len(out) < count and time.monotonic() < deadline:
        out += source.read_samples(0.1) if samples else source.read(0.1)
    return out


def test_frames_arrive_decoded_and_in_order(publisher_session, endpoints):
    with ZenohMocapSource(CELL, config=endpoints[1]) as sub:
        assert wait_for_subscriber(publisher_session, mocap_key(CELL, "weldgun"), 5.0)
        bridge = MocapBridge(source=None, session=publisher_session, cell=CELL, names={1: "weldgun", 2: "mti"})
        for n in range(300):
            bridge.publish(_frame(1, n))
            bridge.publish(_frame(2, n))
        samples = _drain(sub, 600, samples=True)
        bridge.close()
    assert len(samples) == 600 and bridge.published == 600
    for body_id in (1, 2):
        frames = [s.frame for s in samples if s.frame.body_id == body_id]
        assert [f.frame_number for f in frames] == list(range(300))
        np.testing.assert_array_equal(frames[-1].position_mm, [299.0, 598.0, 3.0])
        assert [f.tracking_valid for f in frames] == [n % 7 != 0 for n in range(300)]
    latencies = [s.latency_s for s in samples]
    assert min(latencies) >= 0.0 and max(latencies) < 1.0
    assert sub.stats.received == 600 and sub.stats.rejected == 0


def test_subscription_to_named_bodies_only(publisher_session, endpoints):
    with ZenohMocapSource(CELL, config=endpoints[1], rigid_bodies=["mti"]) as sub:
        assert wait_for_subscriber(publisher_session, mocap_key(CELL, "mti"), 5.0)
        bridge = MocapBridge(None, publisher_session, CELL, names={1: "weldgun", 2: "mti"})
        for n in range(20):
            bridge.publish(_frame(1, n))
            bridge.publish(_frame(2, n))
        frames = _drain(sub, 20)
        time.sleep(0.1)
        frames += sub.read(0.0)
        bridge.close()
    assert {f.body_id for f in frames} == {2} and len(frames) == 20


def test_bad_payloads_are_counted_and_the_stream_goes_on(publisher_session, endpoints):
    with ZenohMocapSource(CELL, config=endpoints[1]) as sub:
        key = mocap_key(CELL, "weldgun")
        assert wait_for_subscriber(publisher_session, key, 5.0)
        publisher_session.put(key, b"not a frame")
        publisher_session.put(key, b"CM\x09" + encode_mocap(_frame(1, 1), 0.0)[3:])
        publisher_session.put(key, encode_mocap(_frame(1, 5), time.time()))
        frames = _drain(sub, 1)
        deadline = time.monotonic() + 2.0
        while sub.stats.rejected < 2 and time.monotonic() < deadline:
            time.sleep(0.01)
        stats = sub.stats
    assert [f.frame_number for f in frames] == [5]
    assert (stats.received, stats.rejected) == (1, 2) and "version 9" in stats.last_error


def test_joint_states(publisher_session, endpoints):
    other = open_session(endpoints[1])
    try:
        with JointStateSubscriber(other, CELL, "R2") as sub, JointStatePublisher(publisher_session, CELL, "R2") as pub:
            assert sub.latest() is None
            assert wait_for_subscriber(publisher_session, joints_key(CELL, "R2"), 5.0)
            for n in range(50):
                pub.publish(JointState(q=np.full(6, 0.01 * n), stamp=100.0 + n))
            states = _drain(sub, 50)
            assert [s.stamp for s in states] == [100.0 + n for n in range(50)]
            np.testing.assert_array_equal(states[-1].q, np.full(6, 0.49))
            assert sub.latest().stamp == 149.0
            publisher_session.put(joints_key(CELL, "R2"), b"\x00" * 72)
            deadline = time.monotonic() + 2.0
            while sub.stats.rejected < 1 and time.monotonic() < deadline:
                time.sleep(0.01)
            assert sub.stats.rejected == 1
        with pytest.raises(DriverError, match="closed"):
            pub.publish(JointState(q=np.zeros(6), stamp=0.0))
    finally:
        other.close()


def test_natnet_to_zenoh_end_to_end(publisher_session, endpoints):
    """Fake Motive -> NatNetSource -> MocapBridge thread -> zenoh -> ZenohMocapSource."""
    with FakeNatNetServer((4, 1)) as motive, \
            NatNetSource("127.0.0.1", local_address="127.0.0.1", command_port=motive.command_port, data_port=0,
                         multicast_group=None) as natnet, \
            ZenohMocapSource(CELL, config=endpoints[1]) as sub:
        assert wait_for_subscriber(publisher_session, mocap_key(CELL, "weldgun"), 5.0)
        with MocapBridge(natnet, publisher_session, CELL, names={11: "weldgun", 12: "mti"}, poll_s=0.01) as bridge:
            for n in range(1, 101):
                motive.send_frame(FakeFrame(n, (FakeBody(11, (0.001 * n, 0.0, 0.5)), FakeBody(12, (0.0, 0.0, 1.0))),
                                            timestamp=n / 120.0))
            frames = _drain(sub, 200)
        assert (natnet.stats.frames_parsed, bridge.published, sub.stats.received) == (100, 200, 200)
        assert bridge.error is None
    weldgun = [f for f in frames if f.body_id == 11]
    assert [f.frame_number for f in weldgun] == list(range(1, 101))
    np.testing.assert_allclose(weldgun[-1].position_mm, [100.0, 0.0, 500.0], atol=1e-3)
    assert weldgun[-1].capture_time == pytest.approx(100 / 120.0)


class _FailingSource(MocapSource):
    def connect(self) -> None:
        pass

    def read(self, timeout_s: float) -> list[RigidBodyFrame]:
        raise DriverDisconnected("fake", "cable pulled")

    def close(self) -> None:
        pass


def test_bridge_stops_on_source_failure_and_close_is_clean(publisher_session, endpoints):
    before = threading.active_count()
    bridge = MocapBridge(_FailingSource(), publisher_session, CELL)
    bridge.start()
    deadline = time.monotonic() + 2.0
    while bridge.error is None and time.monotonic() < deadline:
        time.sleep(0.01)
    assert isinstance(bridge.error, DriverDisconnected)
    bridge.close()
    bridge.close()
    sub = ZenohMocapSource(CELL, config=endpoints[1])
    sub.connect()
    sub.close()
    sub.close()
    with pytest.raises(DriverError, match="not connected"):
        sub.read(0.01)
    assert threading.active_count() == before


def test_constructor_errors(publisher_session):
    with pytest.raises(DriverError, match="either config or session"):
        ZenohMocapSource(CELL, config=ZenohConfig(), session=publisher_session)
    with pytest.raises(DriverError, match="buffer capacity must be >= 1, got 0"):
        ZenohMocapSource(CELL, session=publisher_session, max_buffered_frames=0)
    with pytest.raises(DriverError, match="rigid body name 'a/b' is not a valid key chunk"):
        ZenohMocapSource(CELL, session=publisher_session, rigid_bodies=["a/b"])


def test_unusable_endpoint_is_a_driver_error():
    with pytest.raises(DriverError, match="cannot open a session"):
        open_session(ZenohConfig(listen=("nonsense/1.2.3.4:1",)))
