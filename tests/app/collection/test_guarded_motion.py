"""Every motion of either arm goes through the cell-safety check: validate-dual's contact moves and move_safely."""

from __future__ import annotations

import numpy as np
import pytest

from app.collection.motion import move_safely
from app.collection.safety import CellSafety
from app.dual.validate import check_contact_sequence, collect_contacts
from calibration.errors import UnsafeTarget
from cell_config import load_cell
from drivers.sim import SimClock, SimRobotConfig, SimRobotDriver, planted_truth

R1_START = np.radians([1, -50, -50, 1, 1, 1])
R2_START = np.radians([0, 40, 0, 0, 0, 0])
R1_INTO_R2 = np.radians([-10, 70, 60, 0, 0, 0])  # R1 reaching into R2 at R2_START


@pytest.fixture()
def arms():
    cell = load_cell()
    clock = SimClock(50.0)
    drivers = {}
    for k, (name, q0) in enumerate((("R1", R1_START), ("R2", R2_START))):
        spec = cell.robot(name)
        drivers[name] = SimRobotDriver(name, spec.robot, planted_truth(spec.model(), seed=k), q0=q0, clock=clock,
                                       config=SimRobotConfig(settle_time_s=0.05))
        drivers[name].connect()
    yield cell, CellSafety(cell), drivers
    for d in drivers.values():
        d.close()


def test_an_unsafe_contact_move_is_refused_with_zero_motion(arms):
    _, safety, drivers = arms
    here = np.concatenate([R1_START, R2_START])
    safe = np.concatenate([R1_START + np.radians([0, 5, 0, 0, 0, 0]), R2_START])
    unsafe = np.concatenate([R1_INTO_R2, R2_START])
    with pytest.raises(UnsafeTarget, match=r"R1: .* too close to R2 .*at target 2"):
        collect_contacts(drivers, None, np.stack([here, safe, unsafe]), safety)
    assert [d.move_calls for d in drivers.values()] == [0, 0]
    # R1's move is safe with R2 still turned away; R2's move then hits R1 at its new pose
    r2_park, r1_reach = np.radians([90, 0, 0, 0, 0, 0]), np.radians([-10, 50, 20, 0, 0, 0])
    safety.check_motion("R1", R1_START, r1_reach, {"R2": r2_park})
    with pytest.raises(UnsafeTarget, match=r"R2: .* too close to R1 .*at target 0"):
        check_contact_sequence(safety, np.concatenate([r1_reach, R2_START])[None], np.concatenate([R1_START, r2_park]))


def test_move_safely_checks_against_the_other_arms_live_pose(arms):
    _, safety, drivers = arms
    r1, r2 = drivers["R1"], drivers["R2"]
    r2.move_to(np.radians([90, 0, 0, 0, 0, 0]), 0.5)  # R2 turns away: R1's reach is safe now
    r2.wait_settled(60.0)
    move_safely(r2, R2_START, safety, {"R1": r1}, 0.5)  # and back: checked against R1's live pose
    with pytest.raises(UnsafeTarget, match="R1: .* too close to R2"):
        move_safely(r1, R1_INTO_R2, safety, {"R2": r2}, 0.5)
    assert r1.move_calls == 0 and r2.move_calls == 2
    np.testing.assert_allclose(r1.read_joints().q, R1_START, atol=1e-4)
