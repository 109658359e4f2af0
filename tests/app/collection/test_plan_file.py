"""The one plan-file reader: a collection or a dual plan by the file's kind."""

from __future__ import annotations

import json

import numpy as np
import pytest

from app.collection.plans.collection import Plan, Target
from app.collection.plans.dual import PlanResult, WaypointResult
from app.collection.plans.reader import read_plan
from calibration.errors import DataError


def _dual() -> PlanResult:
    w = WaypointResult(np.zeros(6), np.full(6, 0.1), 0.0, 0.0, 0.0, 0.0, 50.0, 1.0, 1.0, 3, True)
    return PlanResult((w, w), np.eye(4), {"R1": "constant", "R2": "constant"})


def _collection() -> Plan:
    return Plan((Target("R1", np.full(6, 0.2), 0, "anchor"),), {"step": 5})


def test_each_kind_reads_back_as_its_own_type(tmp_path):
    (tmp_path / "d.json").write_text(json.dumps(_dual().to_dict()))
    _collection().save(tmp_path / "c.json")
    dual, coll = read_plan(tmp_path / "d.json"), read_plan(tmp_path / "c.json")
    assert isinstance(dual, PlanResult) and dual.converged and dual.q().shape == (2, 12)
    assert isinstance(coll, Plan) and coll.params == {"step": 5}
    assert json.loads((tmp_path / "c.json").read_text())["kind"] == "collection"


def test_a_file_without_kind_is_told_by_its_layout():
    d = _collection().to_dict()
    d.pop("kind")
    assert isinstance(read_plan(d), Plan)
    d = _dual().to_dict()
    d.pop("kind")
    assert isinstance(read_plan(d), PlanResult)


@pytest.mark.parametrize("plan, kind, message", [
    (_collection().to_dict(), "dual", "this is a collection plan; expected a dual plan"),
    (_dual().to_dict(), "collection", "this is a dual plan; expected a collection plan"),
    (_dual(), "collection", "this is a dual plan; expected a collection plan"),
    ({"schema": "cellcal.plan/1"}, None, "expected a plan with 'waypoints'"),
])
def test_the_wrong_kind_is_refused(plan, kind, message):
    with pytest.raises(DataError, match=message):
        read_plan(plan, kind)


@pytest.mark.parametrize("value, message", [
    ([[1, 0, 0], [0, 1, 0], [0, 0, 1]], "T_wp_gun.*4x4"),
    (np.where(np.eye(4) == 1, np.nan, 0).tolist(), "T_wp_gun.*finite"),
    ([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]], "T_wp_gun.*homogeneous"),
])
def test_a_dual_plan_with_a_malformed_relative_pose_is_refused(value, message):
    d = _dual().to_dict()
    d["T_wp_gun"] = value
    with pytest.raises(DataError, match=message):
        read_plan(d)


def test_a_hand_written_plan_without_a_relative_pose_has_none_not_the_identity():
    """The held pose is what the preview draws as the target: it is never guessed."""
    d = _dual().to_dict()
    d.pop("T_wp_gun")
    plan = read_plan(d)
    assert plan.T_wp_gun is None and plan.to_dict()["T_wp_gun"] is None


@pytest.mark.parametrize("bad", [True, "0.1", None])
def test_an_angle_that_is_not_a_json_number_is_refused_in_either_kind(bad):
    """A collection plan took "0.1" as 0.1 rad and true as 1 rad (new-user run): a plan file's angle is a number."""
    d = _collection().to_dict()
    d["targets"][0]["q_rad"][2] = bad
    with pytest.raises(DataError, match=r"targets\[0\]\.q_rad.*expected 6 finite numbers"):
        read_plan(d)
    d = _dual().to_dict()
    d["waypoints"][1]["R2"][0] = bad
    with pytest.raises(DataError, match="waypoint 1: expected R1 and R2 with 6 finite numbers"):
        read_plan(d)
    d = _dual().to_dict()
    d["T_wp_gun"][0][0] = bad
    with pytest.raises(DataError, match="T_wp_gun"):
        read_plan(d)
    d = _collection().to_dict()
    d["targets"][0]["cluster"] = True
    with pytest.raises(DataError, match="expected an integer cluster"):
        read_plan(d)
