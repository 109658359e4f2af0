"""Plans (the paper's 248-anchor design, JSON round trip) and the safety checks."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from app.collection.plans.poses import (
    anchor_grid,
    build_plan,
    paper_q3_bounds,
    plan_anchor_grid,
    plan_cpa_sweeps,
    plan_validation,
)
from app.collection.plans.reader import read_plan
from app.collection.safety import CellSafety, SafetyConfig
from calibration.errors import ConfigError, DataError, UnsafeTarget
from cell_config import load_cell
from cell_config.capsules import segment_distance

TRAIN_Q = Path(__file__).resolve().parents[4] / "shared/data/welding_motoman/PH_grad_data/test0801_R1/train_data_robot_q_align.csv"


@pytest.fixture(scope="module")
def cell():
    return load_cell()


def test_paper_grid_has_248_anchors_and_1736_targets():
    assert len(anchor_grid()) == 248
    targets = plan_anchor_grid()
    assert len(targets) == 1736
    first = targets[:7]
    np.testing.assert_allclose(np.degrees(first[0].q), [1, -55, -70, 1, 1, 1])
    for j in range(6):
        np.testing.assert_allclose(np.degrees(first[j + 1].q - first[0].q), np.eye(6)[j], atol=1e-12)
    assert [t.kind for t in first] == ["anchor"] + ["perturb"] * 6
    assert {t.cluster for t in first} == {0}
    assert paper_q3_bounds(-10) == (-53.0, 0.0)


@pytest.mark.skipif(not TRAIN_Q.exists(), reason="../shared/data is absent")
def test_paper_grid_matches_the_recorded_design():
    recorded = np.loadtxt(TRAIN_Q, delimiter=",")
    planned = build_plan(plan_anchor_grid()).q
    diff = np.degrees(np.abs(planned - recorded)).max(axis=1)
    # the recorded design has one anchor at (q2, q3) = (-5, 3) deg where the rule gives (-5, 4) deg
    assert np.sum(diff > 0.05) == 7
    assert np.all(diff < 1.05)


def test_reduced_grid_cpa_and_validation(cell):
    assert len(anchor_grid(q2_step_deg=10, q3_step_deg=10)) < 100
    cpa = plan_cpa_sweeps("R1", [(-30, 30), None, None, None, None, (-90, 90)], step_deg=10, first_cluster=248)
    assert len(cpa) == 7 + 19 and {t.cluster for t in cpa} == {248, 249}
    spec = cell.robot("R1").robot
    safety = CellSafety(cell)
    val = plan_validation("R1", spec.lower_rad, spec.upper_rad, 20, seed=4,
                          accept=lambda q: _safe(safety, q))
    again = plan_validation("R1", spec.lower_rad, spec.upper_rad, 20, seed=4, accept=lambda q: _safe(safety, q))
    np.testing.assert_array_equal([t.q for t in val], [t.q for t in again])
    assert {t.kind for t in val} == {"validation"}


def _safe(safety, q):
    try:
        safety.check_configs("R1", q, {"R2": np.zeros(6)})
    except UnsafeTarget:
        return False
    return True


def test_plan_json_round_trip_and_bad_files(tmp_path):
    plan = build_plan(plan_anchor_grid(q2_step_deg=20) + plan_cpa_sweeps("R1", [(0, 10)] + [None] * 5), step=20)
    path = tmp_path / "plan.json"
    plan.save(path)
    assert json.loads(path.read_text())["schema"] == "cellcal.plan/1"
    back = read_plan(path)
    np.testing.assert_array_equal(back.q, plan.q)
    assert back.targets[5].kind == plan.targets[5].kind and back.params == {"step": 20}
    d = plan.to_dict()
    d["targets"][3]["q_rad"][2] = float("nan")
    path.write_text(json.dumps(d))
    with pytest.raises(DataError, match=r"targets\[3\].q_rad"):
        read_plan(path)
    d["targets"][3]["q_rad"] = [0] * 6
    d["targets"][3]["kind"] = "warmup"
    path.write_text(json.dumps(d))
    with pytest.raises(DataError, match="expected one of anchor"):
        read_plan(path)
    path.write_text("{")
    with pytest.raises(DataError, match="not valid JSON"):
        read_plan(path)


def test_segment_distance():
    a0, a1 = np.array([0.0, 0, 0]), np.array([10.0, 0, 0])
    assert segment_distance(a0, a1, np.array([5.0, 3, -1]), np.array([5.0, 3, 1])) == pytest.approx(3.0)
    assert segment_distance(a0, a1, np.array([12.0, 0, 4]), np.array([20.0, 0, 4])) == pytest.approx(math.hypot(2, 4))
    assert segment_distance(a0, a1, np.array([0.0, 2, 0]), np.array([10.0, 2, 0])) == pytest.approx(2.0)
    assert segment_distance(a0, a0, np.array([0.0, 2, 0]), np.array([0.0, 2, 0])) == pytest.approx(2.0)


def test_paper_plan_is_safe_up_front(cell):
    CellSafety(cell).check_plan("R1", build_plan(plan_anchor_grid()).q, {"R2": np.zeros(6)})


def test_out_of_limit_target_names_joint_value_and_limit(cell):
    safety = CellSafety(cell)
    q = np.radians([1, 170, 0, 1, 1, 1])
    with pytest.raises(UnsafeTarget, match=r"R1 joint 2: target 170 deg is outside the limit 155 deg") as e:
        safety.check_plan("R1", np.stack([np.zeros(6), q]), {"R2": np.zeros(6)})
    assert e.value.joint == 2 and "target 1" in str(e.value)
    margin = CellSafety(cell, SafetyConfig(joint_margin_deg=5))
    with pytest.raises(UnsafeTarget, match=r"limit 150 deg \(margin 5 deg\)"):
        margin.check_limits("R1", np.radians([0, 152, 0, 0, 0, 0]))


def test_collisions_with_the_other_arm_and_the_floor(cell):
    safety = CellSafety(cell)
    with pytest.raises(UnsafeTarget, match=r"^R1: \w+ too close to R2 \w+ \(clearance") as e:
        safety.check_configs("R1", np.radians([-10, 70, 60, 0, 0, 0]), {"R2": np.radians([0, 40, 0, 0, 0, 0])})
    assert e.value.joint is None and e.value.value < 50
    with pytest.raises(UnsafeTarget, match=r"^R1: \w+ too close to the floor \(clearance"):  # read 'R1: R1 tool'
        safety.check_configs("R1", np.radians([0, 90, 0, 0, 0, 0]), {"R2": np.zeros(6)})
    with pytest.raises(ConfigError, match="pose of R2 unknown"):
        safety.check_configs("R1", np.zeros(6), None)
    relaxed = CellSafety(cell, SafetyConfig(check_collisions=False, check_floor=False))
    relaxed.check_configs("R1", np.radians([0, 90, 0, 0, 0, 0]), None)


def test_the_path_is_checked_not_only_the_target(cell):
    safety = CellSafety(cell)
    start, end = np.radians([-10, 70, 60, 0, 0, 0]), np.radians([-10, 70, 60, 0, 0, 0])
    start[0], end[0] = math.radians(-60), math.radians(40)  # sweeping q1 passes through the collision
    others = {"R2": np.radians([0, 40, 0, 0, 0, 0])}
    safety.check_configs("R1", np.stack([start, end]), others)
    with pytest.raises(UnsafeTarget, match="too close to R2"):
        safety.check_motion("R1", start, end, others, index=0)


def _loop_outcome(safety, q):
    """What the move-by-move check says of a dual plan: None, or the UnsafeTarget's message."""
    try:
        for i in range(len(q)):
            safety.check_dual_motion(q[max(i - 1, 0)], q[i], i)
    except UnsafeTarget as e:
        return str(e)
    return None


