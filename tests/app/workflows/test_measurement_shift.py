"""compare warns when the training recording's measured positions jump by one fixed vector on some poses."""

from dataclasses import replace

import numpy as np
import pytest

from app.workflows.compare import run_comparison
from calibration.data.recording import write_recording
from calibration.methods.fitter import Fitter
from calibration.methods.options import FitOptions
from tests.conftest import cluster_design, measure

METHODS = ("nominal", "pi")
SHIFT_MM = np.array([0.3, 0.5, -0.1])  # about what 0613's training recording shows


@pytest.fixture(scope="module")
def recordings(synthetic_arm):
    """(clean training, the same with SHIFT_MM added to every 12th pose, test), step 10 deg: 560 poses."""
    _, _, truth = synthetic_arm
    q, cluster = cluster_design(step_deg=10.0)
    train = measure(truth.fk, q, 0.03, 0.01, 1, cluster)
    shifted = np.arange(len(train)) % 12 == 5
    jumped = replace(train, p=train.p + shifted[:, None] * SHIFT_MM)
    q_test, _ = cluster_design(step_deg=20.0, seed=3)
    return train, jumped, shifted, measure(truth.fk, q_test, 0.03, 0.01, 2)


def _shift(r1_nominal, train, test) -> dict:
    cmp = run_comparison(Fitter("R1", r1_nominal, train, FitOptions()), test, METHODS)
    return cmp.analysis["measurement_shift"]


def test_planted_jumps_are_reported_with_their_direction(recordings, r1_nominal):
    _, jumped, shifted, test = recordings
    s = _shift(r1_nominal, jumped, test)
    assert s["found"]
    assert abs(s["shifted_poses"] - shifted.sum()) <= 0.2 * shifted.sum()
    assert float(np.dot(s["direction"], SHIFT_MM / np.linalg.norm(SHIFT_MM))) > 0.95
    assert "jumps by" in s["warning"] and f"{s['shifted_poses']} of {len(jumped)} poses" in s["warning"]


def test_clean_training_recording_gives_no_warning(recordings, r1_nominal):
    train, _, _, test = recordings
    s = _shift(r1_nominal, train, test)
    assert not s["found"] and s["warning"] == "" and s["shifted_poses"] == 0


def test_compare_prints_the_warning(recordings, tmp_path, capsys):
    from app.cli.commands import main

    _, jumped, _, test = recordings
    write_recording(jumped, tmp_path / "train.csv")
    write_recording(test, tmp_path / "test.csv")
    assert main(["compare", "--robot", "R1", "--train", str(tmp_path / "train.csv"), "--test",
                 str(tmp_path / "test.csv"), "--methods", ",".join(METHODS), "--json", str(tmp_path / "c.json")]) == 0
    err = capsys.readouterr().err
    assert "warning: the training recording has" in err and "jumps by" in err
    import json

    assert json.loads((tmp_path / "c.json").read_text())["analysis"]["measurement_shift"]["found"] is True
