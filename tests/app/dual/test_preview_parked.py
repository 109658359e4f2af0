"""A collection plan is previewed, and its safety checked there, with the other arm where ``cellcal plan`` checked it:
parked (:func:`app.collection.runtime.sim.park_q`, where the simulated and the fake controller's arms stand). The preview put
it at home (q = 0) instead, so a plan ``plan`` had certified "safe with the other arms parked" (the own-cell
tutorial's, 277 targets) was previewed as UNSAFE at target 98, R1's wrist 41 mm from R2's at home."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("meshcat")

from app.collection.runtime.sim import park_q  # noqa: E402
from app.collection.safety import CellSafety  # noqa: E402
from app.dual.preview.page import preview  # noqa: E402
from app.dual.preview.plan import read_preview_plan  # noqa: E402
from calibration.errors import ConfigError, UnsafeTarget  # noqa: E402
from cell_config.loader import load_cell  # noqa: E402


def _safe(safety: CellSafety, robot: str, q: np.ndarray, other: str, q_other: np.ndarray) -> bool:
    try:
        safety.check_plan(robot, q[None], {other: q_other}, park_q(robot))
    except (UnsafeTarget, ConfigError):
        return False
    return True


@pytest.mark.parametrize("robot, other", [("R1", "R2"), ("R2", "R1")])
def test_a_collection_plan_is_previewed_with_the_other_arm_parked(robot, other, tmp_path):
    """Targets drawn at random that are safe with the other arm parked and not with it at home: the preview draws
    the other arm parked and finds no defect (it found one per target)."""
    cell = load_cell()
    safety = CellSafety(cell)
    spec = cell.robot(robot).robot
    rng = np.random.default_rng(0)
    picked = []
    for q in rng.uniform(spec.lower_rad, spec.upper_rad, (3000, 6)):
        if _safe(safety, robot, q, other, park_q(other)) and not _safe(safety, robot, q, other, np.zeros(6)):
            picked.append(q)
            if len(picked) == 3:
                break
    assert picked, f"no {robot} pose near the other arm's home among 3000 random ones"
    for k, q in enumerate(picked):  # one plan per target: each is safe from the parking pose on its own
        plan = tmp_path / f"plan{k}.json"
        plan.write_text(json.dumps({"schema": "cellcal.plan/1", "kind": "collection", "targets": [
            {"robot": robot, "q_rad": q.tolist(), "cluster": 0, "kind": "anchor"}]}))
        drawn = read_preview_plan(plan)
        np.testing.assert_array_equal(drawn.q[other], park_q(other)[None])
        result = preview(cell, plan, html_out=tmp_path / f"preview{k}.html")
        assert result.defects == (), result.defects