def test_the_batched_dual_path_check_refuses_exactly_what_the_move_by_move_check_refuses(cell, monkeypatch):
    from cell_config.capsules import PROCESS_ZONE

    safety = CellSafety(cell, SafetyConfig(process_zone=PROCESS_ZONE))
    rng = np.random.default_rng(3)
    centre = np.concatenate([np.radians([0, 10, -10, 0, -30, 0]), np.radians([0, 10, -10, 0, -30, 0])])
    reaching = np.concatenate([np.radians([-10, 70, 60, 0, 0, 0]), np.radians([0, 40, 0, 0, 0, 0])])  # arms close
    outcomes = []
    for middle, spread_deg in [(centre, s) for s in (2, 10, 25, 45, 70)] + [(reaching, s) for s in (3, 8, 15)]:
        for _ in range(8):  # from mostly safe plans to mostly unsafe ones
            q = middle + np.radians(rng.normal(0, spread_deg, (6, 12)))
            expected = _loop_outcome(safety, q)
            try:
                safety.check_dual_path(q)
                got = None
            except UnsafeTarget as e:
                got = str(e)
            assert got == expected, (spread_deg, got, expected)
            outcomes.append(expected)
    assert outcomes.count(None) >= 5 and len(outcomes) - outcomes.count(None) >= 5  # both kinds were tried
    for kind in ("too close to R", "too close to the floor", "joint"):  # every check was reached
        assert any(m and kind in m for m in outcomes), kind
    # non-finite and out-of-limit waypoints too
    for bad in (np.nan, np.inf, math.radians(400)):
        q = np.stack([centre, centre.copy()])
        q[1, 8] = bad
        with pytest.raises(UnsafeTarget) as e:
            safety.check_dual_path(q)
        assert str(e.value) == _loop_outcome(safety, q)
    # a safe plan is settled by the batched screen alone: not one move-by-move check
    safe = next(centre + np.radians(rng.normal(0, 2, (6, 12))) for _ in iter(int, 1))
    assert _loop_outcome(safety, safe) is None
    monkeypatch.setattr(CellSafety, "check_dual_motion", lambda *a, **k: pytest.fail("screen not used"))
    safety.check_dual_path(safe)


