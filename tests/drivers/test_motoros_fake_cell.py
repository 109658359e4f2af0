"""The cell's fake MotoROS controller: groups and arms from the cell description, signals from outside."""

from __future__ import annotations

import os
import signal
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from calibration.errors import ConfigError
from cell_config import DEFAULT_CELL, load_cell
from drivers.motoros import MotorosDriver, MotorosLink
from drivers.motoros.codec import JointTrajPtFull, MotionCtrl
from drivers.motoros.codes import Command
from drivers.motoros.errors import NonFiniteFeedback
from drivers.motoros.fake_cell import build_fake_controller, run_fake_controller

ROBOTS = load_cell(DEFAULT_CELL).robots
Q_R1 = np.array([0.1, -0.2, 0.3, 0.0, 0.5, -0.6])
Q_R2 = np.array([-1.0, 0.25, 0.0, 0.5, 0.0, 1.5])


def _cell(groups: dict[str, int] | None = None) -> SimpleNamespace:
    """A stand-in for CellSpec with the ``controller`` block of the shared contract."""
    controller = SimpleNamespace(host="127.0.0.1", motion_port=0, state_port=0,
                                 groups={"R1": 0, "R2": 1} if groups is None else groups)
    return SimpleNamespace(path=Path("cell.yaml"), robots=ROBOTS, controller=controller)


def _link(fake) -> MotorosLink:
    return MotorosLink(fake.host, fake.motion_port, fake.state_port, reply_timeout_s=0.5, connect_timeout_s=1.0,
                       backoff_s=0.02, max_backoff_s=0.1)


def test_serves_every_group_with_the_arms_of_the_robot_yamls() -> None:
    with build_fake_controller(_cell(), initial_q={"R1": Q_R1, "R2": Q_R2}) as fake:
        for i, name in enumerate(("R1", "R2")):
            np.testing.assert_allclose(fake.groups[i].max_speed_rad_s, ROBOTS[name].robot.max_speed_rad_s)
            np.testing.assert_allclose(fake.groups[i].pulses_per_rad, ROBOTS[name].robot.pulses_per_rad)
        link = _link(fake)
        with MotorosDriver(link, 0, ROBOTS["R1"].robot.max_speed_rad_s) as r1, \
                MotorosDriver(link, 1, ROBOTS["R2"].robot.max_speed_rad_s) as r2:
            np.testing.assert_allclose(r1.read_joints().q, Q_R1, atol=1e-6)
            np.testing.assert_allclose(r2.read_joints().q, Q_R2, atol=1e-6)
            r2.move_to(Q_R2 + 0.05, 0.5)
            np.testing.assert_allclose(r2.wait_settled(3.0).q, Q_R2 + 0.05, atol=1e-4)


def test_point_zero_tolerance_is_30_pulses_of_the_robot_yaml() -> None:
    ppr = ROBOTS["R1"].robot.pulses_per_rad[0]  # MA2010 S axis: pulses_per_deg * 180 / pi
    with build_fake_controller(_cell(), initial_q={"R1": Q_R1}) as fake:
        link = _link(fake)
        with MotorosDriver(link, 0, ROBOTS["R1"].robot.max_speed_rad_s):
            link.request(MotionCtrl(0, 1, Command.START_TRAJ_MODE).encode(), 0, 1, Command.START_TRAJ_MODE)
            for pulses, subcode in ((25, 0), (35, 3011)):
                q = Q_R1 + np.array([pulses / ppr, 0, 0, 0, 0, 0])
                reply = link.request(JointTrajPtFull(0, 0, 0.0, q).encode(), 0, 0, 14)
                assert reply.subcode == subcode, pulses


@pytest.mark.parametrize("groups, message", [
    ({"R1": 0, "R2": 2}, "group indices 0..n-1"),
    ({"R1": 0, "R9": 1}, "unknown robots \\['R9'\\]; valid: R1, R2"),
])
def test_bad_groups_are_config_errors(groups, message) -> None:
    with pytest.raises(ConfigError, match=f"cell.yaml: controller.groups: .*{message}"):
        build_fake_controller(_cell(groups))


def test_no_controller_block_is_a_config_error() -> None:
    with pytest.raises(ConfigError, match="no controller block"):
        build_fake_controller(SimpleNamespace(path=Path("cell.yaml"), robots=ROBOTS, controller=None))


def test_signals_raise_an_alarm_and_toggle_nan_feedback() -> None:
    """run_fake_controller in the main thread (signal handlers live there), a client in another."""
    stop = threading.Event()
    ready: list = []
    seen: dict[str, object] = {}
    errors: list[BaseException] = []

    def client() -> None:
        try:
            deadline = time.monotonic() + 5.0
            while not ready:
                assert time.monotonic() < deadline, "fake never ready"
                time.sleep(0.01)
            with MotorosDriver(_link(ready[0]), 0, ROBOTS["R1"].robot.max_speed_rad_s) as r1:
                os.kill(os.getpid(), signal.SIGUSR1)
                seen["alarm"] = _poll(lambda: r1.status().error_code == 4107)
                os.kill(os.getpid(), signal.SIGUSR2)
                seen["nan"] = _poll(lambda: _raises(r1.read_joints, NonFiniteFeedback))
                os.kill(os.getpid(), signal.SIGUSR2)
                seen["finite"] = _poll(lambda: not _raises(r1.read_joints, NonFiniteFeedback))
        except BaseException as e:  # re-raised in the test thread
            errors.append(e)
        finally:
            stop.set()

    before = signal.getsignal(signal.SIGUSR1), signal.getsignal(signal.SIGUSR2)
    thread = threading.Thread(target=client)
    thread.start()
    run_fake_controller(_cell(), stop, on_ready=ready.append, servo_on_delay_s=0.05)
    thread.join()
    assert not errors, errors
    assert seen == {"alarm": True, "nan": True, "finite": True}
    assert (signal.getsignal(signal.SIGUSR1), signal.getsignal(signal.SIGUSR2)) == before


def _poll(condition, timeout_s: float = 2.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.02)
    return False


def _raises(fn, exc: type[BaseException]) -> bool:
    try:
        fn()
    except exc:
        return True
    return False
