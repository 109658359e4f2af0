"""``export-targets --jbi``: the INFORM job of a dual plan parses back with cellcal's own JBI reader to the very
pulses of the targets CSV, under the robot YAML's pulse convention (a non-trivial one included); bad job names
and speeds are one line, exit 2, nothing written."""

from __future__ import annotations

import csv
import json
import shutil
from datetime import UTC, datetime

import numpy as np
import pytest

from app.jobs.jbi import JobError, parse_job, pulse_job, read_job
from cell_config.loader import DEFAULT_CELL, load_cell
from tests.conftest import assert_bad_input

pytest.importorskip("casadi")

from app.cli.commands import main  # noqa: E402

DATE = datetime(2026, 12, 4, 22, 0, tzinfo=UTC)


@pytest.fixture(scope="module")
def planned(tmp_path_factory):
    root = tmp_path_factory.mktemp("jbi")
    assert main(["plan-dual", "--path", "sweep:5", "--out", str(root / "plan.json")]) == 0
    return root


def odd_convention_cell(root):
    """A copy of the packaged cell whose robots count some joints backwards from a non-zero pulse origin."""
    cell = root / "cell"
    shutil.copytree(DEFAULT_CELL.parent / "robots", cell / "robots")
    shutil.copytree(DEFAULT_CELL.parent / "tools", cell / "tools")
    shutil.copy(DEFAULT_CELL, cell / "cell.yaml")
    for name in ("MA2010", "MA1440"):
        path = cell / "robots" / f"{name}.yaml"
        text = path.read_text().replace("pulse_sign: [1, 1, 1, 1, 1, 1]", "pulse_sign: [1, -1, 1, -1, -1, 1]")
        path.write_text(text.replace("pulse_zero: [0, 0, 0, 0, 0, 0]", "pulse_zero: [120, -3000, 0, 77, 0, -5]"))
    return cell / "cell.yaml"


def csv_pulses(path) -> dict[tuple[int, str], list[int]]:
    with open(path, newline="") as f:
        return {(int(r["index"]), r["robot"]): [int(r[f"pulse{j}"]) for j in range(1, 7)] for r in csv.DictReader(f)}


