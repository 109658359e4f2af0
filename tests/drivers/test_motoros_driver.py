"""MotorosDriver against FakeMotorosController on 127.0.0.1 (real sockets, real protocol, ephemeral ports)."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest

from drivers.errors import DriverDisconnected, DriverError, DriverTimeout, InvalidArgument, RobotFault
from drivers.motoros import FakeMotorosController, MotorosDriver, MotorosLink
from drivers.motoros.codec import (
    JointFeedback,
    JointTrajPtFull,
    JointTrajPtFullEx,
    MotionCtrl,
    MotionReply,
    RobotStatusMsg,
    decode,
)
from drivers.motoros.codes import Command, Result
from drivers.motoros.errors import ControllerNotReady, NonFiniteFeedback
from drivers.motoros.framing import Framer

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
    assert list(fake.received) == [] and fake.points_received == 0


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


def test_a_second_link_gets_no_motion_connection_while_moving(fake, arms, monkeypatch, tmp_path) -> None:
    """MotionServer.c: a new motion connection is closed at once while a queue holds motion."""
    r1, _ = arms
    r1.move_to(Q0[0] + 1.0, 0.5)
    monkeypatch.setenv("CELLCAL_LOCK_DIR", str(tmp_path / "elsewhere"))  # a client on another machine
    with MotorosDriver(_link(fake), 0, SPEED, name="R1b") as other:
        with pytest.raises(DriverDisconnected, match="peer closed|reset|send failed"):
            other.stop()
    r1.stop()


def test_a_second_link_replaces_an_idle_motion_connection(fake, arms, monkeypatch, tmp_path) -> None:
    """MotionServer.c: an idle motion connection is closed for the new one; the old link reconnects later."""
    r1, _ = arms
    monkeypatch.setenv("CELLCAL_LOCK_DIR", str(tmp_path / "elsewhere"))  # a client on another machine
    with MotorosDriver(_link(fake), 0, SPEED, name="R1b") as other:
        other.move_to(Q0[0] + 0.1, 1.0)
        other.wait_settled(2.0)
    r1.move_to(Q0[0], 1.0)  # its connection was closed by the controller: replaced before sending
    np.testing.assert_allclose(r1.wait_settled(2.0).q, Q0[0], atol=1e-4)


def test_a_second_process_on_one_controller_is_refused_before_it_connects(fake, monkeypatch, tmp_path) -> None:
    """MotoROS gives its one motion slot to whichever client connected last, so two collectors on one machine moved
    the arms in turn, each reconnecting over the other (new-user run). The first link claims the controller; a
    second is refused naming the holder and opens nothing; the kernel frees a claim when its process dies."""
    import os
    import signal
    import subprocess
    import sys

    from drivers.errors import DriverError

    monkeypatch.setenv("CELLCAL_LOCK_DIR", str(tmp_path))
    first, second = _link(fake), _link(fake)
    first.connect()
    try:
        with pytest.raises(DriverError, match=rf"another process holds this controller \(pid {os.getpid()}: "):
            second.connect()
        assert second.state_connections == 0  # refused before any connection
    finally:
        first.close()
    second.connect()  # the claim went with the first link
    second.close()
    holder = subprocess.Popen([sys.executable, "-c", "import sys; from drivers.motoros.link import claim_controller; "
                               f"claim_controller('127.0.0.1', {fake.motion_port}, 'x'); print('held', flush=True); "
                               "sys.stdin.read()"], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                              env={**os.environ, "CELLCAL_LOCK_DIR": str(tmp_path)})
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(DriverError, match=rf"\(pid {holder.pid}: -c\)"):
            second.connect()
    finally:
        holder.send_signal(signal.SIGKILL)  # a crash: no cleanup runs
        holder.wait(5)
    second.connect()
    second.close()


# -- behaviour taken from MotoPlus/MotionServer.c and Controller.c ------------------------------------------

PPR = 1.0e5  # pulses per rad of the fake's encoders in these tests


def test_servo_off_is_switched_on_by_start_traj_mode() -> None:
    with FakeMotorosController(max_speed_rad_s=SPEED, initial_q=Q0, servo_on_delay_s=0.3) as fake:
        fake.set_servo(False)
        with MotorosDriver(_link(fake), 0, SPEED) as r1:
            r1.link.wait_state(0.1)
            assert not r1.status().servo_on
            t0 = time.monotonic()
            r1.move_to(Q0[0] + 0.1, 1.0)
            assert time.monotonic() - t0 >= 0.3  # the reply waited for the servos
            np.testing.assert_allclose(r1.wait_settled(2.0).q, Q0[0] + 0.1, atol=1e-4)
            assert r1.status().servo_on
        assert _commands(fake)[:2] == [Command.START_TRAJ_MODE, Command.CHECK_MOTION_READY]


def test_start_traj_mode_has_its_own_longer_timeout() -> None:
    # three waits of up to 5 s each (MotionServer.c, MOTION_START_TIMEOUT): 15 s had no margin
    assert MotorosLink("127.0.0.1").start_traj_timeout_s == 25.0 > 3 * 5.0
    with FakeMotorosController(max_speed_rad_s=SPEED, initial_q=Q0, servo_on_delay_s=0.8) as fake:
        fake.set_servo(False)
        with MotorosDriver(_link(fake, reply_timeout_s=0.3, start_traj_timeout_s=0.4), 0, SPEED) as r1:
            with pytest.raises(DriverTimeout, match="timed out after 0.4 s waiting for reply to command 200121"):
                r1.move_to(Q0[0] + 0.1, 1.0)
        assert _traj_points(fake) == []
        fake.set_servo(False)
        with MotorosDriver(_link(fake, reply_timeout_s=0.3, start_traj_timeout_s=2.0), 0, SPEED) as r1:
            r1.move_to(Q0[0] + 0.1, 1.0)  # 0.8 s to servo on: longer than the reply timeout, within its own
            np.testing.assert_allclose(r1.wait_settled(2.0).q, Q0[0] + 0.1, atol=1e-4)


def test_start_traj_mode_resets_an_alarm_only_when_allowed(fake) -> None:
    fake.set_alarm(4107)
    time.sleep(0.05)
    with MotorosDriver(_link(fake), 0, SPEED, reset_alarms=True) as r1:
        r1.move_to(Q0[0] + 0.1, 1.0)
        np.testing.assert_allclose(r1.wait_settled(2.0).q, Q0[0] + 0.1, atol=1e-4)
        assert not r1.status().alarm


@pytest.mark.parametrize("fault, subcode, words", [
    (lambda f: f.set_remote(False), 5005, "not in remote mode"),
    (lambda f: f.set_hold(True), 5007, "hold"),
    (lambda f: f.set_alarm(4107, resettable=False), 5001, "alarm active"),
])
def test_start_traj_mode_refusal_names_the_cause(fake, fault, subcode, words) -> None:
    fault(fake)
    time.sleep(0.05)
    with MotorosDriver(_link(fake), 0, SPEED, reset_alarms=True) as r1:
        with pytest.raises(ControllerNotReady, match=rf"START_TRAJ_MODE refused: NOT_READY \({subcode}: {words}\)") \
                as err:
            r1.move_to(Q0[0] + 0.1, 1.0)
    assert isinstance(err.value, RobotFault) and err.value.subcode == subcode
    assert _traj_points(fake) == []


def test_check_motion_ready_false_is_refused_with_its_subcode() -> None:
    """The status can say 'motion possible' while the controller has just left remote mode."""
    with FakeMotorosController(max_speed_rad_s=SPEED, initial_q=Q0, publish_hz=4.0) as fake:
        with MotorosDriver(_link(fake, stale_after_s=2.0), 0, SPEED) as r1:
            r1.move_to(Q0[0] + 0.05, 1.0)
            r1.wait_settled(3.0)
            r1.link.wait_state(1.0)
            assert r1.link.status()[0].motion_possible == 1
            fake.set_remote(False)
            points = len(_traj_points(fake))
            with pytest.raises(ControllerNotReady, match=r"CHECK_MOTION_READY is FALSE: not in remote mode "
                                                         r"\(subcode 5005\)") as err:
                r1.move_to(Q0[0], 1.0)
            assert err.value.subcode == 5005
            assert len(_traj_points(fake)) == points


def test_check_motion_ready_answers_true_or_false_with_a_subcode(fake, arms) -> None:
    r1, _ = arms
    ask = lambda command: _ask(r1.link, MotionCtrl(0, 7, command))  # noqa: E731
    assert (ask(Command.CHECK_MOTION_READY).result, ask(Command.CHECK_MOTION_READY).subcode) == (Result.FALSE, 5008)
    assert ask(Command.START_TRAJ_MODE).result == Result.SUCCESS
    assert (ask(Command.CHECK_MOTION_READY).result, ask(Command.CHECK_MOTION_READY).subcode) == (Result.TRUE, 0)
    fake.set_estop(True)
    assert (ask(Command.CHECK_MOTION_READY).result, ask(Command.CHECK_MOTION_READY).subcode) == (Result.FALSE, 5003)


def test_stop_traj_mode_is_sent_when_the_last_driver_closes(fake) -> None:
    link = _link(fake)
    r1, r2 = MotorosDriver(link, 0, SPEED), MotorosDriver(link, 1, SPEED)
    r1.connect()
    r2.connect()
    r1.move_to(Q0[0] + 0.1, 1.0)
    r1.wait_settled(2.0)
    assert link.trajectory_mode
    r1.close()
    assert Command.STOP_TRAJ_MODE not in _commands(fake)  # R2 still uses the controller
    r2.close()
    assert _commands(fake)[-1] == Command.STOP_TRAJ_MODE and not link.trajectory_mode
    with MotorosDriver(_link(fake), 0, SPEED):  # no trajectory mode started: nothing to stop
        pass
    assert _commands(fake).count(Command.STOP_TRAJ_MODE) == 1


def test_queue_count_comes_back_in_the_subcode(fake, arms) -> None:
    r1, _ = arms
    assert r1.queue_count() == 0
    r1.move_to(Q0[0] + 2.0, 0.5)  # 1.5 s: more than the 200 increments of 4 ms the queue holds
    time.sleep(0.1)
    assert r1.queue_count() == 200
    reply = _ask(r1.link, MotionCtrl(3, 1, Command.CHECK_QUEUE_CNT))
    assert (reply.result, reply.subcode) == (Result.FAILURE, -1)
    r1.wait_settled(3.0)
    assert r1.queue_count() == 0


def test_point_zero_must_be_within_30_pulses_of_the_arm(fake, arms) -> None:
    r1, _ = arms
    assert _ask(r1.link, MotionCtrl(0, 1, Command.START_TRAJ_MODE)).result == Result.SUCCESS
    q = fake.q(0)
    near = _ask(r1.link, JointTrajPtFull(0, 0, 0.0, q + 25 / PPR))
    far = _ask(r1.link, JointTrajPtFull(0, 0, 0.0, q + np.array([0, 0, 35 / PPR, 0, 0, 0])))
    assert (near.result, near.subcode) == (Result.SUCCESS, 0)
    assert (far.result, far.subcode) == (Result.INVALID, 3011)


def test_driver_sends_its_feedback_as_point_zero(fake, arms) -> None:
    r1, _ = arms
    r1.move_to(Q0[0] + 0.3, 1.0)
    first = _traj_points(fake)[0]
    assert (first.sequence, first.time) == (0, 0.0)
    np.testing.assert_allclose(first.pos[:6], Q0[0], atol=1e-6)  # float32 on the wire
    np.testing.assert_array_equal(first.vel, 0.0)


def test_sequences_and_times_are_checked_like_motoros(fake, arms) -> None:
    """No consecutive-sequence check; a non-increasing time adds no motion; sequence < 0, time >= 4 h and a
    point without velocity are INVALID."""
    r1, _ = arms
    link = r1.link
    assert _ask(link, MotionCtrl(0, 1, Command.START_TRAJ_MODE)).result == Result.SUCCESS
    q = fake.q(0)
    answers = [_ask(link, p) for p in (
        JointTrajPtFull(0, 0, 0.0, q),
        JointTrajPtFull(0, 5, 0.2, q + 0.1),  # sequence jumps from 0 to 5: accepted
        JointTrajPtFull(0, 6, 0.2, q + 0.5),  # same time: accepted, adds no motion
        JointTrajPtFull(0, -1, 0.3, q),
        JointTrajPtFull(0, 7, 14400.0, q),
        JointTrajPtFull(0, 8, 0.5, q, valid_fields=3),
    )]
    assert [(a.result, a.subcode) for a in answers] == [(0, 0), (0, 0), (0, 0), (3, 3005), (3, 3016), (3, 3015)]
    np.testing.assert_allclose(r1.wait_settled(2.0).q, q + 0.1, atol=1e-5)


@pytest.mark.parametrize("value", [np.nan, np.inf])
def test_non_finite_feedback_never_reaches_a_trajectory(fake, arms, value) -> None:
    r1, _ = arms
    fake.set_nonfinite_feedback(True, value)
    time.sleep(0.05)
    received = len(fake.received)
    with pytest.raises(NonFiniteFeedback, match="joint feedback of group 0 is not finite") as err:
        r1.move_to(Q0[0] + 0.1, 0.5)
    assert isinstance(err.value, DriverError) and not isinstance(err.value, ValueError)
    assert len(fake.received) == received and _traj_points(fake) == []
    with pytest.raises(NonFiniteFeedback):
        r1.read_joints()
    fake.set_nonfinite_feedback(False)
    time.sleep(0.05)
    np.testing.assert_allclose(r1.read_joints().q, Q0[0], atol=1e-6)


def test_non_finite_feedback_names_the_joints_as_plain_numbers() -> None:
    """The message read 'joints [np.int64(1), np.int64(2), ...]' under numpy 2 (new-user run: register with the
    fake controller's SIGUSR2)."""
    err = NonFiniteFeedback("motoros@127.0.0.1:50240/R1", 0, np.array([0.1, np.nan, 0.2, 0.3, np.inf, 0.4]))
    assert "(joints [2, 5]: [0.1, nan, 0.2, 0.3, inf, 0.4])" in str(err), str(err)


def test_a_restarted_controller_on_the_same_ports_is_reconnected() -> None:
    first = FakeMotorosController(max_speed_rad_s=SPEED, initial_q=Q0).start()
    ports = (first.motion_port, first.state_port)
    link = MotorosLink("127.0.0.1", *ports, reply_timeout_s=0.5, connect_timeout_s=1.0, backoff_s=0.02,
                       max_backoff_s=0.1)
    try:
        with MotorosDriver(link, 0, SPEED) as r1:
            r1.move_to(Q0[0] + 0.1, 1.0)
            r1.wait_settled(2.0)
            q_killed = np.stack([first.q(0), first.q(1)])
            first.close()  # the process was killed
            with FakeMotorosController(max_speed_rad_s=SPEED, initial_q=q_killed, motion_port=ports[0],
                                       state_port=ports[1]) as second:
                deadline = time.monotonic() + 2.0
                while link.state_connections < 2:
                    assert time.monotonic() < deadline, "state connection did not come back"
                    time.sleep(0.01)
                r1.link.wait_state(0.1)
                r1.move_to(Q0[0] + 0.2, 1.0)  # the new controller is not in trajectory mode: START again
                np.testing.assert_allclose(r1.wait_settled(2.0).q, Q0[0] + 0.2, atol=1e-4)
                assert Command.START_TRAJ_MODE in _commands(second)
    finally:
        first.close()


@pytest.mark.parametrize("n_groups, types", [(1, [15, 13]), (2, [15, 15, 2017, 13])])
def test_state_stream_is_published_like_the_state_server(n_groups, types) -> None:
    """StateServer.c: feedback per group, JointFeedbackEx only with two groups or more, then the status."""
    with FakeMotorosController(n_groups=n_groups, initial_q=Q0[:n_groups]) as fake:
        with socket.create_connection((fake.host, fake.state_port), timeout=1.0) as sock:
            framer, packets = Framer("test"), []
            while len(packets) < 3 * len(types):
                packets += framer.feed(sock.recv(4096))
    start = next(i for i, p in enumerate(packets) if p.msg_type == 15)
    assert [p.msg_type for p in packets[start:start + len(types)]] == types
    fb = decode(packets[start])
    assert fb.valid_fields == 6 and fb.time == 0.0  # position + velocity, no time, as MotoROS sends it


def test_stop_traj_mode_is_refused_while_a_queue_holds_motion(fake, arms) -> None:
    r1, _ = arms
    r1.move_to(Q0[0] + 1.0, 1.0)
    busy = _ask(r1.link, MotionCtrl(0, 50, Command.STOP_TRAJ_MODE))
    assert busy.result == Result.FAILURE and r1.link.trajectory_mode
    r1.wait_settled(2.0)
    assert _ask(r1.link, MotionCtrl(0, 51, Command.STOP_TRAJ_MODE)).result == Result.SUCCESS
    assert not r1.link.trajectory_mode
    r1.move_to(Q0[0], 1.0)  # motion_possible is 0 again: the driver restarts trajectory mode
    np.testing.assert_allclose(r1.wait_settled(2.0).q, Q0[0], atol=1e-4)


def test_a_peer_that_only_sends_garbage_is_retried_ever_more_slowly() -> None:
    """Issue 12: the state reader reconnected at 20 Hz to a peer that accepts and sends garbage."""
    import socket
    import threading

    from drivers.motoros.state import StateStream

    server = socket.create_server(("127.0.0.1", 0))
    server.settimeout(0.1)
    stop = threading.Event()
    accepted = []

    def serve() -> None:
        while not stop.is_set():
            try:
                conn, _ = server.accept()
            except TimeoutError:
                continue
            accepted.append(time.monotonic())
            conn.sendall(b"\xff\xff\xff\x7fgarbage")
            conn.close()

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    reader_stop = threading.Event()
    stream = StateStream("127.0.0.1", server.getsockname()[1], "motoros-test", reader_stop, connect_timeout_s=0.5,
                         backoff_s=0.05, max_backoff_s=1.0, stale_after_s=0.5)
    stream.start()
    time.sleep(2.0)
    reader_stop.set()
    stream.join()
    stop.set()
    thread.join(timeout=2)
    server.close()
    # doubling from 0.05 s to the 1 s cap: 0, 0.05, 0.15, 0.35, 0.75, 1.55 -> at most 6 tries in 2 s (20 Hz: 40)
    assert 3 <= len(accepted) <= 7, len(accepted)


class _ScriptedLink:
    """The three link calls wait_settled makes, answering from a script of (status, stamp offset) pairs."""

    motion_device = "stub"

    def __init__(self, q: np.ndarray, statuses: list[tuple[RobotStatusMsg, float]], t0: float) -> None:
        self.q, self.statuses, self.t0, self.i = q, statuses, t0, 0

    def feedback(self, group: int):
        self.i = min(self.i + 1, len(self.statuses) - 1)
        return JointFeedback(group, np.r_[self.q, np.zeros(4)]), self.t0 + self.statuses[self.i][1]

    def status(self):
        msg, dt = self.statuses[self.i]
        return msg, self.t0 + dt

    def wait_state(self, timeout_s: float) -> None:
        pass


_ALARM = RobotStatusMsg(drives_powered=1, e_stopped=0, error_code=4107, in_error=1, in_motion=0, mode=2,
                        motion_possible=0)
_CLEAR = RobotStatusMsg(drives_powered=1, e_stopped=0, error_code=0, in_error=0, in_motion=0, mode=2,
                        motion_possible=1)


def _after_reset(statuses: list[tuple[RobotStatusMsg, float]]) -> MotorosDriver:
    t0 = time.monotonic()
    driver = MotorosDriver(_ScriptedLink(Q0[0], statuses, t0), 0, SPEED, reset_alarms=True)
    driver._fresh_after, driver._clear_seen = t0, False  # as START_TRAJ_MODE's reply leaves them
    return driver


def test_a_stale_alarm_status_arriving_after_the_reset_is_not_a_fault() -> None:
    """A status sent before START_TRAJ_MODE reset the alarm may arrive after its reply (two connections)."""
    driver = _after_reset([(_ALARM, 0.0), (_ALARM, 0.01), (_CLEAR, 0.05), (_CLEAR, 0.09), (_CLEAR, 0.13),
                           (_CLEAR, 0.17), (_CLEAR, 0.21)])
    np.testing.assert_allclose(driver.wait_settled(1.0).q, Q0[0])


def test_an_alarm_after_a_clear_status_or_one_that_lasts_is_a_fault() -> None:
    driver = _after_reset([(_CLEAR, 0.0), (_CLEAR, 0.04), (_ALARM, 0.08)] + [(_ALARM, 0.1)] * 5)
    with pytest.raises(RobotFault, match="alarm=True"):
        driver.wait_settled(1.0)
    driver = _after_reset([(_ALARM, 0.01 + 0.1 * k) for k in range(10)])  # the reset did not take:
    driver._target = Q0[0] + 0.1  # the arm does not move
    with pytest.raises(RobotFault, match="code 4107"):
        driver.wait_settled(1.0)


# -- the motion server's handling of each message, as MotionServer.c's WaitForSimpleMsg / SimpleMsgProcess -------


def _raw_client(fake: FakeMotorosController) -> tuple[socket.socket, Framer]:
    sock = socket.create_connection((fake.host, fake.motion_port), timeout=1.0)
    return sock, Framer("test")


def _next(sock: socket.socket, framer: Framer) -> object:
    """The next reply, or 'closed' when the controller hung up (timeout: AssertionError)."""
    from drivers.motoros.codec import decode
    from drivers.motoros.framing import recv_into_framer

    deadline = time.monotonic() + 1.0
    while time.monotonic() < deadline:
        try:
            packets = recv_into_framer(sock, framer)
        except DriverDisconnected:
            return "closed"
        except TimeoutError:
            continue
        if packets:
            return decode(packets[0])
    raise AssertionError("neither a reply nor a close within 1 s")


def test_disconnect_closes_the_connection_without_a_reply(fake) -> None:
    """MotoROS returns 1 from MotionCtrlProcess on DISCONNECT and closes before sending the reply; the fake
    answered it."""
    sock, framer = _raw_client(fake)
    with sock:
        sock.sendall(MotionCtrl(0, 1, Command.CHECK_MOTION_READY).encode())
        assert isinstance(_next(sock, framer), MotionReply)
        sock.sendall(MotionCtrl(0, 2, Command.DISCONNECT).encode())
        assert _next(sock, framer) == "closed"


@pytest.mark.parametrize("msg_type", [999, 2, 2030, 7])
def test_an_unknown_message_type_is_answered_3003_and_the_connection_stays(fake, msg_type) -> None:
    """GetExpectedByteSizeForMessageType has no size: 'Unknown Message Received', INVALID 3003 (the fake said
    3001), and the loop goes on."""
    from drivers.motoros.codec import Packet

    sock, framer = _raw_client(fake)
    with sock:
        sock.sendall(Packet(msg_type, 2, 0, bytes(8)).to_bytes())
        reply = _next(sock, framer)
        assert isinstance(reply, MotionReply) and (reply.result, reply.subcode) == (Result.INVALID, 3003)
        sock.sendall(Packet(msg_type, 3, 0, bytes(8)).to_bytes())  # a reply from the PC: no answer, still connected
        sock.sendall(MotionCtrl(0, 1, Command.CHECK_MOTION_READY).encode())
        reply = _next(sock, framer)
        assert isinstance(reply, MotionReply) and reply.command == Command.CHECK_MOTION_READY


@pytest.mark.parametrize("msg", [RobotStatusMsg(1, 0, 0, 0, 0, 2, 1),
                                 JointFeedback(0, np.zeros(6), np.zeros(6)),
                                 MotionReply(0, 1, Command.STOP_MOTION, Result.SUCCESS, 0)])
def test_a_type_the_motion_port_does_not_serve_drops_the_connection(fake, msg) -> None:
    """SimpleMsgProcess's default returns ERROR: WaitForSimpleMsg breaks out and closes, no reply sent; the fake
    stayed connected."""
    sock, framer = _raw_client(fake)
    with sock:
        sock.sendall(msg.encode())
        assert _next(sock, framer) == "closed"


def test_a_connection_replaced_before_its_thread_runs_does_not_kill_the_thread(monkeypatch) -> None:
    """After a reconnect the fake's thread of the replaced connection died with EBADF (settimeout on a socket the
    newer connection had already closed): a thread scheduled late, as on a loaded machine."""
    errors: list[BaseException] = []
    monkeypatch.setattr(threading, "excepthook", lambda args: errors.append(args.exc_value))
    serve = FakeMotorosController._serve_motion

    def late(self, sock):  # noqa: ANN001
        time.sleep(0.2)
        serve(self, sock)

    monkeypatch.setattr(FakeMotorosController, "_serve_motion", late)
    with FakeMotorosController(max_speed_rad_s=SPEED, initial_q=Q0) as fake:
        first = socket.create_connection((fake.host, fake.motion_port), timeout=1.0)
        time.sleep(0.05)
        second = socket.create_connection((fake.host, fake.motion_port), timeout=1.0)  # replaces the first
        time.sleep(0.4)
        first.close()
        second.close()
    assert errors == []


def test_the_fake_keeps_a_bounded_request_history(monkeypatch) -> None:
    """Every request was kept in a list that never shrank; a rehearsal sends about 100 points a second."""
    import drivers.motoros.fake as fake_module

    monkeypatch.setattr(fake_module, "MAX_KEPT_REQUESTS", 5)
    with FakeMotorosController(max_speed_rad_s=SPEED, initial_q=Q0) as fake:
        sock, framer = _raw_client(fake)
        with sock:
            for k in range(20):
                sock.sendall(MotionCtrl(0, k, Command.CHECK_MOTION_READY).encode())
                assert isinstance(_next(sock, framer), MotionReply)
        assert [m.sequence for m in fake.received] == list(range(15, 20))


def test_close_while_an_acceptor_starts_a_handler_joins_it_once_started(monkeypatch: pytest.MonkeyPatch) -> None:
    """close() racing a client's connection: the acceptor's new handler thread may be between its creation and its
    start when close() walks the thread list. A fresh-clone run met it once ("cannot join thread before it is
    started" at teardown); here each of the fake's thread starts is slowed so the window is wide, and close() must
    wait for the start, join, and leave no thread running."""
    import drivers.motoros.fake as fake_module

    real_thread = threading.Thread

    class SlowStart(real_thread):
        def start(self) -> None:
            time.sleep(0.3)
            super().start()

    monkeypatch.setattr(fake_module.threading, "Thread", SlowStart)
    threads_before = set(threading.enumerate())
    controller = FakeMotorosController(max_speed_rad_s=SPEED, initial_q=Q0).start()
    client = socket.create_connection(("127.0.0.1", controller.motion_port), timeout=2.0)
    try:
        time.sleep(0.1)  # the acceptor took the client and is starting its handler (0.3 s)
        controller.close()
    finally:
        client.close()
        monkeypatch.undo()
    leaked = [t for t in set(threading.enumerate()) - threads_before if t.is_alive()]
    assert not leaked, f"threads left running: {leaked}"
