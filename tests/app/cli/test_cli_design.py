"""``cellcal select`` and ``cellcal plan --design optimal``: valid outputs, the safety model, bad budgets."""

from __future__ import annotations

import json

import numpy as np
import pytest

from app.cli.commands import main
from app.collection.plans.reader import read_plan
from app.collection.runtime.sim import park_q
from app.collection.safety import CellSafety
from calibration.data.recording import read_recording, write_recording
from cell_config import load_cell
from tests.conftest import assert_bad_input, cluster_design, measure


@pytest.fixture(scope="module")
def train(tmp_path_factory, synthetic_arm):
    """A 7-rows-per-cluster recording without a cluster column (the loader groups consecutive rows)."""
    _, _, truth = synthetic_arm
    q, _ = cluster_design(step_deg=15.0, spread_wrist=True, seed=2)
    path = tmp_path_factory.mktemp("design") / "train.csv"
    write_recording(measure(truth.fk, q, 0.02, 0.01, 1), path)
    return path


def test_select_writes_whole_clusters_as_a_valid_recording(tmp_path, train, capsys):
    out, js = tmp_path / "subset.csv", tmp_path / "select.json"
    assert main(["select", "--robot", "R1", "--data", str(train), "--budget", "5", "--out", str(out),
                 "--json", str(js)]) == 0
    full, sub = read_recording(train), read_recording(out)
    report = json.loads(js.read_text())
    assert len(sub) == 35 and report["samples"] == 35 and len(report["clusters"]) == 5
    rows = np.concatenate([np.arange(7 * c, 7 * c + 7) for c in sorted(report["clusters"])])
    np.testing.assert_array_equal(sub.q, full.q[rows])  # whole clusters, in the recording's order
    np.testing.assert_allclose(sub.p, full.p[rows])
    assert np.all(np.diff(sub.clusters()) >= 0) and len(set(sub.clusters().tolist())) == 5
    assert report["figures"]["selected"]["clusters"] == 5 and "condition_number" in report["figures"]["all"]
    assert "condition number" in capsys.readouterr().out


@pytest.mark.parametrize("budget", ["2", "1000", "x"])
def test_select_refuses_a_bad_budget_and_writes_nothing(tmp_path, train, capsys, budget):
    out = tmp_path / "subset.csv"
    argv = ["select", "--robot", "R1", "--data", str(train), "--budget", budget, "--out", str(out)]
    if budget == "x":
        with pytest.raises(SystemExit) as e:  # argparse's own type check
            main(argv)
        assert e.value.code == 2
    else:
        assert_bad_input(capsys, argv, "budget", budget)
    assert not out.exists()


def test_plan_optimal_respects_limits_and_safety_and_moves_joints_1_4_5_6(tmp_path, capsys):
    out, js = tmp_path / "plan.json", tmp_path / "plan_summary.json"
    assert main(["plan", "--robot", "R1", "--design", "optimal", "--budget", "63", "--out", str(out),
                 "--json", str(js)]) == 0
    plan = read_plan(out, "collection")
    cell = load_cell()
    spec = cell.robot("R1").robot
    assert len(plan) == 63 and sum(t.kind == "anchor" for t in plan.targets) == 9
    q = plan.q
    assert np.all(q >= spec.lower_rad) and np.all(q <= spec.upper_rad)
    CellSafety(cell).check_plan("R1", q, {"R2": park_q("R2")}, park_q("R1"))  # raises if any target/path is unsafe
    span = np.degrees(np.ptp(q, axis=0))
    assert np.all(span[[0, 3, 4, 5]] > 20.0), span  # the paper's grid keeps them within 2 deg
    figs = json.loads(js.read_text())["figures"]
    assert figs["optimal"]["rank"] == figs["optimal"]["identifiable"]
    assert figs["paper_grid"]["rank"] < figs["paper_grid"]["identifiable"]
    assert figs["optimal"]["condition_number"] < figs["paper_grid"]["condition_number"]
    assert "paper_grid" in capsys.readouterr().out


@pytest.mark.parametrize("design", [["--design", "optimal"], []])
def test_plan_optimal_refuses_a_bad_budget_and_writes_nothing(tmp_path, capsys, design):
    out = tmp_path / "plan.json"
    assert_bad_input(capsys, ["plan", "--robot", "R1", *design, "--budget", "10", "--out", str(out)],
                     "at least 21 poses")
    assert not out.exists()


def test_budget_belongs_to_the_optimal_design(tmp_path, capsys):
    out = tmp_path / "plan.json"
    assert_bad_input(capsys, ["plan", "--robot", "R1", "--design", "grid", "--budget", "70", "--out", str(out)],
                     "--design optimal")
    assert not out.exists()


