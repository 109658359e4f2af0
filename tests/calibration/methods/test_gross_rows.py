"""Gross measurement errors in a training recording (issue 30): a few marker swaps are named, set aside and warned
about; clean data loses no row."""

import json

import numpy as np
import pytest

from calibration.data.recording import Recording, write_recording
from calibration.methods.fitter import Fitter
from calibration.methods.heldout import GROSS_MAX_SHARE
from calibration.methods.options import FitOptions
from tests.conftest import cluster_design, measure


@pytest.fixture(scope="module")
def clean(synthetic_arm):
    _, _, truth = synthetic_arm
    q, cluster = cluster_design(step_deg=30.0)
    return measure(truth.fk, q, 0.05, 0.02, 1)  # no cluster column: consecutive groups of 7


def planted(rec: Recording, rows: list[int], error_mm: float = 50.0, seed: int = 0) -> Recording:
    d = np.random.default_rng(seed).normal(size=(len(rows), 3))
    p = rec.p.copy()
    p[rows] += error_mm * d / np.linalg.norm(d, axis=1, keepdims=True)
    return Recording(rec.q, p, rec.quat, rec.extra, "planted")


def test_clean_data_rejects_no_row(clean, r1_nominal):
    fitter = Fitter("R1", r1_nominal, clean)
    screened = fitter.without_gross_rows()
    assert screened is fitter and screened.gross.rows == () and not screened.gross.message()
    assert fitter._cache.is_empty()  # still fresh: calibration.frames.check.base_free may change its options


@pytest.mark.parametrize("error_mm", [5.0, 50.0])
def test_planted_gross_rows_are_named_and_rejected(clean, r1_nominal, error_mm):
    rows = [3, 40, 41, 80]
    fitter = Fitter("R1", r1_nominal, planted(clean, rows, error_mm)).without_gross_rows()
    assert fitter.gross.rows == tuple(rows)
    np.testing.assert_allclose(fitter.gross.position_mm, error_mm, rtol=0.1)
    assert len(fitter.train) == len(clean) - len(rows)
    # the clusters survive the gap: the kept rows keep the ids of their consecutive groups of 7
    expected = np.delete(np.arange(len(clean)) // 7, rows)
    np.testing.assert_array_equal(fitter.train.clusters(), expected)
    assert "4 of" in fitter.gross.message() and "4 (" in fitter.gross.message()  # row 3 is data row 4
    model, _ = fitter.fit("nls1")
    assert model.info["gross_rows"]["rows"] == [r + 1 for r in rows]


def test_the_fit_without_the_gross_rows_is_the_clean_fit(clean, r1_nominal):
    x_clean = Fitter("R1", r1_nominal, clean).global_fit()
    x_bad = Fitter("R1", r1_nominal, planted(clean, [5, 77])).global_fit()
    x_screened = Fitter("R1", r1_nominal, planted(clean, [5, 77])).without_gross_rows().global_fit()
    assert np.abs(x_screened - x_clean).max() < 0.2 * np.abs(x_bad - x_clean).max()


def test_more_rows_beyond_the_bound_than_a_few_rejects_none_and_says_so(clean, r1_nominal):
    rows = list(range(0, len(clean), int(1 / GROSS_MAX_SHARE) // 2))  # twice the share
    fitter = Fitter("R1", r1_nominal, planted(clean, rows)).without_gross_rows()
    assert fitter.gross.rows == () and fitter.gross.too_many and len(fitter.train) == len(clean)
    assert "none was rejected" in fitter.gross.message()


def test_rejection_can_be_turned_off(clean, r1_nominal):
    from cell_config import load_cell

    robot = load_cell().robot("R1")
    bad = planted(clean, [10])
    assert Fitter.for_arm(robot.arm(), bad).gross.rows == (10,)
    off = Fitter.for_arm(robot.arm(), bad, options=FitOptions(reject_gross_rows=False))
    assert off.gross is None and len(off.train) == len(clean)


def test_fit_warns_naming_the_rows_and_carries_them_in_the_json(clean, tmp_path, capsys):
    from app.cli.commands import main

    write_recording(planted(clean, [7, 8]), tmp_path / "t.csv")
    assert main(["fit", "--robot", "R1", "--train", str(tmp_path / "t.csv"), "--method", "nls1",
                 "--out", str(tmp_path / "m.yaml"), "--json", str(tmp_path / "j.json")]) == 0
    warnings = [line for line in capsys.readouterr().err.splitlines() if "gross" in line]
    assert len(warnings) == 1 and warnings[0].startswith("warning: 2 of") and "8 (" in warnings[0] \
        and "9 (" in warnings[0]
    assert json.loads((tmp_path / "j.json").read_text())["gross_rows"]["rows"] == [8, 9]


def test_diagnose_screens_its_recording_as_fit_does(clean, tmp_path, capsys):
    """diagnose fitted its effects on the rows as read: a 50 mm marker swap was left for an effect to explain."""
    from app.cli.commands import main

    write_recording(planted(clean, [7, 8]), tmp_path / "t.csv")
    assert main(["diagnose", "--robot", "R1", "--train", str(tmp_path / "t.csv"), "--json",
                 str(tmp_path / "d.json")]) == 0
    warnings = [line for line in capsys.readouterr().err.splitlines() if "gross" in line]
    assert len(warnings) == 1 and "2 of 84 training rows" in warnings[0] and "8 (" in warnings[0]
    doc = json.loads((tmp_path / "d.json").read_text())
    assert doc["gross_rows"]["rows"] == [8, 9] and doc["samples"]["fit"] + doc["samples"]["heldout"] == len(clean) - 2
