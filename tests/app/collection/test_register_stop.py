"""A registration that ends early (an alarm, a lost controller, Ctrl-C) stops the arm and commands nothing more: the
arm used to be driven back to its start pose from a ``finally``, a new motion right after the operator's Ctrl-C."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from sim_cell import FAST, R2_PARK, make_cell

from app.collection.register import measure_registration
from drivers.errors import RobotFault
from drivers.sim import SimFault, SimRobotDriver, planted_truth

Q_CENTER = np.radians([1, -50, -50, 1, 1, 1])


class Counting:
    """The simulated arm, counting ``move_to`` and ``stop``; ``interrupt_at`` raises Ctrl-C on that move."""

    def __init__(self, driver, interrupt_at: int | None = None) -> None:
        self.driver, self.interrupt_at, self.moves, self.stops = driver, interrupt_at, 0, 0

    def __getattr__(self, name):
        return getattr(self.driver, name)

    def move_to(self, q, speed_fraction):
        self.moves += 1
        if self.moves == self.interrupt_at:
            raise KeyboardInterrupt
        return self.driver.move_to(q, speed_fraction)

    def stop(self) -> None:
        self.stops += 1
        self.driver.stop()


def _plan(n: int) -> np.ndarray:
    plan = np.repeat(Q_CENTER[None], n, axis=0)
    plan[:, 4] += np.radians(np.linspace(-10, 10, n))
    return plan


@pytest.mark.parametrize("end", ["ctrl-c", "alarm"])
def test_a_registration_ended_early_stops_the_arm_and_moves_it_no_more(end):
    cell, driver, mocap, _, safety = make_cell()
    arm = Counting(driver, interrupt_at=3 if end == "ctrl-c" else None)
    if end == "alarm":
        driver.schedule_fault(SimFault.ALARM, at_call=3)
    r2 = SimRobotDriver("R2", cell.robot("R2").robot, planted_truth(cell.robot("R2").model(), seed=2), q0=R2_PARK,
                        clock=driver.clock)
    rt = SimpleNamespace(cell=cell, drivers={"R1": arm}, others=lambda robot: {"R2": r2},
                         mocap_for=lambda robot: mocap, body_ids={"R1": 1})
    with driver, r2, mocap:
        with pytest.raises(KeyboardInterrupt if end == "ctrl-c" else RobotFault):
            measure_registration(rt, safety, "R1", _plan(6), FAST, progress=False)
    assert arm.moves == 3 and arm.stops == 1  # no move back to the start pose after the third