@pytest.mark.parametrize("convention", ["yaml", "odd"])
def test_the_job_parses_back_to_the_targets_pulses(planned, tmp_path, capsys, convention):
    cell_path = DEFAULT_CELL if convention == "yaml" else odd_convention_cell(tmp_path)
    out, jbi, js = tmp_path / "t.csv", tmp_path / "SPRAY1.JBI", tmp_path / "t.json"
    assert main(["export-targets", "--cell", str(cell_path), "--plan", str(planned / "plan.json"), "--out", str(out),
                 "--jbi", str(jbi), "--speed", "5", "--json", str(js)]) == 0
    assert "5 coordinated joint moves (R1 = RB1, R2 = RB2, pulses, VJ=5.00)" in capsys.readouterr().out
    assert json.loads(js.read_text())["jbi"] == str(jbi)
    job = read_job(jbi)
    assert job.name == "SPRAY1" and job.groups == (("RB1",), ("RB2",))
    from_csv = csv_pulses(out)
    from_job = {}
    for k, p in enumerate(job.positions):
        assert p.postype == "PULSE" and p.tool == 0
        from_job[(k // 2, {"RB1": "R1", "RB2": "R2"}[p.unit])] = [int(v) for v in p.values]
    assert from_job == from_csv and len(from_job) == 10
    # and the pulses are the robot YAML's convention of the planned angles
    cell = load_cell(cell_path)
    plan = json.loads((planned / "plan.json").read_text())
    for (i, robot), pulses in from_job.items():
        q = np.asarray(plan["waypoints"][i][robot])
        assert pulses == cell.robot(robot).robot.to_pulses(q).tolist()
        np.testing.assert_allclose(cell.robot(robot).robot.from_pulses(np.array(pulses)), q,
                                   atol=0.5 / cell.robot(robot).robot.pulses_per_rad.min())
    lines = jbi.read_bytes().split(b"\r\n")
    assert lines[-1] == b"" and b"MOVJ C00000 VJ=5.00  +MOVJ C00001 VJ=5.00" in lines
    if convention == "odd":  # the convention matters: the packaged cell's pulses differ
        assert from_job != csv_pulses_of_default(planned, tmp_path)


def csv_pulses_of_default(planned, tmp_path):
    out = tmp_path / "default.csv"
    assert main(["export-targets", "--plan", str(planned / "plan.json"), "--out", str(out)]) == 0
    return csv_pulses(out)


@pytest.mark.parametrize(("name", "extra", "fragment"), [
    ("spray 1.JBI", [], "is not 1-32 letters"),
    ("SPRAY1.txt", [], "valid: .JBI"),
    ("SPRAY1.JBI", ["--speed", "0"], "outside [0.01, 100]"),
    ("SPRAY1.JBI", ["--speed", "150"], "outside [0.01, 100]"),
])
def test_bad_job_name_or_speed_exits_2_and_writes_nothing(planned, tmp_path, capsys, name, extra, fragment):
    out, jbi = tmp_path / "t.csv", tmp_path / name
    assert_bad_input(capsys, ["export-targets", "--plan", str(planned / "plan.json"), "--out", str(out),
                              "--jbi", str(jbi), *extra], fragment)
    assert not out.exists() and not jbi.exists()


def test_speed_without_a_job_is_refused_not_ignored(planned, tmp_path, capsys):
    out = tmp_path / "t.csv"
    assert_bad_input(capsys, ["export-targets", "--plan", str(planned / "plan.json"), "--out", str(out), "--speed",
                              "5"], "--speed", "needs --jbi")
    assert not out.exists()


def test_an_unsafe_plan_writes_no_job(planned, tmp_path, capsys):
    plan = json.loads((planned / "plan.json").read_text())
    plan["waypoints"][2]["R1"][1] = 3.0  # beyond joint 2's upper limit (155 deg)
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(plan))
    out, jbi = tmp_path / "t.csv", tmp_path / "SPRAY1.JBI"
    assert main(["export-targets", "--plan", str(bad), "--out", str(out), "--jbi", str(jbi)]) == 2
    capsys.readouterr()
    assert not out.exists() and not jbi.exists()


def test_pulse_job_round_trips_any_pulses_through_the_reader():
    """Property over random jobs of one and two groups: the reader gives back every pulse and robot."""
    rng = np.random.default_rng(5)
    for units in (("RB1",), ("RB1", "RB2")):
        for n in (1, 7):
            steps = [{u: rng.integers(-10**6, 10**6, 6).tolist() for u in units} for _ in range(n)]
            job = parse_job(pulse_job("J", steps, 12.5, DATE))
            assert job.groups == tuple((u,) for u in units)
            got = [(p.unit, [int(v) for v in p.values]) for p in job.positions]
            assert got == [(u, s[u]) for s in steps for u in units]


def test_pulse_job_refuses_a_step_leaving_a_robot_out():
    with pytest.raises(JobError, match="step 1 moves RB2; every step must move RB1, RB2"):
        pulse_job("J", [{"RB1": [0] * 6, "RB2": [0] * 6}, {"RB2": [1] * 6}], 10.0, DATE)
    with pytest.raises(JobError, match="expected 6 integer pulses"):
        pulse_job("J", [{"RB1": [0] * 5}], 10.0, DATE)
    with pytest.raises(JobError, match="no positions"):
        pulse_job("J", [], 10.0, DATE)


def test_the_example_job_in_docs_parses_as_a_two_group_job():
    from pathlib import Path

    job = read_job(Path(__file__).resolve().parents[3] / "docs" / "examples" / "SWEEP4.JBI")
    assert job.name == "SWEEP4" and job.groups == (("RB1",), ("RB2",)) and len(job.positions) == 8
    assert [p.unit for p in job.positions] == ["RB1", "RB2"] * 4


@pytest.mark.parametrize("module", ["app.dual.export_targets", "app.jobs.plan_job", "app.jobs"])
def test_each_module_imports_on_its_own(module):
    """export_targets once imported app.jobs, whose compensate imports export_targets: a circle that failed when
    export_targets was imported first."""
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-c", f"import {module}"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
