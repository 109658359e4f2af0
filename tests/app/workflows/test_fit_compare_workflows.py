"""fit and compare as workflows: plain inputs in, a result out, warnings through ``warn``, no argparse anywhere;
recalibrate's argument checks in its workflow (``checked_inputs``)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from app.collection.plans.collection import Plan
from app.workflows.compare import CompareInputs, compare
from app.workflows.fit import FitInputs, TrainingInputs, fit_model, trained_fitter
from app.workflows.recalibrate import checked_inputs
from calibration.errors import CellCalError, ConfigError, DataError
from calibration.models import load_model
from cell_config import load_cell
from tests.conftest import R1_TEST, R1_TRAIN, SHARED_DATA, needs_shared_data


def test_a_cpa_fit_without_sweeps_is_refused_when_its_inputs_are_built() -> None:
    with pytest.raises(CellCalError, match="--method cpa needs --cpa SWEEPS"):
        FitInputs(TrainingInputs("R1", ("never-read.csv",)), "cpa", "model.yaml")


@needs_shared_data()
def test_fit_model_writes_the_model_and_returns_what_the_command_prints(tmp_path: Path) -> None:
    lines: list[str] = []
    out = tmp_path / "nls1.yaml"
    result = fit_model(load_cell(), FitInputs(TrainingInputs("R1", (str(R1_TRAIN),)), "nls1", str(out)), lines.append)
    assert result.trained.frame_check is not None and result.trained.days is None
    assert load_model(out).n_parameters == result.model.n_parameters == result.to_json()["n_parameters"]
    assert result.to_json()["samples"] == len(result.trained.fitter.train)
    assert result.line().startswith(f"nls1: {result.model.n_parameters} parameters fitted on ")
    assert all(line.startswith("warning: ") for line in lines)
    json.dumps(result.to_json())  # the command writes it as it is


@needs_shared_data()
def test_several_training_recordings_give_the_days_told_first_through_warn() -> None:
    other = SHARED_DATA / "PH_grad_data" / "test0725_R1"
    if not other.exists():
        pytest.skip(f"{other} not found")
    lines: list[str] = []
    trained = trained_fitter(load_cell(), TrainingInputs("R1", (str(R1_TRAIN), str(other))), lines.append)
    assert trained.days is not None and trained.frame_check is None
    assert lines[0] == trained.days.summary()


@needs_shared_data()
def test_compare_refuses_an_unreadable_test_recording_before_any_fit(tmp_path: Path) -> None:
    bad = tmp_path / "test.csv"
    bad.write_text("not a recording\n")
    with pytest.raises(DataError, match=str(bad)):
        compare(load_cell(), CompareInputs(TrainingInputs("R1", (str(R1_TRAIN),)), str(bad), ("nls1",)),
                lambda line: None)


@needs_shared_data()
def test_compare_returns_the_comparison_with_its_frame_checks() -> None:
    result = compare(load_cell(), CompareInputs(TrainingInputs("R1", (str(R1_TRAIN),)), str(R1_TEST), ("nls1",)),
                     lambda line: None)
    frames = result.comparison.analysis["frames"]
    assert set(result.comparison.models) == {"nls1"} and frames["training"] is not None
    assert frames["test"]["model"] == "nls1" and len(result.test) > 0


def test_recalibrates_argument_checks_run_in_its_workflow(tmp_path: Path) -> None:
    robot = load_cell().robot("R1")
    settings = dict(validation_seed=None, rebase=False, add_weight=1, tolerance=None)
    (tmp_path / "file").write_text("")
    with pytest.raises(ConfigError, match="the model folder is a file"):
        checked_inputs(robot, tmp_path / "file", None, None, 4, "nls1", (), **settings)
    with pytest.raises(CellCalError, match="--validation must be at least 1, got 0"):
        checked_inputs(robot, tmp_path / "models", None, None, 0, "nls1", (), **settings)
    plan = tmp_path / "plan.json"
    Plan((), {}).save(plan)
    with pytest.raises(DataError, match="the plan moves nothing, expected R1 only"):
        checked_inputs(robot, tmp_path / "models", str(plan), None, 4, "nls1", (), **settings)
    inputs = checked_inputs(robot, tmp_path / "models", None, None, 4, "nls1", (), **settings)
    assert (inputs.robot, inputs.model_dir, inputs.plan, inputs.session, inputs.added) == (
        "R1", tmp_path / "models", None, None, ())