def test_dual_motion_checks_both_arms_together_and_leaves_only_the_process_zone(cell):
    from app.collection.plan_safety import UnsafePlan, check_plan_safe
    from app.collection.plans.dual import PlanResult, WaypointResult
    from cell_config.capsules import PROCESS_ZONE, SEGMENTS

    safety = CellSafety(cell, SafetyConfig(process_zone=PROCESS_ZONE))
    r2 = np.radians([0, 40, 0, 0, 0, 0])
    start = np.concatenate([np.radians([-60, 70, 60, 0, 0, 0]), r2])
    end = np.concatenate([np.radians([40, 70, 60, 0, 0, 0]), r2])
    safety.check_configs("R1", np.stack([start[:6], end[:6]]), {"R2": r2})  # both ends are clear ...
    with pytest.raises(UnsafeTarget, match="too close to R2") as e:  # ... the joint move between them is not
        safety.check_dual_motion(start, end, index=7)
    assert "target 7" in str(e.value)
    nan = float("nan")
    low = WaypointResult(np.radians([0, 90, 0, 0, 0, 0]), r2, nan, nan, nan, nan, nan, nan, nan, 0, True)
    with pytest.raises(UnsafePlan, match="waypoint 0: R1: .*too close to the floor"):
        check_plan_safe(cell, PlanResult((low,), None, {"R1": "constant", "R2": "constant"}))
    with pytest.raises(ConfigError, match="unknown capsules"):
        CellSafety(cell, SafetyConfig(process_zone=("gun",)))
    # the process zone leaves exactly the pairs with both capsules in it unchecked
    zone = CellSafety(cell, SafetyConfig(process_zone=PROCESS_ZONE))._zone_pairs
    assert zone.sum() == len(PROCESS_ZONE) ** 2 and all(zone[SEGMENTS.index(a), SEGMENTS.index(b)]
                                                          for a in PROCESS_ZONE for b in PROCESS_ZONE)
