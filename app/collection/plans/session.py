"""A complete collection plan for one arm of the cell: anchor grid, CPA sweeps and validation poses.

The pieces come from :mod:`app.collection.plans.poses`; this module picks the cell-level choices: the paper's anchor
design (5 deg steps, 248 anchors) or a coarser grid, single-joint sweeps around a safe upright pose for
circular point analysis, and random validation poses drawn inside the region the anchors cover (so the
interpolating models are judged where they were fitted), each one checked against limits, the floor and
the other arms' parking poses. The whole plan is checked the same way before it is returned.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from app.collection.plans.collection import Plan
from app.collection.plans.poses import build_plan, paper_q3_bounds, plan_anchor_grid, plan_cpa_sweeps, plan_validation
from app.collection.safety import CellSafety
from calibration.errors import CellCalError, ConfigError

#: Sweep range [deg] of each joint for CPA, around the pose ``CPA_BASE_DEG``.
CPA_RANGES_DEG: tuple[tuple[float, float], ...] = ((-30, 30), (-30, 30), (-30, 30), (-45, 45), (-45, 45), (-45, 45))
CPA_BASE_DEG = (1.0, 0.0, 0.0, 1.0, 1.0, 1.0)
Q2_RANGE_DEG = (-55.0, 50.0)


@dataclass(frozen=True)
class PlanSpec:
    """What goes into a session plan.

    Attributes:
        q2_step_deg, q3_step_deg: anchor grid steps [deg] (5, 5 is the paper's 248-anchor design).
        cpa: add single-joint sweeps (needed by the ``cpa`` method).
        cpa_step_deg: sweep step [deg].
        n_validation: random validation poses (the test set); 0 for none.
        wrist_range_deg: validation q1, q4, q5, q6 are drawn in +- this [deg].
        seed: seed of the validation poses.
    """

    q2_step_deg: float = 5.0
    q3_step_deg: float = 5.0
    cpa: bool = True
    cpa_step_deg: float = 10.0
    n_validation: int = 50
    wrist_range_deg: float = 5.0
    seed: int = 0


def validation_plan(robot: str, safety: CellSafety, others: Mapping[str, np.ndarray], n: int, *, seed: int = 0,
                    wrist_range_deg: float = 5.0) -> Plan:
    """``n`` random validation poses inside the anchor region, each safe against ``others``.

    q2 lies in the grid's q2 range, q3 inside the q2-dependent band of the anchor design (3 deg inside its
    edges), q1 and the wrist joints within +- ``wrist_range_deg``.

    Raises:
        UnsafeTarget: no safe pose found for one of the draws.
    """
    w = math.radians(wrist_range_deg)
    lo_q3, hi_q3 = -70.0, 50.0
    lower = np.array([-w, math.radians(Q2_RANGE_DEG[0] + 3), math.radians(lo_q3), -w, -w, -w])
    upper = np.array([w, math.radians(Q2_RANGE_DEG[1] - 3), math.radians(hi_q3), w, w, w])
    lim_lo, lim_hi = safety.limits(robot)
    lower, upper = np.maximum(lower, lim_lo), np.minimum(upper, lim_hi)

    def accept(q: np.ndarray) -> bool:
        lo, hi = paper_q3_bounds(math.degrees(q[1]))
        if not lo + 3 <= math.degrees(q[2]) <= hi - 3:
            return False
        try:
            safety.check_configs(robot, q, others)
        except CellCalError:
            return False
        return True

    return build_plan(plan_validation(robot, lower, upper, n, seed=seed, margin_deg=0.0, accept=accept,
                                      max_tries=2000), kind="validation", n=n, seed=seed)


def session_plan(robot: str, safety: CellSafety, others: Mapping[str, np.ndarray], spec: PlanSpec = PlanSpec(),
                 q_start: np.ndarray | None = None, anchors: Plan | None = None) -> Plan:
    """Anchors (+1 deg perturbations), optional CPA sweeps, validation poses; checked safe as a whole.

    Args:
        robot: robot name in the cell.
        safety: the cell's safety checker.
        others: joint angles [rad] of the other arms during the session (their parking poses).
        spec: what to include.
        q_start: where the arm starts; the move from there to the first target is checked too.
        anchors: the anchor clusters to use instead of the grid of ``spec``'s steps (e.g. the optimal design of
            :mod:`app.collection.plans.design`); its params are kept in the plan's.

    Raises:
        ConfigError: bad steps.
        UnsafeTarget: a target or a path between targets is unsafe.
    """
    if spec.n_validation < 0:
        raise ConfigError("plan", "validation", f"expected a number >= 0 of validation poses, got {spec.n_validation}")
    if anchors is None:
        targets = plan_anchor_grid(robot, q2_range_deg=Q2_RANGE_DEG, q2_step_deg=spec.q2_step_deg,
                                   q3_step_deg=spec.q3_step_deg)
    else:
        targets = list(anchors.targets)
    n_anchors = len({t.cluster for t in targets})
    if spec.cpa:
        targets += plan_cpa_sweeps(robot, CPA_RANGES_DEG, step_deg=spec.cpa_step_deg, base_deg=CPA_BASE_DEG,
                                   first_cluster=n_anchors)
    if spec.n_validation:
        targets += list(validation_plan(robot, safety, others, spec.n_validation, seed=spec.seed,
                                        wrist_range_deg=spec.wrist_range_deg).targets)
    grid = {"q2_step_deg": spec.q2_step_deg, "q3_step_deg": spec.q3_step_deg} if anchors is None else anchors.params
    plan = build_plan(targets, **{**grid, "robot": robot, "anchors": n_anchors, "cpa": spec.cpa,
                                  "cpa_step_deg": spec.cpa_step_deg, "validation": spec.n_validation,
                                  "seed": spec.seed})
    safety.check_plan(robot, plan.q, others, q_start)
    return plan
