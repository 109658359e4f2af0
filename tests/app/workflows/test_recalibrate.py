"""Recalibration decisions, and the bad-input paths of plan/collect/export/recalibrate/demo."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from app.cli.commands import main
from app.workflows.recalibrate import decide_and_install
from calibration.errors import DataError
from calibration.kinematics.parameterisation import MinimalParameterisation
from calibration.models import ConstantModel, load_model, save_model
from tests.conftest import SIM_FAST, assert_bad_input, measure, planted_parameters


@pytest.fixture(scope="module")
def arm(r1_nominal):
    """(truth model, validation recording, a good and a poor model of it)."""
    par = MinimalParameterisation(r1_nominal, fit_tool=True)
    x = planted_parameters(par)
    truth = par.model(x)
    q = np.random.default_rng(4).uniform(-0.6, 0.6, (40, 6))
    validation = measure(truth.fk, q, 0.01, 0.001, 5)
    good = ConstantModel("R1", "nls1", par.model(0.98 * x), 27, {})
    poor = ConstantModel("R1", "nominal", r1_nominal, 0, {})
    return truth, validation, good, poor


def test_first_model_is_installed(tmp_path, arm):
    _, validation, good, _ = arm
    d = decide_and_install(tmp_path, good, validation)
    assert d.replaced and d.current is None and d.archived is None
    assert load_model(tmp_path / "current.yaml").method == "nls1"
    assert d.to_json()["decision"] == "installed"


def test_better_model_replaces_and_the_old_one_is_archived(tmp_path, arm):
    _, validation, good, poor = arm
    save_model(poor, tmp_path / "current.yaml")
    d = decide_and_install(tmp_path, good, validation)
    assert d.replaced and d.candidate_rms_mm < d.current_rms_mm
    assert load_model(tmp_path / "current.yaml").method == "nls1"
    archived = list((tmp_path / "previous").iterdir())
    assert archived == [d.archived] and load_model(archived[0]).method == "nominal"
    j = d.to_json()
    assert j["decision"] == "replaced" and j["current"]["position_rms_mm"] > j["candidate"]["position_rms_mm"]
    assert f"(lower by {d.current_rms_mm - d.candidate_rms_mm:.2g} mm)" in d.summary()


def test_a_decision_by_less_than_its_rounding_says_by_how_much(tmp_path, arm):
    """Both figures printed to 0.1 um read 'replaced: candidate ... 0.1812 < model in service 0.1812' (new-user run)."""
    from dataclasses import replace

    _, validation, good, _ = arm
    d = decide_and_install(tmp_path, good, validation)
    same = replace(d, current={"position_mm": {"rms": d.candidate_rms_mm + 3e-6}})
    assert "< model in service" in same.summary() and "(lower by 3e-06 mm)" in same.summary()


def test_worse_model_is_kept_out(tmp_path, arm):
    _, validation, good, poor = arm
    save_model(good, tmp_path / "current.yaml")
    before = (tmp_path / "current.yaml").read_bytes()
    d = decide_and_install(tmp_path, poor, validation)
    assert not d.replaced and d.candidate_rms_mm > d.current_rms_mm
    assert (tmp_path / "current.yaml").read_bytes() == before
    assert not (tmp_path / "previous").exists()
    assert d.rejected is not None and load_model(d.rejected).method == "nominal"
    assert d.to_json()["decision"] == "kept"


def test_model_in_service_for_another_robot_is_refused(tmp_path, arm):
    _, validation, good, _ = arm
    _, _, _, poor = arm
    save_model(ConstantModel("R2", "nominal", poor.model, 0, {}), tmp_path / "current.yaml")
    with pytest.raises(DataError, match="for R2, not R1"):
        decide_and_install(tmp_path, good, validation)


def _sim_recalibrate(tmp_path, method: str, validation: int) -> tuple[list[str], Path]:
    """``recalibrate`` arguments on the simulated cell with a small grid plan, and its model folder."""
    plan = tmp_path / "plan.json"
    assert main(["plan", "--robot", "R1", "--out", str(plan), "--design", "grid", "--q2-step", "35", "--q3-step", "30"]) == 0
    models = tmp_path / "models"
    return ["recalibrate", "--robot", "R1", "--plan", str(plan), "--model-dir", str(models), "--method", method,
            "--validation", str(validation), "--validation-seed", "2", "--sim", *SIM_FAST, "--no-progress"], models


def test_recalibrate_cli_on_the_simulated_cell(tmp_path, capsys):
    args, models = _sim_recalibrate(tmp_path, "nls1", 6)
    assert main(args + ["--json", str(tmp_path / "d1.json")]) == 0
    d1 = json.loads((tmp_path / "d1.json").read_text())
    assert d1["decision"] == "installed" and d1["validation_samples"] == 6
    assert "installed candidate nls1" in capsys.readouterr().out
    assert load_model(models / "current.yaml").method == "nls1"


@pytest.mark.parametrize("stopped_in", ["training", "validation"])
def test_ctrl_c_during_recalibrate_names_the_training_session_not_a_resume_it_lacks(tmp_path, capsys, monkeypatch,
                                                                                     stopped_in):
    # it said "stopped (continue with --resume)" (recalibrate has no --resume), or after --plan only "stopped"
    import app.collection.collect

    calls = []
    collect = app.collection.collect.collect_arm

    def interrupted(*args, **kwargs):
        calls.append(1)
        if len(calls) == (1 if stopped_in == "training" else 2):
            raise KeyboardInterrupt
        return collect(*args, **kwargs)

    monkeypatch.setattr(app.collection.collect, "collect_arm", interrupted)
    args, models = _sim_recalibrate(tmp_path, "nls1", 3)
    capsys.readouterr()
    assert main(args) == 130
    err = capsys.readouterr().err.strip().splitlines()
    session = re.escape(str(models / "sessions")) + r"/\d{8}T\d{6}/train"
    expected = (rf"the training session so far is ({session}): finish it with cellcal collect --robot R1 --session "
                r"\1 --resume, then recalibrate --session \1\)" if stopped_in == "training" else
                rf"recalibrate --session {session} reuses the training session\)")
    assert len(err) == 1 and re.fullmatch(r"cellcal recalibrate: stopped \(nothing installed; " + expected, err[0]), err
    assert not (models / "current.yaml").exists()


def test_first_candidate_outside_the_tolerance_is_refused_not_installed(tmp_path, arm):
    from calibration.evaluation.metrics import error_stats, errors

    _, validation, good, poor = arm
    rms = {m.method: error_stats(errors(m, validation))["position_mm"]["rms"] for m in (good, poor)}
    tolerance = float(np.sqrt(rms["nls1"] * rms["nominal"]))  # between the two
    assert rms["nls1"] < tolerance < rms["nominal"]
    d = decide_and_install(tmp_path, poor, validation, tolerance_mm=tolerance)
    assert d.refused and not d.replaced and not (tmp_path / "current.yaml").exists()
    assert d.rejected is not None and load_model(d.rejected).method == "nominal"
    assert d.to_json()["decision"] == "refused" and "refused candidate nominal" in d.summary()
    assert decide_and_install(tmp_path, good, validation, tolerance_mm=tolerance).replaced  # within it: installed
    save_model(poor, tmp_path / "current.yaml")  # a usable model in service: a better candidate above it replaces it
    assert decide_and_install(tmp_path, good, validation, tolerance_mm=1e-6).replaced


def _session_of(folder, robot: str) -> None:
    """A created (empty) session of ``robot``: what collect leaves before its first sample."""
    from app.collection.plans.collection import Plan, Target
    from app.collection.session_store import SessionStore

    plan = Plan((Target(robot, np.zeros(6), 0, "anchor"),), {})
    with SessionStore(folder, create=True) as store:
        store.init(plan, {"robot": robot, "body_id": 1})


def test_a_session_of_the_other_arm_is_refused_before_any_motion(tmp_path, capsys):
    session, models, out = tmp_path / "s_r1", tmp_path / "models_r2", tmp_path / "r1.csv"
    _session_of(session, "R1")
    before = sorted(str(p) for p in tmp_path.rglob("*"))
    for argv in (["recalibrate", "--robot", "R2", "--session", str(session), "--model-dir", str(models),
                  "--method", "nls1", "--sim"],
                 ["collect", "--robot", "R2", "--session", str(session), "--resume", "--sim"],
                 ["export", "--robot", "R2", "--session", str(session), "--out", str(out)]):
        assert_bad_input(capsys, argv, str(session), "collected on R1, not R2")
    assert sorted(str(p) for p in tmp_path.rglob("*")) == before


def test_a_session_stopped_half_way_is_refused_before_any_motion(tmp_path, capsys):
    # a collection stopped by Ctrl-C after 53 of 1736 training targets: recalibrate --session fitted and installed
    # a model on those 53 without a word
    from app.collection.plans.collection import Plan, Target
    from app.collection.session_store import Sample, SessionStore

    session, models = tmp_path / "s_r1", tmp_path / "models_r1"
    targets = tuple(Target("R1", np.full(6, 0.01 * i), i // 7, "anchor" if i % 7 == 0 else "perturb")
                    for i in range(14)) + (Target("R1", np.zeros(6), -1, "validation"),)
    with SessionStore(session, create=True) as store:
        store.init(Plan(targets, {}), {"robot": "R1", "body_id": 1})
        for i in range(9):  # the first cluster and 2 poses of the second; 5 training targets and the validation left
            store.add_sample(Sample(i, targets[i].q, np.array([1000.0, 0, 500]), np.array([1.0, 0, 0, 0]), 0.01,
                                    0.001, 0.05, 30, float(i), np.ones(6)), "R1", targets[i].kind, targets[i].cluster)
    before = sorted(str(p) for p in tmp_path.rglob("*"))
    assert_bad_input(capsys, ["recalibrate", "--robot", "R1", "--session", str(session), "--model-dir", str(models),
                              "--method", "nls1", "--sim", "--yes", "--json", str(tmp_path / "d.json")],
                     str(session), "the session is incomplete: 5 of its 14 anchor/perturb targets not yet measured",
                     f"cellcal collect --robot R1 --session {session} --resume")
    assert sorted(str(p) for p in tmp_path.rglob("*")) == before


def test_a_folder_without_a_session_says_there_is_nothing_to_recalibrate_from(tmp_path, capsys):
    # it said "nothing to resume; start a new collect with a plan", worded for collect --resume
    session, models = tmp_path / "nosuch", tmp_path / "models_r1"
    argv = ["recalibrate", "--robot", "R1", "--session", str(session), "--model-dir", str(models), "--method", "nls1",
            "--sim", "--yes"]
    assert_bad_input(capsys, argv, str(session), "no session here (session.sqlite not found): nothing to recalibrate "
                     "from", "cellcal collect --robot R --plan PLAN --session DIR", "recalibrate --plan PLAN")
    assert main(argv) == 2
    assert "resume" not in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_recalibrate_cli_refuses_a_first_model_outside_the_tolerance(tmp_path, capsys):
    args, models = _sim_recalibrate(tmp_path, "nominal", 4)
    capsys.readouterr()
    assert main(args + ["--tolerance-mm", "0.01", "--json", str(tmp_path / "d.json")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "refused candidate nominal" in err[0] and "--tolerance-mm 0.01" in err[0], err
    assert not (models / "current.yaml").exists() and len(list((models / "rejected").iterdir())) == 1
    assert json.loads((tmp_path / "d.json").read_text())["decision"] == "refused"


def test_bad_inputs_exit_2_and_write_nothing(tmp_path, capsys):
    bad_plan = tmp_path / "bad_plan.json"
    bad_plan.write_text('{"schema": "cellcal.plan/1", "targets": [{"robot": "R1", "q_rad": [0, 0], '
                        '"cluster": 0, "kind": "anchor"}]}')
    not_json = tmp_path / "not_json.json"
    not_json.write_text("{nope")
    r2_plan = tmp_path / "r2.json"
    assert main(["plan", "--robot", "R2", "--out", str(r2_plan), "--design", "grid", "--q2-step", "50", "--q3-step", "50"]) == 0
    capsys.readouterr()
    before = sorted(p.name for p in tmp_path.iterdir())
    session, out, models = tmp_path / "s", tmp_path / "rec.csv", tmp_path / "models"

    assert_bad_input(capsys, ["collect", "--robot", "R1", "--plan", str(bad_plan), "--session", str(session)],
         "no controller block", "--sim")
    assert_bad_input(capsys, ["collect", "--robot", "R1", "--plan", str(bad_plan), "--session", str(session), "--sim"],
         "targets[0].q_rad", "expected 6 finite numbers")
    assert_bad_input(capsys, ["collect", "--robot", "R1", "--plan", str(not_json), "--session", str(session), "--sim"],
         "not valid JSON")
    assert_bad_input(capsys, ["collect", "--robot", "R1", "--plan", str(r2_plan), "--session", str(session), "--sim"],
         "the plan moves R2, expected R1 only")
    assert_bad_input(capsys, ["collect", "--robot", "R1", "--plan", str(tmp_path / "missing.json"), "--session", str(session),
                  "--sim"], "file not found")
    assert_bad_input(capsys, ["collect", "--robot", "R1", "--session", str(session), "--resume", "--sim"], "no session here")
    assert_bad_input(capsys, ["collect", "--robot", "R1", "--session", str(session), "--sim"], "needs --plan")
    assert_bad_input(capsys, ["export", "--session", str(session), "--out", str(out)], "no session here")
    assert_bad_input(capsys, ["export", "--session", str(session), "--out", str(out), "--kinds", "anchor,bogus"],
         "unknown target kind 'bogus'")
    assert_bad_input(capsys, ["recalibrate", "--robot", "R1", "--session", str(session), "--model-dir", str(models), "--sim"],
         "no session here")
    assert_bad_input(capsys, ["recalibrate", "--robot", "R1", "--plan", str(bad_plan), "--model-dir", str(models), "--sim"],
         "expected 6 finite numbers")
    assert_bad_input(capsys, ["recalibrate", "--robot", "R1", "--plan", str(r2_plan), "--model-dir", str(models),
                              "--sim"], "the plan moves R2")
    assert_bad_input(capsys, ["recalibrate", "--robot", "R1", "--plan", str(r2_plan), "--model-dir", str(models)],
         "no controller block", "--sim")
    assert_bad_input(capsys, ["recalibrate", "--robot", "R9", "--plan", str(r2_plan), "--model-dir", str(models), "--sim"],
         "unknown robot 'R9'")
    assert_bad_input(capsys, ["recalibrate", "--robot", "R1", "--plan", str(bad_plan), "--model-dir", str(bad_plan), "--sim"],
         "model folder is a file")
    assert_bad_input(capsys, ["plan", "--robot", "R1", "--out", str(tmp_path / "p.json"), "--design", "grid", "--q2-step", "-5"],
                     "--q2-step must be in [0.5, 90] deg, got -5")
    assert_bad_input(capsys, ["demo", "--out", str(bad_plan)], "must be a folder")
    assert sorted(p.name for p in tmp_path.iterdir()) == before


@pytest.mark.parametrize("scale", ["inf", "0", "2000"])
def test_a_sim_time_scale_out_of_range_is_refused_before_anything_is_written(tmp_path, capsys, scale):
    """Every --sim command checks --time-scale as demo does: ``inf`` made the bridge's timeouts infinite (a hang)."""
    plan = tmp_path / "plan.json"
    assert main(["plan", "--robot", "R1", "--out", str(plan), "--design", "grid", "--q2-step", "50", "--q3-step", "50"]) == 0
    capsys.readouterr()
    before = sorted(p.name for p in tmp_path.iterdir())
    for argv in (["collect", "--robot", "R1", "--plan", str(plan), "--session", str(tmp_path / "s"), "--sim"],
                 ["recalibrate", "--robot", "R1", "--plan", str(plan), "--model-dir", str(tmp_path / "m"),
                  "--method", "nls1", "--sim"]):
        assert_bad_input(capsys, argv + ["--time-scale", scale, "--no-progress"], "--time-scale must be in (0, 1000]")
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_the_recalibrate_workflow_runs_without_the_cli_and_prints_nothing(tmp_path, capsys):
    # issue 32 point 7: the workflow lived in cmd_recalibrate, wrote its Ctrl-C hint onto argparse's args and
    # printed; now it takes plain inputs and hooks, and every line goes through the hooks
    from app.collection.collect import DEMO_COLLECT
    from app.collection.plans.reader import read_plan
    from app.collection.runtime.sim import SimCell, SimCellOptions
    from app.collection.safety import CellSafety
    from app.reports.acceptance import Tolerance
    from app.workflows.recalibrate import RecalibrationHooks, RecalibrationInputs, recalibrate
    from cell_config import load_cell

    args, models = _sim_recalibrate(tmp_path, "nls1", 4)
    capsys.readouterr()
    cell = load_cell()
    said: list[tuple[str, str]] = []
    hooks = RecalibrationHooks(say=lambda s: said.append(("say", s)), warn=lambda s: said.append(("warn", s)),
                               confirm=lambda s: said.append(("confirm", s)),
                               stop_hint=lambda s: said.append(("hint", s)),
                               dry_run=lambda *a: pytest.fail("not a dry run"),
                               motion=lambda: (DEMO_COLLECT, CellSafety(cell)))
    inputs = RecalibrationInputs("R1", models, read_plan(tmp_path / "plan.json", "collection"), None, 4, 2, "nls1",
                                 False, (), 1, Tolerance())
    result = recalibrate(cell, SimCell(cell, SimCellOptions(time_scale=200, deterministic=True)), inputs, hooks)
    assert capsys.readouterr().out == ""
    assert result.decision is not None and result.decision.replaced and result.rebased is None
    assert result.to_json() == result.decision.to_json() and result.decision.validation_samples == 4
    lines = [(kind, s) for kind, s in said if kind != "warn"]  # the small plan leaves directions unseen: a warning
    assert [kind for kind, _ in lines] == ["confirm", "hint", "hint", "hint"] and lines[-1] == ("hint", "")
    assert "R1 will visit" in lines[0][1] and "recalibrate --session" in lines[2][1]
    assert all(s.startswith("warning: ") for kind, s in said if kind == "warn")
    assert load_model(models / "current.yaml").method == "nls1"
