"""MotorosDriver against FakeMotorosController on 127.0.0.1 (real sockets, real protocol, ephemeral ports)."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest

from drivers.errors import DriverDisconnected, DriverError, DriverTimeout, RobotFault
from drivers.motoros import FakeMotorosController, MotorosDriver, MotorosLink
from drivers.motoros.codec import Command, JointTrajPtFull, JointTrajPtFullEx, MotionCtrl, MotionReply, Result
from drivers.motoros.errors import ControllerNotReady, InvalidArgument, NonFiniteFeedback

SPEED = np.full(6, 4.0)  # rad/s, fake and driver agree
Q0 = np.array([[0.1, -0.2, 0.3, 0.0, 0.5, -0.6], [-1.0, 0.25, 0.0, 0.5, 0.0, 1.5]])


@pytest.fixture
def fake() -> Iterator[FakeMotorosController]:
    threads_before = set(threading.enumerate())
    with FakeMotorosController(max_speed_rad_s=SPEED, initial_q=Q0) as controller:
        yield controller
    leaked = [t for t in set(threading.enumerate()) - threads_before if t.is_alive()]
    assert not leaked, f"threads left running: {leaked}"


def _link(fake: FakeMotorosController, **kw: float) -> MotorosLink:
    options = dict(reply_timeout_s=0.5, connect_timeout_s=1.0, backoff_s=0.02, max_backoff_s=0.1)
    options.update(kw)
    return MotorosLink("127.0.0.1", fake.motion_port, fake.state_port, **options)


@pytest.fixture
def arms(fake: FakeMotorosController) -> Iterator[tuple[MotorosDriver, MotorosDriver]]:
    link = _link(fake)
    with MotorosDriver(link, 0, SPEED) as r1, MotorosDriver(link, 1, SPEED) as r2:
        yield r1, r2


def _traj_points(fake: FakeMotorosController) -> list:
    return [m for m in fake.received if isinstance(m, (JointTrajPtFull, JointTrajPtFullEx))]


def _commands(fake: FakeMotorosController) -> list[int]:
    return [m.command for m in fake.received if isinstance(m, MotionCtrl)]


def _ask(link: MotorosLink, msg: MotionCtrl | JointTrajPtFull) -> MotionReply:
    """One raw request through the link, matched like the driver matches its own."""
    command = msg.command if isinstance(msg, MotionCtrl) else msg.TYPE
    return link.request(msg.encode(), msg.group, msg.sequence, command)


def test_reads_both_groups_of_one_controller(arms) -> None:
    r1, r2 = arms
    np.testing.assert_allclose(r1.read_joints().q, Q0[0], atol=1e-6)
    np.testing.assert_allclose(r2.read_joints().q, Q0[1], atol=1e-6)
    assert abs(r1.read_joints().stamp - time.monotonic()) < 0.5
    assert r1.status().ready and r1.name == "R1" and r2.name == "R2"


def test_move_and_settle_moves_only_its_group(fake, arms) -> None:
    r1, r2 = arms
    target = Q0[0] + np.array([0.4, -0.2, 0.1, 0.3, -0.1, 0.2])
    r1.move_to(target, speed_fraction=1.0)
    settled = r1.wait_settled(timeout_s=2.0, tolerance_rad=1e-4)
    np.testing.assert_allclose(settled.q, target, atol=1e-4)
    np.testing.assert_allclose(fake.q(0), target, atol=1e-6)
    np.testing.assert_allclose(r2.read_joints().q, Q0[1], atol=1e-6)
    assert [p.sequence for p in _traj_points(fake)] == [0, 1]


def test_speed_fraction_sets_the_duration(fake, arms) -> None:
    r1, _ = arms
    r1.move_to(Q0[0] + np.array([0.4, 0, 0, 0, 0, 0]), speed_fraction=0.5)
    last = _traj_points(fake)[-1]
    assert last.time == pytest.approx(1.5 * 0.4 / (4.0 * 0.5))  # cubic peak speed = 0.5 * max


def test_feedback_speed_stays_within_the_limit(fake, arms) -> None:
    r1, _ = arms
    r1.move_to(Q0[0] + 1.0, speed_fraction=1.0)
    peak = 0.0
    while r1.status().in_motion or peak == 0.0:
        peak = max(peak, float(np.max(np.abs(r1.link.feedback(0)[0].vel))))
        r1.link.wait_state(0.05)
    assert 0.8 * 4.0 < peak <= 4.0 * 1.01


def test_both_arms_move_at_once_through_the_shared_link(fake, arms) -> None:
    targets = Q0 + 0.3
    errors: list[BaseException] = []

    def run(arm: MotorosDriver, q: np.ndarray) -> None:
        try:
            arm.move_to(q, 1.0)
            arm.wait_settled(2.0)
        except BaseException as e:  # re-raised below in the test thread
            errors.append(e)

    threads = [threading.Thread(target=run, args=(arm, q)) for arm, q in zip(arms, targets)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    np.testing.assert_allclose(np.stack([fake.q(0), fake.q(1)]), targets, atol=1e-6)


def test_full_ex_trajectory_message(fake) -> None:
    with MotorosDriver(_link(fake), 1, SPEED, trajectory_message="full_ex") as r2:
        r2.move_to(Q0[1] - 0.2, 1.0)
        r2.wait_settled(2.0)
    assert all(isinstance(p, JointTrajPtFullEx) for p in _traj_points(fake))
    np.testing.assert_allclose(fake.q(1), Q0[1] - 0.2, atol=1e-6)


def test_stop_halts_short_of_the_target(fake, arms) -> None:
    r1, _ = arms
    target = Q0[0] + 2.0
    r1.move_to(target, speed_fraction=1.0)  # 0.75 s move
    time.sleep(0.15)
    r1.stop()
    held = r1.wait_settled(timeout_s=1.0)
    assert np.max(np.abs(held.q - Q0[0])) > 0.01
    assert np.max(np.abs(held.q - target)) > 1.0
    assert not r1.status().in_motion


@pytest.mark.parametrize("fault, message", [
    (lambda f: f.set_alarm(4107), "alarm 4107"),
    (lambda f: f.set_estop(True), "e-stop"),
    (lambda f: f.set_mode(play=False), "pendant in TEACH mode"),
])
def test_faults_refuse_motion_before_anything_is_sent(fake, arms, fault, message) -> None:
    r1, _ = arms
    fault(fake)
    time.sleep(0.05)  # one status publication
    received = len(fake.received)
    with pytest.raises(ControllerNotReady, match=f"motion refused: .*{message}") as err:
        r1.move_to(Q0[0] + 0.1, 0.5)
    assert isinstance(err.value, RobotFault) and message in err.value.cause
    assert len(fake.received) == received
    np.testing.assert_allclose(fake.q(0), Q0[0], atol=1e-6)


def test_controller_refusal_is_a_robot_fault() -> None:
    """The status seen by the driver can lag; the controller's NOT_READY reply must still stop the move."""
    with FakeMotorosController(max_speed_rad_s=SPEED, initial_q=Q0, publish_hz=4.0) as fake:
        with MotorosDriver(_link(fake, stale_after_s=2.0), 0, SPEED) as r1:
            r1.link.wait_state(1.0)  # just after a publication: the next one is 250 ms away
            fake.set_estop(True)
            assert r1.status().ready  # not yet published
            with pytest.raises(RobotFault, match=r"START_TRAJ_MODE refused: NOT_READY \(5003: e-stop\)"):
                r1.move_to(Q0[0] + 0.1, 0.5)
            assert _traj_points(fake) == []


