"""Model files on the command line: a NaN, a non-rotation or another robot's model is exit 2 and writes nothing."""

import json

import numpy as np
import pytest
import yaml

from app.cli.commands import main
from app.workflows.recalibrate import decide_and_install
from calibration.errors import ModelError, OutputError
from calibration.kinematics.parameterisation import MinimalParameterisation
from calibration.models import ConstantModel, load_model, save_model
from tests.conftest import SIM_FAST, assert_bad_input, cluster_design, measure, planted_parameters


@pytest.fixture(scope="module")
def files(tmp_path_factory, synthetic_arm):
    """A valid R1 model, a NaN one, one whose R_flange is not a rotation, joints and recordings."""
    par, x, truth = synthetic_arm
    root = tmp_path_factory.mktemp("models")
    from calibration.data.recording import write_recording

    q, cluster = cluster_design(step_deg=30.0)
    write_recording(measure(truth.fk, q, 0.02, 0.01, 1, cluster), root / "train.csv")
    q_test = np.random.default_rng(3).uniform(-0.8, 0.8, (40, 6))
    write_recording(measure(truth.fk, q_test, 0.02, 0.01, 2), root / "test.csv")
    np.savetxt(root / "q.csv", q_test[:5], delimiter=",")
    save_model(ConstantModel("R1", "nls1", truth, 27, {}), root / "r1.yaml")
    data = yaml.safe_load((root / "r1.yaml").read_text())
    data["geometry"]["P"][2][2] = float("nan")
    (root / "nan.yaml").write_text(yaml.safe_dump(data))
    data = yaml.safe_load((root / "r1.yaml").read_text())
    data["geometry"]["R_flange"] = [[1.0, 0.1, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    (root / "skew.yaml").write_text(yaml.safe_dump(data))
    return root


def test_predict_with_a_nan_model_exits_2_and_writes_nothing(files, tmp_path, capsys):
    out = tmp_path / "poses.csv"
    assert_bad_input(capsys, ["predict", "--model", str(files / "nan.yaml"), "--joints", str(files / "q.csv"),
                              "--out", str(out)], "nan.yaml: geometry.P[2][2]: expected a finite number, got nan")
    assert_bad_input(capsys, ["predict", "--model", str(files / "skew.yaml"), "--joints", str(files / "q.csv"),
                              "--out", str(out)], "skew.yaml: geometry.R_flange: not a rotation")
    assert not out.exists()
    assert_bad_input(capsys, ["predict", "--robot", "R2", "--model", str(files / "r1.yaml"), "--joints",
                              str(files / "q.csv"), "--out", str(out)], "r1.yaml: robot: the model is for R1, not R2")
    assert not out.exists()
    assert main(["predict", "--robot", "R1", "--model", str(files / "r1.yaml"), "--joints", str(files / "q.csv"),
                 "--out", str(out)]) == 0
    assert len(out.read_text().splitlines()) == 6


def test_evaluate_and_compare_refuse_a_nan_model_and_write_no_json(files, tmp_path, capsys):
    out = tmp_path / "e.json"
    assert_bad_input(capsys, ["evaluate", "--model", str(files / "nan.yaml"), "--test", str(files / "test.csv"),
                              "--json", str(out)], "nan.yaml", "expected a finite number")
    assert_bad_input(capsys, ["evaluate", "--robot", "R2", "--model", str(files / "r1.yaml"), "--test",
                              str(files / "test.csv"), "--json", str(out)], "the model is for R1, not R2")
    assert_bad_input(capsys, ["compare", "--robot", "R1", "--train", str(files / "train.csv"), "--test",
                              str(files / "test.csv"), "--methods", "nominal", "--model", str(files / "nan.yaml"),
                              "--json", str(out)], "nan.yaml", "expected a finite number")
    assert not out.exists()
    assert main(["evaluate", "--robot", "R1", "--model", str(files / "r1.yaml"), "--test", str(files / "test.csv"),
                 "--json", str(out)]) == 0
    assert "NaN" not in out.read_text() and json.loads(out.read_text())["robot"] == "R1"


def test_plan_dual_refuses_r1s_model_for_r2_and_writes_nothing(files, tmp_path, capsys):
    pytest.importorskip("casadi")
    out, summary = tmp_path / "plan.json", tmp_path / "s.json"
    r1 = files / "r1.yaml"
    assert_bad_input(capsys, ["plan-dual", "--models", f"R1={r1},R2={r1}", "--path", "sweep:3", "--out", str(out),
                              "--json", str(summary)], "r1.yaml: robot: the model is for R1, not R2")
    relabelled = tmp_path / "r2.yaml"  # R1's MA2010 geometry with its robot name edited to R2 (an MA1440)
    relabelled.write_text(r1.read_text().replace("robot: R1", "robot: R2"))
    assert_bad_input(capsys, ["plan-dual", "--models", f"R2={relabelled}", "--path", "sweep:3", "--out", str(out)],
                     "r2.yaml: geometry: not R2's geometry", "a model of another robot type?")
    assert_bad_input(capsys, ["plan-dual", "--models", f"R1={files / 'nan.yaml'}", "--path", "sweep:3", "--out",
                              str(out)], "nan.yaml", "expected a finite number")
    assert not out.exists() and not summary.exists()


@pytest.mark.parametrize("command", ["predict", "evaluate", "rebase", "export-urdf"])
def test_a_models_geometry_is_checked_against_the_robot_it_records_without_robot(files, tmp_path, capsys, command):
    """The model file knows its robot: without --robot its geometry is checked against that robot's YAML (predict
    and evaluate checked it only with --robot; rebase required --robot), and --robot disagreeing is refused."""
    relabelled = tmp_path / "r2.yaml"  # R1's MA2010 geometry with its robot name edited to R2 (an MA1440)
    relabelled.write_text((files / "r1.yaml").read_text().replace("robot: R1", "robot: R2"))
    out, js = tmp_path / "out.file", tmp_path / "out.json"
    rest = {"predict": ["--joints", str(files / "q.csv"), "--out", str(out)],
            "evaluate": ["--test", str(files / "test.csv")],
            "rebase": ["--data", str(files / "train.csv"), "--translation-only", "--out", str(out)],  # its own
            # training data hold no frame change, which the held-out check would refuse: the choice is given here
            "export-urdf": ["--out", str(out)]}[command] + ["--json", str(js)]
    assert_bad_input(capsys, [command, "--model", str(relabelled), *rest], "r2.yaml: geometry: not R2's geometry")
    assert_bad_input(capsys, [command, "--robot", "R1", "--model", str(relabelled), *rest],
                     "r2.yaml: robot: the model is for R2, not R1")
    assert not out.exists() and not js.exists()
    assert main([command, "--model", str(files / "r1.yaml"), *rest]) == 0  # the robot it records: R1
    assert json.loads(js.read_text())["robot"] == "R1"


def test_validate_dual_refuses_r1s_model_for_r2(files, tmp_path, capsys):
    pytest.importorskip("casadi")
    out = tmp_path / "v.json"
    r1 = files / "r1.yaml"
    assert_bad_input(capsys, ["validate-dual", "--sim", "--models", f"R1={r1},R2={r1}", "--json", str(out)],
                     "r1.yaml: robot: the model is for R1, not R2")
    assert not out.exists()


@pytest.fixture(scope="module")
def arm(r1_nominal):
    par = MinimalParameterisation(r1_nominal, fit_tool=True)
    x = planted_parameters(par)
    q = np.random.default_rng(4).uniform(-0.6, 0.6, (40, 6))
    validation = measure(par.model(x).fk, q, 0.01, 0.001, 5)
    return validation, ConstantModel("R1", "nls1", par.model(0.98 * x), 27, {}), ConstantModel(
        "R1", "nominal", r1_nominal, 0, {})


@pytest.mark.parametrize("corrupt", ["nan", "skew", "binary"])
def test_an_unusable_model_in_service_is_reported_and_a_valid_candidate_replaces_it(tmp_path, arm, corrupt):
    validation, good, poor = arm
    current = tmp_path / "current.yaml"
    save_model(poor, current)
    data = yaml.safe_load(current.read_text())
    if corrupt == "nan":
        data["geometry"]["P"][1][0] = float("nan")
    elif corrupt == "skew":
        data["geometry"]["R_flange_tool"] = [[2.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    current.write_bytes(b"\x00\xff\x89" if corrupt == "binary" else yaml.safe_dump(data).encode())
    before = current.read_bytes()
    d = decide_and_install(tmp_path, poor, validation)  # even the poorer candidate: the old one is unusable
    assert d.replaced and d.current is None and d.current_problem
    assert "unusable" in d.summary() and d.current_problem in d.summary()
    j = d.to_json()
    assert j["decision"] == "replaced" and j["current"] is None and j["current_problem"] == d.current_problem
    assert load_model(current).method == "nominal"
    assert d.archived is not None and d.archived.read_bytes() == before  # kept for the record


def test_a_model_in_service_whose_errors_are_not_finite_never_wins(tmp_path, arm, monkeypatch):
    validation, good, poor = arm
    save_model(good, tmp_path / "current.yaml")
    import app.workflows.recalibrate as recal

    real = recal._validation_stats

    def stats(model, rec):
        s = real(model, rec)
        if model.method == "nls1":
            s["position_mm"]["rms"] = float("nan")
        return s
    monkeypatch.setattr(recal, "_validation_stats", stats)
    d = decide_and_install(tmp_path, poor, validation)
    assert d.replaced and d.current_problem == "its errors on the validation poses are not finite"
    assert load_model(tmp_path / "current.yaml").method == "nominal"
    with pytest.raises(ModelError, match="non-finite errors on the validation poses; nothing installed"):
        decide_and_install(tmp_path, good, validation)  # now the nls1 candidate gives NaN: refused
    assert load_model(tmp_path / "current.yaml").method == "nominal"


def test_a_symlinked_model_in_service_is_refused_before_anything_moves(tmp_path, arm):
    validation, good, poor = arm
    save_model(poor, tmp_path / "real.yaml")
    (tmp_path / "current.yaml").symlink_to(tmp_path / "real.yaml")
    with pytest.raises(OutputError, match="current.yaml: is a symbolic link"):
        decide_and_install(tmp_path, good, validation)
    assert (tmp_path / "current.yaml").is_symlink() and not (tmp_path / "previous").exists()


def test_recalibrate_cli_replaces_a_nan_model_in_service(tmp_path, files, capsys, caplog):
    plan = tmp_path / "plan.json"
    assert main(["plan", "--robot", "R1", "--out", str(plan), "--design", "grid", "--q2-step", "35", "--q3-step", "30"]) == 0
    models = tmp_path / "models"
    models.mkdir()
    (models / "current.yaml").write_bytes((files / "nan.yaml").read_bytes())
    assert main(["recalibrate", "--robot", "R1", "--plan", str(plan), "--model-dir", str(models), "--method", "nls1",
                 "--validation", "6", "--validation-seed", "2", "--sim", *SIM_FAST, "--no-progress",
                 "--json", str(tmp_path / "d.json")]) == 0
    d = json.loads((tmp_path / "d.json").read_text())
    assert d["decision"] == "replaced" and d["current"] is None
    assert "geometry.P[2][2]: expected a finite number, got nan" in d["current_problem"]
    assert "replaced the unusable model in service (geometry.P[2][2]" in capsys.readouterr().out
    assert "is unusable (geometry.P[2][2]: expected a finite number, got nan); a valid candidate will replace" \
        in caplog.text
    assert load_model(models / "current.yaml").method == "nls1"
    assert [p.read_bytes() for p in (models / "previous").iterdir()] == [(files / "nan.yaml").read_bytes()]


def test_diagnose_refuses_a_model_of_another_robot_or_a_nan_model(files, tmp_path, capsys):
    out, js = tmp_path / "d.yaml", tmp_path / "d.json"
    common = ["--data", str(files / "train.csv"), "--out", str(out), "--json", str(js)]
    assert_bad_input(capsys, ["diagnose", "--robot", "R2", "--model", str(files / "r1.yaml")] + common,
                     "r1.yaml: robot: the model is for R1, not R2")
    assert_bad_input(capsys, ["diagnose", "--robot", "R1", "--model", str(files / "nan.yaml")] + common,
                     "nan.yaml: geometry.P[2][2]: expected a finite number, got nan")
    assert not out.exists() and not js.exists()
