"""summarize_plan: counts, visited ranges, the cubic-profile duration estimate and the full safety verdict."""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest
from sim_cell import R2_PARK, small_plan

from app.collection.dry_run import PlanSummary, summarize_plan
from app.collection.plans.collection import KINDS, Target
from app.collection.plans.poses import build_plan
from app.collection.safety import CellSafety
from calibration.errors import ConfigError, UnsafeTarget
from cell_config import load_cell

Q_START = np.radians([1, -50, -50, 1, 1, 1])
OTHERS = {"R2": R2_PARK}


@pytest.fixture(scope="module")
def cell():
    return load_cell()


def mixed_plan():
    plan = small_plan()
    extra = [Target("R1", np.radians([5, 10, -10, 0, 20, 0]), 99, "validation"),
             Target("R1", np.radians([-5, 0, 0, 30, 0, 0]), 100, "cpa")]
    return build_plan(list(plan.targets) + extra)


def test_counts_and_ranges_follow_the_plan(cell):
    plan = mixed_plan()
    s = summarize_plan(plan, CellSafety(cell), OTHERS, Q_START)
    assert isinstance(s, PlanSummary) and s.robot == "R1" and s.n_targets == len(plan)
    assert list(s.targets_per_kind) == [k for k in KINDS if k in s.targets_per_kind]
    assert s.targets_per_kind == {k: sum(t.kind == k for t in plan.targets) for k in KINDS
                                  if any(t.kind == k for t in plan.targets)}
    assert sum(s.targets_per_kind.values()) == len(plan)
    q = np.vstack([Q_START, plan.q])
    np.testing.assert_array_equal(s.q_min_rad, q.min(axis=0))
    np.testing.assert_array_equal(s.q_max_rad, q.max(axis=0))
    assert s.safe and s.safety_error is None
    assert "every target and path is safe" in "\n".join(s.lines()) and s.to_json()["targets"] == len(plan)


def test_duration_is_the_cubic_profile_of_the_slowest_joint(cell):
    safety = CellSafety(cell)
    v = cell.robot("R1").robot.max_speed_rad_s
    targets, q = [], Q_START.copy()
    for j, d_deg in enumerate([10, 20, 5, 40, 30, 60]):
        step = np.zeros(6)
        step[j] = np.radians(d_deg)
        q = q + step
        targets.append(Target("R1", q.copy(), j, "cpa"))
    plan = build_plan(targets)
    s = summarize_plan(plan, safety, OTHERS, Q_START, speed_fraction=0.25, per_target_s=2.0)
    expected = [1.5 * np.radians(d) / (0.25 * v[j]) for j, d in enumerate([10, 20, 5, 40, 30, 60])]
    assert s.motion_s == pytest.approx(sum(expected), rel=1e-12)
    assert s.longest_move_s == pytest.approx(max(expected), rel=1e-12)
    assert s.duration_s == pytest.approx(sum(expected) + 6 * 2.0, rel=1e-12)
    twice = summarize_plan(plan, safety, OTHERS, Q_START, speed_fraction=0.5)
    assert twice.motion_s == pytest.approx(s.motion_s / 2, rel=1e-12)
    both = build_plan([Target("R1", Q_START + np.radians([10, 0, 0, 40, 0, 0]), 0, "anchor")])
    slowest = max(np.radians(10) / v[0], np.radians(40) / v[3])  # joints move together: the slowest one counts
    assert summarize_plan(both, safety, OTHERS, Q_START, speed_fraction=1.0).motion_s == pytest.approx(1.5 * slowest)


def test_the_safety_verdict_is_the_full_check(cell):
    from app.collection.plan_safety import check_plan_safe

    safety = CellSafety(cell)
    plan = small_plan()
    colliding = build_plan(list(plan.targets[:3]) + [dataclasses.replace(plan.targets[0],
                                                                         q=np.radians([-10, 70, 60, 0, 0, 0]))])
    near = {"R2": np.radians([0, 40, 0, 0, 0, 0])}
    s = summarize_plan(colliding, safety, near, Q_START)
    with pytest.raises(UnsafeTarget):
        safety.check_plan("R1", colliding.q, near, Q_START)
    with pytest.raises(UnsafeTarget) as e:  # the one definition of a safe plan, which collect runs before motion
        check_plan_safe(cell, colliding, "p", safety=safety, others=near, q_start={"R1": Q_START})
    assert not s.safe and f"p: unsafe plan, {s.safety_error}; nothing written" == str(e.value)
    assert s.safety_error.startswith("target 3: ") and "too close to R2" in s.safety_error
    assert "REFUSED" in s.lines()[-1]
    assert summarize_plan(colliding, safety, OTHERS, Q_START).safe  # R2 turned away: the same plan is safe
    unknown = summarize_plan(plan, safety, {}, Q_START)
    assert not unknown.safe and "pose of R2 unknown" in unknown.safety_error
    out_of_limits = build_plan([dataclasses.replace(plan.targets[0], q=np.radians([1, 0, 170, 1, 1, 1]))])
    error = summarize_plan(out_of_limits, safety, OTHERS, Q_START).safety_error
    assert "target 170 deg is outside the limit 160 deg" in error


@pytest.mark.parametrize("kwargs, words", [({"speed_fraction": 0.0}, "(0, 1]"), ({"speed_fraction": 1.5}, "(0, 1]"),
                                           ({"per_target_s": -1.0}, ">= 0"),
                                           ({"q_start": np.full(6, np.nan)}, "6 finite joint angles")])
def test_bad_inputs_are_config_errors(cell, kwargs, words):
    args = {"q_start": Q_START, **kwargs}
    with pytest.raises(ConfigError, match=re.escape(words)):
        summarize_plan(small_plan(), CellSafety(cell), OTHERS, **args)


def test_a_plan_of_two_robots_is_refused(cell):
    two = build_plan([Target("R1", Q_START, 0, "anchor"), Target("R2", R2_PARK, 0, "anchor")])
    with pytest.raises(ConfigError, match="expected targets of one robot, got R1, R2"):
        summarize_plan(two, CellSafety(cell), OTHERS, Q_START)
