"""A simulated cell for the session tests; run as a script it collects a session (for the SIGKILL test)."""

from __future__ import annotations

import sys

import numpy as np

from app.collection.collect import CollectConfig, run_session
from app.collection.plans.poses import build_plan, plan_anchor_grid
from app.collection.safety import CellSafety
from cell_config import load_cell
from drivers.sim import SimClock, SimMocapConfig, SimMocapSource, SimRobotConfig, SimRobotDriver, planted_truth

FAST = CollectConfig(speed_fraction=0.5, dwell_s=0.2, discard_s=0.02, frame_timeout_s=0.5, settle_timeout_s=30.0,
                     min_frames=8)
R2_PARK = np.radians([90, 0, 0, 0, 0, 0])


def make_cell(scale: float = 30.0, seed: int = 1, mocap: SimMocapConfig | None = None):
    """(cell, R1 driver, mocap, truth, safety) with a planted-error truth and a 120 Hz mocap."""
    cell = load_cell()
    r1 = cell.robot("R1")
    truth = planted_truth(r1.model(), seed=seed)
    driver = SimRobotDriver("R1", r1.robot, truth, q0=np.radians([1, -50, -50, 1, 1, 1]), clock=SimClock(scale),
                            config=SimRobotConfig(settle_time_s=0.2))
    source = SimMocapSource({1: driver}, mocap or SimMocapConfig(rate_hz=120.0, seed=seed, buffer_frames=3600))
    return cell, driver, source, truth, CellSafety(cell)


def small_plan(q2_step_deg: float = 45.0, q3_step_deg: float = 30.0):
    return build_plan(plan_anchor_grid(q2_range_deg=(-55.0, 35.0), q2_step_deg=q2_step_deg,
                                       q3_step_deg=q3_step_deg))


if __name__ == "__main__":
    _, driver, source, _, safety = make_cell()
    with driver, source:
        run_session(sys.argv[1], driver, source, safety, body_id=1, plan=small_plan(20.0, 20.0),
                    others={"R2": R2_PARK}, config=FAST, resume=len(sys.argv) > 2, progress=False)
