"""CanContactProbe against SimulatedProbe on python-can's virtual bus (one unique channel per test)."""

from __future__ import annotations

import threading
import time
import uuid
from collections.abc import Iterator

import pytest

from drivers.can_probe import STATUS_ARMED, STATUS_CONTACT, CanContactProbe, ProbeStats, encode_event, encode_heartbeat
from drivers.errors import DriverError, DriverTimeout
from drivers.sim.can_probe import SimulatedProbe


@pytest.fixture
def pair() -> Iterator[tuple[CanContactProbe, SimulatedProbe]]:
    channel = f"probe-{uuid.uuid4().hex}"
    threads_before = set(threading.enumerate())
    with CanContactProbe(channel, interface="virtual", heartbeat_timeout_s=0.2) as probe, \
            SimulatedProbe(channel, heartbeat_period_s=0.02) as sim:
        _wait(lambda: probe.stats.heartbeats > 0)
        yield probe, sim
    assert not [t for t in set(threading.enumerate()) - threads_before if t.is_alive()]


def _wait(condition, timeout_s: float = 1.0) -> None:  # noqa: ANN001
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, "condition not met in time"
        time.sleep(0.005)


def test_frame_layout() -> None:
    assert encode_heartbeat(257, STATUS_ARMED) == (0x5A0, b"\x01\x01")
    assert encode_event(True, 7, 0x01020304) == (0x5A1, b"\x01\x07\x04\x03\x02\x01")
    assert encode_event(False, 256, 5, base_id=0x100) == (0x101, b"\x00\x00\x05\x00\x00\x00")


def test_touch_and_release_are_decoded(pair) -> None:
    probe, sim = pair
    seq = sim.touch()
    _wait(lambda: probe.latest is not None)
    event = probe.latest
    assert event.touched and event.sequence == seq and event.probe_time_ms >= 0
    assert abs(event.stamp - time.monotonic()) < 0.5
    _wait(lambda: probe.status_bits == STATUS_ARMED | STATUS_CONTACT)
    sim.release()
    _wait(lambda: not probe.latest.touched)
    assert probe.latest.sequence == seq + 1
    assert probe.stats.events == 2 and probe.stats.malformed == 0


def test_wait_for_contact_returns_the_next_touch(pair) -> None:
    probe, sim = pair
    sim.touch()
    _wait(lambda: probe.latest is not None)
    sim.release()
    timer = threading.Timer(0.05, sim.touch)
    timer.start()
    event = probe.wait_for_contact(timeout_s=1.0)  # the touch before the call does not count
    timer.join()
    assert event.touched and event.sequence == 3


def test_wait_for_contact_times_out(pair) -> None:
    probe, _ = pair
    t0 = time.monotonic()
    with pytest.raises(DriverTimeout, match="timed out after 0.1 s waiting for a contact"):
        probe.wait_for_contact(timeout_s=0.1)
    assert time.monotonic() - t0 < 0.5


def test_heartbeat_loss_is_detected(pair) -> None:
    probe, sim = pair
    probe.check_alive()
    assert probe.is_alive() and probe.heartbeat_age_s() < 0.2
    sim.heartbeat_paused = True
    with pytest.raises(DriverTimeout, match="timed out after 0.2 s waiting for the probe heartbeat"):
        probe.wait_for_contact(timeout_s=2.0)
    assert not probe.is_alive()
    sim.heartbeat_paused = False
    _wait(probe.is_alive)


def test_no_probe_on_the_bus_is_a_timeout() -> None:
    with CanContactProbe(f"empty-{uuid.uuid4().hex}", interface="virtual", heartbeat_timeout_s=0.05) as probe:
        with pytest.raises(DriverTimeout, match="probe heartbeat"):
            probe.wait_for_contact(timeout_s=1.0)


@pytest.mark.parametrize("frame", [
    dict(arbitration_id=0x5A1, data=b"\x01\x02"),  # short event
    dict(arbitration_id=0x5A1, data=b"\x07\x01\x00\x00\x00\x00"),  # unknown state
    dict(arbitration_id=0x5A0, data=b"\x01\x01\x00"),  # long heartbeat
    dict(arbitration_id=0x5A0, data=b"\x01\x80"),  # unknown status bit
    dict(arbitration_id=0x5A0, data=b"", is_remote_frame=True, dlc=2),  # remote frame
])
def test_malformed_frames_are_counted_and_ignored(pair, frame) -> None:
    probe, sim = pair
    sim.send_raw(**frame)
    _wait(lambda: probe.stats.malformed == 1)
    assert probe.latest is None
    sim.touch()  # still decoding after the bad frame
    _wait(lambda: probe.latest is not None)
    assert probe.stats.malformed == 1


def test_foreign_ids_are_not_malformed(pair) -> None:
    probe, sim = pair
    sim.send_raw(0x123, b"\xff" * 8)
    sim.touch()
    _wait(lambda: probe.latest is not None)
    assert probe.stats.malformed == 0


def test_sequence_gaps_count_lost_events(pair) -> None:
    probe, sim = pair
    sim.touch()
    sim.skip_events(3)
    sim.release()
    _wait(lambda: probe.stats.events == 2)
    assert probe.stats == ProbeStats(heartbeats=probe.stats.heartbeats, events=2, malformed=0, lost_events=3)


def test_unopenable_bus_is_a_driver_error() -> None:
    probe = CanContactProbe("can-does-not-exist", interface="no-such-interface")
    with pytest.raises(DriverError, match="can-probe@no-such-interface:can-does-not-exist: cannot open the bus"):
        probe.connect()
    probe.close()


def test_bad_arguments_and_unconnected_use() -> None:
    with pytest.raises(ValueError, match="heartbeat_timeout_s must be > 0, got 0"):
        CanContactProbe("x", interface="virtual", heartbeat_timeout_s=0)
    with pytest.raises(DriverError, match="not connected"):
        CanContactProbe("x", interface="virtual").check_alive()