def test_plan_defaults_to_the_optimal_design_of_196_poses(monkeypatch):
    """The default design is the optimal one (issue 34: the paper's grid sees 11 of 27 directions on R1) with a
    budget of 196 poses, 21 for a rebase design; the grid needs --design grid and its steps belong to it."""
    import app.cli.cell as cell_cli
    from app.cli.commands import build_parser

    args = build_parser().parse_args(["plan", "--robot", "R1", "--out", "p.json"])
    assert args.design == "optimal" and args.budget is None and args.q2_step is None
    seen = {}

    def fake_optimal_plan(robot, par, safety, others, spec, q_start):
        seen[spec.target] = spec.budget
        raise cell_cli.CellCalError("stop here")

    monkeypatch.setattr("app.collection.plans.design.optimal_plan", fake_optimal_plan)
    for extra in ([], ["--for", "rebase"]):
        args = build_parser().parse_args(["plan", "--robot", "R1", "--out", "p.json", *extra])
        with pytest.raises(cell_cli.CellCalError, match="stop here"):
            cell_cli.cmd_plan(args)
    assert seen == {"identification": 196, "rebase": 21}


def test_grid_steps_belong_to_the_grid_design(tmp_path, capsys):
    out = tmp_path / "plan.json"
    assert_bad_input(capsys, ["plan", "--robot", "R1", "--q2-step", "30", "--out", str(out)],
                     "--q2-step applies to --design grid only", "add --design grid")
    assert not out.exists()


@pytest.mark.parametrize("budget, fragments", [("10", ("--budget: expected an integer of at least 21 poses",)),
                                               ("70000", ("--budget 70000 asks for 10000 clusters", "give --budget")),
                                               # the help's minimum is a rebase design's; an identification design
                                               # of 21 said "3 clusters see 18 of 27 ...; raise the budget"
                                               ("21", ("--budget 21: 3 clusters of 7 see 18 of 27",
                                                       "give a larger --budget"))])
def test_plan_budget_errors_say_what_to_pass_without_internals(tmp_path, capsys, budget, fragments):
    from app.cli.commands import main

    out = tmp_path / "plan.json"
    assert main(["plan", "--robot", "R1", "--design", "optimal", "--budget", budget, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("cellcal plan: --budget"), err
    assert all(f in err for f in fragments) and "DesignSpec" not in err and "plan: plan:" not in err, err
    assert not out.exists()


def _budget_help(command: str) -> str:
    """The --budget entry of ``cellcal COMMAND --help``, whitespace joined (argparse wraps it)."""
    import argparse

    from app.cli.commands import build_parser

    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)).choices[command]
    text = " ".join(sub.format_help().split())
    text = text[text.index(" options: "):]  # the option list, not the usage line
    return text[text.index("--budget "):][:400]


@pytest.mark.parametrize("command, unit, other", [("plan", "POSES", "clusters"), ("select", "CLUSTERS", "poses")])
def test_budget_help_says_its_unit_and_that_the_other_command_counts_the_other(command, unit, other):
    """plan --budget counts poses, select --budget clusters: a new user took one for the other."""
    text = _budget_help(command)
    assert text.startswith(f"--budget {unit} "), text  # the unit in the usage line
    assert f"number of {unit}" in text and f"not {other}" in text, text
    assert ("default 196" if command == "plan" else "no default") in text, text


@pytest.mark.parametrize("option, value", [("--q2-step", "0"), ("--q3-step", "nan"), ("--q3-step", "inf"),
                                           ("--q2-step", "-5")])
def test_plan_refuses_a_grid_step_outside_its_range_naming_the_option_and_value(tmp_path, capsys, option, value):
    # 0 and nan were refused as "plan: q2_range_deg/steps: expected positive steps ...", inf gave a one-row grid
    out = tmp_path / "plan.json"
    assert_bad_input(capsys, ["plan", "--design", "grid", "--robot", "R1", "--out", str(out), option, value],
                     f"{option} must be in [0.5, 90] deg, got {value}")
    assert not out.exists()


@pytest.mark.parametrize("target", ["rebase", "identification"])
def test_select_json_sigma_says_its_unit_and_matches_the_printed_table(tmp_path, train, capsys, target):
    """The rebase directions' sigma keys name no unit (``base rotation about x``): the JSON gave radians where the
    printed table says mdeg, and nothing said so. Every sigma now has its unit in ``sigma_units``, and the printed
    figure is the JSON's in the table's unit."""
    js = tmp_path / "select.json"
    assert main(["select", "--robot", "R1", "--data", str(train), "--budget", "5", "--for", target,
                 "--out", str(tmp_path / "s.csv"), "--json", str(js)]) == 0
    table = capsys.readouterr().out
    figs = json.loads(js.read_text())["figures"]["selected"]
    assert set(figs["sigma_units"]) == set(figs["sigma"]) and set(figs["sigma_units"].values()) == {"mm", "rad"}
    for name, unit in figs["sigma_units"].items():
        assert unit == ("rad" if name.endswith("_rad") or "rotation" in name or "offset" in name else "mm"), name
    if target == "rebase":
        for name, sigma in figs["sigma"].items():
            unit = figs["sigma_units"][name]
            line = next(l for l in table.splitlines() if l.startswith(f"sigma {name} ["))
            shown = float(line.split()[-2])  # the selected design's column, printed with 4 decimals
            assert line.split("]")[0].endswith("mdeg" if unit == "rad" else "mm"), line
            np.testing.assert_allclose(shown, 1e3 * np.degrees(sigma) if unit == "rad" else sigma, rtol=0, atol=5.1e-5)
