"""The diagnose workflow: files written, bad input refused with nothing written, and the real R1 data."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from app.workflows.diagnose import run_diagnose
from calibration.errors import CellCalError
from calibration.models import load_model
from tests.conftest import write_backlash_case

SHARED = Path(__file__).resolve().parents[3].parent / "shared" / "data" / "welding_motoman"
R1_TRAIN = SHARED / "PH_grad_data" / "test0801_R1"
R1_TEST = SHARED / "kinematic_raw_data" / "test0801_R1"


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("diag")
    write_backlash_case(d, n_q2=6, n_q3=5, n_heldout=150)
    return d


def test_writes_json_report_and_model(files, tmp_path):
    res = run_diagnose("R1", files / "fit.csv", files / "ho.csv", json_path=tmp_path / "d.json",
                       report_dir=tmp_path / "rep", model_out=tmp_path / "m.yaml")
    j = json.loads((tmp_path / "d.json").read_text())
    assert j["schema"] == "cellcal.diagnose/1" and j["robot"] == "R1"
    assert [e["kind"] for e in j["effects"]] == ["backlash"]
    assert (tmp_path / "rep" / "report.md").exists() and (tmp_path / "rep" / "mismatch.png").exists()
    assert "backlash" in (tmp_path / "rep" / "report.md").read_text()
    m = load_model(tmp_path / "m.yaml")
    assert m.kind == "physics" and [e.kind for e in m.effects] == ["backlash"]
    np.testing.assert_allclose(m.fk(np.zeros((1, 6)))[1], res.model.fk(np.zeros((1, 6)))[1])


def test_given_model_is_the_baseline(files, tmp_path):
    run_diagnose("R1", files / "fit.csv", files / "ho.csv", model_out=tmp_path / "m.json")
    res = run_diagnose("R1", files / "fit.csv", files / "ho.csv", model=tmp_path / "m.json")
    assert res.baseline.model == "geometric+backlash" and res.effects == ()


@pytest.mark.parametrize("bad, match", [({"robot": "R9"}, "R9"), ({"data": "missing.csv"}, "not found")])
def test_bad_input_writes_nothing(files, tmp_path, bad, match):
    kw = {"robot": "R1", "data": files / "fit.csv", "heldout": files / "ho.csv", "json_path": tmp_path / "d.json",
          "report_dir": tmp_path / "rep", "model_out": tmp_path / "m.yaml"}
    kw.update(bad)
    with pytest.raises(CellCalError, match=match):
        run_diagnose(**kw)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.skipif(not (R1_TRAIN.exists() and R1_TEST.exists()), reason=f"real recordings not found at {SHARED}")
def test_real_r1_does_not_invent_effects_on_unmoved_joints(tmp_path):
    res = run_diagnose("R1", R1_TRAIN, R1_TEST, json_path=tmp_path / "r.json")
    assert res.n_fit == 1736 and res.n_heldout == 1500
    # An effect of a joint's own angle (gear error, backlash) needs that joint to move; a gravity compliance
    # follows the torque, which q2 and q3 change on every joint, and a zero offset needs no motion at all.
    own_angle = ("gear_transmission", "backlash")
    assert not any(set(e.joints) & {1, 4, 5, 6} for e in res.effects if e.kind in own_angle)
    hidden = {j for u in res.not_identifiable for j in u.joints if u.kind != "joint_offset"}
    assert {1, 4, 5, 6} <= hidden
    assert res.final.rms_mm <= res.baseline.rms_mm + 1e-9
