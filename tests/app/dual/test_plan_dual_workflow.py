"""The plan-dual workflow runs the plan safety check itself: a caller without the CLI cannot get an unchecked plan."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

import app.dual.plan_dual as workflow
from app.collection.plan_safety import UnsafePlan
from app.dual.plan_dual import PlanDualInputs, plan_dual
from cell_config import load_cell


def test_an_unsafe_solved_plan_is_refused_without_the_cli_and_nothing_is_written(tmp_path: Path) -> None:
    out = tmp_path / "plan.json"
    # two waypoints solve, but the move between them drifts the gun far off the workpiece's pose (plan_safety)
    with pytest.raises(UnsafePlan, match=r"^the solved plan: unsafe plan, waypoint 1: the move to it from waypoint 0 "
                                         r"takes the gun \d+ mm from its relative pose"):
        plan_dual(load_cell(), PlanDualInputs("sweep:2", compile="off", out=str(out)))
    assert not out.exists()


def test_the_check_sees_the_plan_and_models_before_the_file_is_written(tmp_path: Path,
                                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    out = tmp_path / "plan.json"
    seen: list[tuple[Any, ...]] = []

    def check(cell: Any, plan: Any, source: str, **kwargs: Any) -> None:
        seen.append((plan, source, kwargs, out.exists()))

    monkeypatch.setattr(workflow, "check_plan_safe", check)
    result = plan_dual(load_cell(), PlanDualInputs("sweep:5", compile="off", out=str(out)))
    assert seen == [(result.plan, "the solved plan", {"models": {}}, False)]
    assert out.exists() and result.to_json()["waypoints"] == 5 and result.to_json()["out"] == str(out)
