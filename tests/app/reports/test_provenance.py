"""Provenance: every model file a command writes records when, which cellcal and the sha256 of its inputs."""

from __future__ import annotations

import datetime as dt
import hashlib

import numpy as np
import pytest
import yaml

from app.cli.commands import main
from app.reports.provenance import input_files, model_provenance, provenance, version
from calibration.data.recording import put_in, write_recording
from calibration.kinematics.so3 import make_T
from calibration.models import load_model, save_model
from tests.conftest import SIM_FAST, cluster_design, measure, write_backlash_case


@pytest.fixture(scope="module")
def data(tmp_path_factory, synthetic_arm):
    _, _, truth = synthetic_arm
    root = tmp_path_factory.mktemp("prov")
    q, cluster = cluster_design(step_deg=20.0)
    write_recording(measure(truth.fk, q, 0.02, 0.01, 1, cluster), root / "train.csv")
    q_few = np.random.default_rng(4).uniform(-0.6, 0.6, (30, 6))
    day2 = put_in(measure(truth.fk, q_few, 0.02, 0.01, 5), make_T(np.eye(3), np.array([1.5, -0.8, 0.6])), np.eye(4))
    write_recording(day2, root / "day2.csv")  # another day: its base moved (a rebase that changes nothing is refused)
    return root


def _sha(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_provenance_hashes_each_file_and_each_file_of_a_welding_folder(tmp_path):
    a = tmp_path / "a.csv"
    a.write_bytes(b"q1\n1\n")
    folder = tmp_path / "day"
    folder.mkdir()
    (folder / "robot_q_align.csv").write_bytes(b"0,0,0,0,0,0\n")
    (folder / "mocap_T_align.csv").write_bytes(b"1,2,3,1,0,0,0\n")
    (folder / "notes.txt").write_bytes(b"not read by the recording reader")
    when = dt.datetime(2026, 3, 4, 5, 6, 7, tzinfo=dt.UTC)
    p = provenance([("train", a), ("cpa", None), ("test", folder)], now=when)
    assert p["created_utc"] == "2026-03-04T05:06:07Z" and p["cellcal_version"] == version()
    assert [(i["role"], i["path"]) for i in p["inputs"]] == [
        ("train", str(a)), ("test", str(folder / "robot_q_align.csv")), ("test", str(folder / "mocap_T_align.csv"))]
    for item in p["inputs"]:
        assert item["sha256"] == hashlib.sha256(open(item["path"], "rb").read()).hexdigest()
    assert input_files(a) == [a]


def test_fit_records_the_training_file_and_the_file_round_trips_bit_identically(tmp_path, data):
    out = tmp_path / "m.yaml"
    assert main(["fit", "--robot", "R1", "--train", str(data / "train.csv"), "--method", "nls1", "--out", str(out)]) == 0
    model = load_model(out)
    p = model_provenance(model)
    assert p is not None and p["cellcal_version"] == version()
    assert p["inputs"] == [{"role": "train", "path": str(data / "train.csv"), "sha256": _sha(data / "train.csv")}]
    created = dt.datetime.strptime(p["created_utc"], "%Y-%m-%dT%H:%M:%SZ").replace(tzinfo=dt.UTC)
    assert abs((dt.datetime.now(dt.UTC) - created).total_seconds()) < 600
    again = tmp_path / "again.yaml"
    save_model(model, again)
    assert again.read_bytes() == out.read_bytes()


def test_rebase_records_the_model_and_the_new_days_poses(tmp_path, data):
    fitted, rebased = tmp_path / "m.yaml", tmp_path / "r.yaml"
    assert main(["fit", "--robot", "R1", "--train", str(data / "train.csv"), "--method", "nls1",
                 "--out", str(fitted)]) == 0
    assert main(["rebase", "--robot", "R1", "--model", str(fitted), "--data", str(data / "day2.csv"),
                 "--out", str(rebased)]) == 0
    p = model_provenance(load_model(rebased))
    assert [(i["role"], i["sha256"]) for i in p["inputs"]] == [("model", _sha(fitted)), ("data", _sha(data / "day2.csv"))]


def test_a_model_file_without_provenance_still_loads(tmp_path, data):
    out = tmp_path / "m.yaml"
    assert main(["fit", "--robot", "R1", "--train", str(data / "train.csv"), "--method", "base", "--out", str(out)]) == 0
    d = yaml.safe_load(out.read_text())
    del d["info"]["provenance"]
    old = tmp_path / "old.yaml"
    old.write_text(yaml.safe_dump(d, sort_keys=False))
    model = load_model(old)
    assert model_provenance(model) is None
    np.testing.assert_array_equal(model.fk(np.zeros((1, 6)))[1], load_model(out).fk(np.zeros((1, 6)))[1])


def test_diagnose_and_recalibrate_record_their_inputs(tmp_path):
    from app.workflows.diagnose import run_diagnose

    write_backlash_case(tmp_path)
    run_diagnose("R1", tmp_path / "fit.csv", tmp_path / "ho.csv", model_out=tmp_path / "d.yaml")
    p = model_provenance(load_model(tmp_path / "d.yaml"))
    assert [(i["role"], i["sha256"]) for i in p["inputs"]] == [("data", _sha(tmp_path / "fit.csv")),
                                                              ("heldout", _sha(tmp_path / "ho.csv"))]

    plan, models = tmp_path / "plan.json", tmp_path / "models"
    assert main(["plan", "--robot", "R1", "--out", str(plan), "--design", "grid", "--q2-step", "35", "--q3-step", "30"]) == 0
    assert main(["recalibrate", "--robot", "R1", "--plan", str(plan), "--model-dir", str(models), "--method", "nls1",
                 "--validation", "6", "--validation-seed", "2", "--sim", *SIM_FAST, "--no-progress"]) == 0
    p = model_provenance(load_model(models / "current.yaml"))
    assert [i["role"] for i in p["inputs"]] == ["train", "validation"]
    for item in p["inputs"]:
        assert item["path"].startswith(str(models / "sessions")) and item["sha256"] == _sha(type(models)(item["path"]))


def test_a_fit_on_several_training_recordings_records_each_of_them(data, tmp_path, synthetic_arm):
    q, cluster = cluster_design(step_deg=20.0)
    write_recording(measure(synthetic_arm[2].fk, q, 0.02, 0.01, 2, cluster), tmp_path / "other_day.csv")
    out = tmp_path / "two_days.yaml"
    days = [data / "train.csv", tmp_path / "other_day.csv"]
    assert main(["fit", "--robot", "R1", "--train", str(days[0]), "--train", str(days[1]),
                 "--method", "nls1", "--out", str(out)]) == 0
    inputs = model_provenance(load_model(out))["inputs"]
    assert [(i["role"], i["path"], i["sha256"]) for i in inputs] == [("train", str(d), _sha(d)) for d in days]
