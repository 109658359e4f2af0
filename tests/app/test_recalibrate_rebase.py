"""``recalibrate --rebase`` on the simulated cell: the candidate is the model in service with its frames refitted
on the new training poses; without a model in service it stops before any motion."""

from __future__ import annotations

import json
from pathlib import Path

from app.cli.commands import main
from calibration.models import load_model
from tests.conftest import SIM_FAST, assert_bad_input


def test_rebase_refits_the_frames_of_the_model_in_service(tmp_path, capsys):
    plan = tmp_path / "plan.json"
    assert main(["plan", "--robot", "R1", "--out", str(plan), "--q2-step", "35", "--q3-step", "30"]) == 0
    models = tmp_path / "models"
    args = ["recalibrate", "--robot", "R1", "--plan", str(plan), "--model-dir", str(models), "--validation", "6",
            "--validation-seed", "2", "--sim", *SIM_FAST, "--no-progress"]
    before = sorted(p.name for p in tmp_path.iterdir())
    assert_bad_input(capsys, args + ["--rebase"], "--rebase refits the frames of the model in service", "there is none")
    assert sorted(p.name for p in tmp_path.iterdir()) == before
    assert main(args + ["--method", "nls1"]) == 0
    capsys.readouterr()
    assert main(args + ["--rebase", "--json", str(tmp_path / "d.json")]) == 0
    out = capsys.readouterr().out
    assert "Rebased on" in out
    d = json.loads((tmp_path / "d.json").read_text())
    assert d["method"] == "nls1" and d["rebase"]["samples"] > 0
    # what the rebase minimises cannot rise (the sim's frames were already right, so the position mean alone is
    # a coin flip at the noise level: 0.14608 against 0.14606 mm in one run)
    assert d["rebase"]["objective_rms"]["after"] <= d["rebase"]["objective_rms"]["before"]
    assert d["rebase"]["position_mean_mm"]["after"] <= d["rebase"]["position_mean_mm"]["before"] * 1.05
    assert load_model(Path(d["current_path"] if d["replaced"] else d["rejected"])).kind == "rebased"
