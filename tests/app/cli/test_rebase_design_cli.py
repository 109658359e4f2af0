"""``cellcal plan --design optimal --for rebase`` and ``cellcal rebase --offsets``: a 21-pose rebase design that
moves the wrist carries a model over a day whose joint zeros moved; the paper's still-wrist clusters cannot
(``scripts/benchmarks/bench_rebase_design.py``)."""

from __future__ import annotations

import json

import numpy as np

from app.cli.commands import main
from app.collection.plans.reader import read_plan
from calibration.data.recording import Recording, write_recording
from calibration.frames.rebase_design import REBASE_OFFSETS
from calibration.kinematics import so3
from calibration.kinematics.so3 import make_T
from calibration.models import ConstantModel, load_model, save_model
from calibration.models.rebased import RebasedModel
from cell_config import load_cell
from tests.conftest import assert_bad_input


def test_plan_for_rebase_moves_the_wrist_and_sees_every_rebase_direction(tmp_path):
    out, js = tmp_path / "plan.json", tmp_path / "plan_summary.json"
    assert main(["plan", "--robot", "R1", "--out", str(out), "--design", "optimal", "--budget", "21", "--for",
                 "rebase", "--json", str(js)]) == 0
    plan, figs = read_plan(out, "collection"), json.loads(js.read_text())["figures"]
    assert len(plan) == 21 and plan.params["for"] == "rebase"
    assert np.degrees(np.ptp(plan.q[:, 3:5], axis=0)).min() > 20.0  # joints 4 and 5 move widely
    n = 12 + len(REBASE_OFFSETS)
    assert figs["optimal"]["rank"] == figs["optimal"]["identifiable"] == n
    assert figs["paper_grid"]["rank"] < n  # the grid's still wrist cannot see the wrist offsets
    assert set(figs["optimal"]["sigma"]) >= {"joint 4 offset", "joint 5 offset", "base x shift"}


def test_for_rebase_needs_the_optimal_design(tmp_path, capsys):
    assert_bad_input(capsys, ["plan", "--design", "grid", "--robot", "R1", "--out", str(tmp_path / "p.json"),
                              "--for", "rebase"],
                     "--for applies to --design optimal only")
    assert not (tmp_path / "p.json").exists()


def test_rebase_offsets_recovers_a_moved_wrist_zero_on_the_rebase_design(tmp_path):
    nominal = load_cell().robot("R1").model()
    model = ConstantModel("R1", "nls1", nominal)
    save_model(model, tmp_path / "m.yaml")
    assert main(["plan", "--robot", "R1", "--out", str(tmp_path / "plan.json"), "--design", "optimal", "--budget",
                 "21", "--for", "rebase"]) == 0
    q = read_plan(tmp_path / "plan.json", "collection").q
    dq = np.radians([0.0, 0.0, 0.0, 0.05, -0.05, 0.0])
    truth = RebasedModel("R1", "nls1", model, make_T(so3.exp(np.radians([0.1, -0.05, 0.2])), np.array([2.0, -1, 0.5])),
                         make_T(so3.exp(np.radians([0.2, 0.1, -0.3])), np.array([0.5, 0.3, -0.8])),
                         joint_offsets=dq)
    R, p = truth.fk(q)
    write_recording(Recording(q, p, so3.R_to_quat(R)), tmp_path / "day.csv")
    for flag, name in (("--offsets", "o"), ("--all-directions", "f")):
        assert main(["rebase", "--robot", "R1", "--model", str(tmp_path / "m.yaml"), "--data",
                     str(tmp_path / "day.csv"), "--out", str(tmp_path / f"{name}.yaml"), "--json",
                     str(tmp_path / f"{name}.json"), flag]) == 0
    report = json.loads((tmp_path / "o.json").read_text())
    assert report["directions"] == "frames+offsets" and report["fitted_directions"] == 14
    np.testing.assert_allclose(np.radians(report["joint_offsets_deg"]), dq, atol=1e-7)
    q_val = np.random.default_rng(3).uniform(-1.0, 1.0, (50, 6))
    with_offsets = load_model(tmp_path / "o.yaml", "R1", nominal)
    frames_only = load_model(tmp_path / "f.yaml", "R1", nominal)
    np.testing.assert_allclose(with_offsets.fk(q_val)[1], truth.fk(q_val)[1], atol=1e-5)
    assert np.abs(frames_only.fk(q_val)[1] - truth.fk(q_val)[1]).max() > 0.1


def test_simulated_cross_day_rebase_design_meets_the_goal_and_the_grid_does_not():
    """Issue 10 in the simulated cell (seed 0 of ``scripts/benchmarks/bench_rebase_design.py``, 150 validation poses over the
    whole workspace, 3 noise draws of the 21 poses): the rebase design with the wrist offsets is within 1.25 x day
    B's own full calibration on every draw; 3 grid clusters are not on any, with or without the offsets, and
    neither are frames alone on the rebase design (the bench: 40 of 40 runs over 5 seeds x 8 draws, the grid 0)."""
    from scripts.benchmarks.bench_days import GOAL_RATIO
    from scripts.benchmarks.bench_rebase_design import run

    rows = run(0, True, lambda m: None, draws=3)["rows"]
    assert max(rows["(b) rebase design: frames + offsets 4, 5"]["ratios"]) <= GOAL_RATIO
    for k in ("(a) grid, 3 clusters: frames", "(a) grid, 3 clusters: frames + offsets 4, 5",
              "(b) rebase design: frames"):
        assert min(rows[k]["ratios"]) > GOAL_RATIO, k
