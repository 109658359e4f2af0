"""``diagnose --train A --train B``: what differs between the days in the JSON (schema keys kept), the text and the
HTML report; bad input (a recording given twice, another robot's recording) is one line, exit 2, nothing written."""

from __future__ import annotations

import json

import numpy as np
import pytest

from app.cli.commands import main
from calibration.data.recording import Recording, put_in, write_recording
from calibration.kinematics import so3
from calibration.kinematics.so3 import make_T
from cell_config import load_cell
from tests.conftest import assert_bad_input, backlash_case, cluster_design, measure

#: Keys of the diagnose report (``docs/formats/diagnose-json.md``) that must stay.
SPEC_KEYS = {"schema", "robot", "samples", "noise_floor_mm", "baseline", "mismatch", "effects", "final", "verdict"}


@pytest.fixture(scope="module")
def days(tmp_path_factory):
    """Day A (the small backlash case), day B = A's poses in a base frame moved by 1 mm and 0.05 deg."""
    d = tmp_path_factory.mktemp("days")
    _, _, fit, _ = backlash_case(n_q2=5, n_q3=4)
    T = make_T(so3.exp(np.radians(0.05) * np.array([0.0, 0.0, 1.0])), np.array([1.0, 0.0, 0.0]))
    moved = put_in(fit, T, np.eye(4))
    write_recording(fit, d / "a.csv")
    write_recording(Recording(moved.q, moved.p, moved.quat, dict(fit.extra), "b"), d / "b.csv")
    return d


def test_two_days_json_text_and_report(days, tmp_path, capsys):
    out, report = tmp_path / "d.json", tmp_path / "report"
    assert main(["diagnose", "--robot", "R1", "--train", str(days / "a.csv"), "--data", str(days / "b.csv"),
                 "--json", str(out), "--report", str(report)]) == 0
    text = capsys.readouterr().out
    j = json.loads(out.read_text())
    assert SPEC_KEYS <= set(j)
    (b,) = j["days"]["days"]
    assert b["frames_differ"] and not b["kinematics_differ"]
    moved = {f["name"] for f in b["frames"] if f["differs"]}
    assert "base x shift" in moved and all(n.startswith("base") for n in moved)
    assert j["days"]["drift"]["tested"]  # the synthetic design carries t
    assert "against" in text and "frames differ" in text
    html = (report / "report.html").read_text()
    assert "What differs between the recordings" in html


def test_same_recording_twice_is_refused(days, tmp_path, capsys):
    out = tmp_path / "d.json"
    assert_bad_input(capsys, ["diagnose", "--robot", "R1", "--train", str(days / "a.csv"), "--train",
                              str(days / "a.csv"), "--json", str(out)], "a.csv", "given twice")
    assert not out.exists()


def test_other_robot_recording_is_refused(days, tmp_path, capsys):
    r2 = load_cell().robot("R2").model()
    q, cluster = cluster_design(step_deg=30.0, spread_wrist=False)
    write_recording(measure(r2.fk, q, 0.02, 0.01, 1, cluster), tmp_path / "r2.csv")
    out = tmp_path / "d.json"
    assert_bad_input(capsys, ["diagnose", "--robot", "R1", "--train", str(days / "a.csv"), "--train",
                              str(tmp_path / "r2.csv"), "--json", str(out)], "r2.csv", "not a recording of R1")
    assert not out.exists()