def test_alarm_during_motion_raises_while_waiting(fake, arms) -> None:
    r1, _ = arms
    r1.move_to(Q0[0] + 2.0, speed_fraction=0.25)
    time.sleep(0.05)
    fake.set_alarm(4321)
    with pytest.raises(RobotFault, match="code 4321"):
        r1.wait_settled(timeout_s=1.0)


def test_missing_group_fails_at_connect(fake) -> None:
    link = _link(fake, connect_timeout_s=0.2)
    with pytest.raises(DriverTimeout, match="R3: timed out after 0.2 s waiting for feedback of motion group 2"):
        MotorosDriver(link, 2, SPEED).connect()
    with MotorosDriver(link, 0, SPEED):  # the failed driver released its share of the link
        pass


def test_bad_arguments_are_refused_with_nothing_sent(fake, arms) -> None:
    r1, _ = arms
    with pytest.raises(InvalidArgument, match="R1: q must be 6 finite joint angles") as err:
        r1.move_to(np.zeros(5), 0.5)
    assert err.value.argument == "q" and not isinstance(err.value, ValueError)
    with pytest.raises(InvalidArgument, match="R1: q must be 6 finite"):
        r1.move_to(np.array([0, 0, np.nan, 0, 0, 0]), 0.5)
    with pytest.raises(InvalidArgument, match=r"speed_fraction must be in \(0, 1\], got 1.5") as err:
        r1.move_to(Q0[0], 1.5)
    assert (err.value.argument, err.value.value) == ("speed_fraction", 1.5)
    with pytest.raises(InvalidArgument, match="shorter than 14400 s"):
        r1.move_to(Q0[0] + 1.0, 1e-5)
    with pytest.raises(InvalidArgument, match="max_speed_rad_s must be positive"):
        MotorosDriver(r1.link, 0, -SPEED)
    with pytest.raises(InvalidArgument, match="reconnect_attempts must be >= 1, got 0"):
        MotorosLink("127.0.0.1", reconnect_attempts=0)
    assert fake.received == []


