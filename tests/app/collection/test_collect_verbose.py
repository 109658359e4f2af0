"""``collect -v`` on the simulated cell: one line per measured target with its residual against the model in use and
the mocap's health in its window (issue 34: it showed only a counter)."""

from __future__ import annotations

import logging
import re

import numpy as np
import pytest

from app.cli.commands import main
from app.progress import install_logging
from calibration.data.recording import read_recording
from calibration.evaluation.metrics import errors
from calibration.models import ConstantModel, load_model
from cell_config import load_cell
from tests.conftest import SIM_FAST

LINE = re.compile(r"R1 target (\d+)/(\d+) \((\w+), cluster (-?\d+)\): residual ([\d.]+) mm / ([\d.]+) deg against (.+?); "
                  r"mocap (\d+) frames in the window, tracking spread ([\d.]+) mm / ([\d.]+) deg, marker error "
                  r"([\d.]+) mm \(frames above 0.5 mm rejected\)")


@pytest.fixture
def verbose_logging():
    yield
    install_logging(logging.WARNING)  # main() set the root logger to INFO for -v


def _collect(tmp_path, capsys, *extra: str) -> tuple[list[re.Match], object]:
    plan = tmp_path / "plan.json"
    if not plan.exists():
        assert main(["plan", "--robot", "R1", "--out", str(plan), "--design", "grid", "--q2-step", "35",
                     "--q3-step", "30"]) == 0
    session = tmp_path / f"s{len(list(tmp_path.glob('s*')))}"
    capsys.readouterr()
    assert main(["-v", "collect", "--robot", "R1", "--plan", str(plan), "--session", str(session), "--sim", *SIM_FAST,
                 "--no-progress", *extra]) == 0
    err = capsys.readouterr().err
    lines = [LINE.fullmatch(ln) for ln in err.splitlines() if re.match(r"R1 target \d+/", ln)]
    assert lines and all(lines), err[-2000:]
    rec = tmp_path / f"{session.name}.csv"
    assert main(["export", "--session", str(session), "--out", str(rec)]) == 0
    return lines, read_recording(rec)


def test_collect_v_shows_each_targets_residual_and_mocap_health(tmp_path, capsys, verbose_logging):
    lines, rec = _collect(tmp_path, capsys)
    n = len(rec)
    assert [int(m.group(1)) for m in lines] == list(range(1, n + 1)) and {int(m.group(2)) for m in lines} == {n}
    assert {m.group(7) for m in lines} == {"the nominal R1"}
    robot = load_cell().robot("R1")
    e = errors(ConstantModel("R1", "nominal", robot.model(), 0, {}), rec)  # evaluate's figures, recomputed
    np.testing.assert_allclose([float(m.group(5)) for m in lines], e.position_mm, atol=6e-4)
    np.testing.assert_allclose([float(m.group(6)) for m in lines], e.orientation_deg, atol=6e-4)
    assert [int(m.group(8)) for m in lines] == rec.extra["frames"].astype(int).tolist()
    np.testing.assert_allclose([float(m.group(11)) for m in lines], rec.extra["marker_err"], atol=6e-4)
    assert all(float(m.group(9)) > 0 for m in lines)  # the simulated mocap's noise: a spread in every window


def test_collect_v_takes_the_residual_against_the_model_given(tmp_path, capsys, verbose_logging):
    """With --model, the lines' residuals are that model's: a model fitted on the first session's poses."""
    _, first = _collect(tmp_path, capsys)
    model = tmp_path / "nls1.yaml"
    assert main(["fit", "--robot", "R1", "--train", str(tmp_path / "s0.csv"), "--method", "nls1", "--out",
                 str(model)]) == 0
    lines, rec = _collect(tmp_path, capsys, "--model", str(model))
    assert {m.group(7) for m in lines} == {str(model)}
    e = errors(load_model(str(model)), rec)
    np.testing.assert_allclose([float(m.group(5)) for m in lines], e.position_mm, atol=6e-4)
    assert np.mean(e.position_mm) < 0.5 * np.mean(errors(ConstantModel("R1", "nominal", load_cell().robot(
        "R1").model(), 0, {}), first).position_mm)  # the fitted model's residuals, not the nominal's


def test_recalibrate_v_shows_the_lines_against_the_model_in_service(tmp_path, capsys, verbose_logging):
    """recalibrate collects too: with -v its targets' lines compare with the model in service (the nominal arm when
    there is none)."""
    plan = tmp_path / "plan.json"
    assert main(["plan", "--robot", "R1", "--out", str(plan), "--design", "grid", "--q2-step", "35",
                 "--q3-step", "30"]) == 0
    argv = ["recalibrate", "--robot", "R1", "--plan", str(plan), "--model-dir", str(tmp_path / "models"), "--method",
            "nls1", "--validation", "4", "--validation-seed", "2", "--sim", *SIM_FAST, "--no-progress"]
    capsys.readouterr()
    assert main(["-v", *argv]) == 0
    lines = [LINE.fullmatch(ln) for ln in capsys.readouterr().err.splitlines() if re.match(r"R1 target \d+/", ln)]
    assert len(lines) == 77 + 4 and all(lines) and {m.group(7) for m in lines} == {"the nominal R1"}