def test_reconnects_after_the_controller_drops_connections(fake, arms) -> None:
    r1, _ = arms
    fake.drop_connections()
    deadline = time.monotonic() + 1.0
    while r1.link.state_connections < 2:  # the state reader reconnects in the background
        assert time.monotonic() < deadline, "state connection did not come back"
        time.sleep(0.01)
    r1.link.wait_state(0.1)
    r1.move_to(Q0[0] + 0.1, 1.0)  # the dead idle motion connection is replaced before sending
    np.testing.assert_allclose(r1.wait_settled(2.0).q, Q0[0] + 0.1, atol=1e-4)


def test_state_outage_is_reported_as_disconnected(fake, arms) -> None:
    r1, _ = arms
    fake.close()
    deadline = time.monotonic() + 1.0
    while True:
        try:
            r1.read_joints()
        except DriverDisconnected as e:
            assert "state connection down" in str(e)
            break
        assert time.monotonic() < deadline, "outage not noticed"
        time.sleep(0.01)


def test_controller_gone_raises_disconnected(fake, arms) -> None:
    r1, _ = arms
    fake.close()
    with pytest.raises(DriverDisconnected, match="no connection after 3 attempts"):
        r1.stop()


def test_nothing_listening_raises_disconnected(fake) -> None:
    link = MotorosLink("127.0.0.1", fake.motion_port, fake.state_port, backoff_s=0.01, connect_timeout_s=0.5)
    fake.close()
    with pytest.raises(DriverDisconnected, match="no connection after 3 attempts"):
        MotorosDriver(link, 0, SPEED).connect()


def test_stalled_reply_times_out_then_recovers(fake, arms) -> None:
    r1, _ = arms
    fake.stall_replies(True)
    t0 = time.monotonic()
    with pytest.raises(DriverTimeout, match="timed out after 0.5 s"):
        r1.stop()
    assert time.monotonic() - t0 < 0.9
    fake.stall_replies(False)
    r1.stop()  # a fresh connection, so the stale reply cannot be mistaken for this one


def test_messages_split_into_one_byte_chunks() -> None:
    # 25 Hz: one send() per byte is costly, and a loaded test machine must not starve the publisher
    with FakeMotorosController(max_speed_rad_s=SPEED, initial_q=Q0, publish_hz=25.0) as fake:
        fake.split_messages(1, delay_s=0.0)
        with MotorosDriver(_link(fake, stale_after_s=1.0, reply_timeout_s=1.0), 0, SPEED) as r1:
            r1.move_to(Q0[0] + 0.05, 1.0)
            np.testing.assert_allclose(r1.wait_settled(3.0).q, Q0[0] + 0.05, atol=1e-4)


def test_garbage_on_the_state_stream_is_survived(fake, arms, caplog) -> None:
    r1, _ = arms
    with caplog.at_level("WARNING", logger="cellcal.drivers"):
        fake.inject_state_bytes(b"\xff\xff\xff\x7fgarbage")
        time.sleep(0.2)  # reader drops the stream and reconnects
    assert "length prefix 2147483647 outside [12, 4096]; stream is corrupt; reconnecting" in caplog.text
    np.testing.assert_allclose(r1.read_joints().q, Q0[0], atol=1e-6)


def test_a_second_link_gets_no_motion_connection_while_moving(fake, arms) -> None:
    """MotionServer.c: a new motion connection is closed at once while a queue holds motion."""
    r1, _ = arms
    r1.move_to(Q0[0] + 1.0, 0.5)
    with MotorosDriver(_link(fake), 0, SPEED, name="R1b") as other:
        with pytest.raises(DriverDisconnected, match="peer closed|reset|send failed"):
            other.stop()
    r1.stop()


def test_a_second_link_replaces_an_idle_motion_connection(fake, arms) -> None:
    """MotionServer.c: an idle motion connection is closed for the new one; the old link reconnects later."""
    r1, _ = arms
    with MotorosDriver(_link(fake), 0, SPEED, name="R1b") as other:
        other.move_to(Q0[0] + 0.1, 1.0)
        other.wait_settled(2.0)
    r1.move_to(Q0[0], 1.0)  # its connection was closed by the controller: replaced before sending
    np.testing.assert_allclose(r1.wait_settled(2.0).q, Q0[0], atol=1e-4)
