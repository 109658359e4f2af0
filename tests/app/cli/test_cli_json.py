"""``--json`` of the commands that print a result: the file parses and holds the figures the command printed."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from app.cli.commands import main
from calibration.data.recording import write_recording
from tests.conftest import SIM_FAST, cluster_design, measure


def numbers(line: str) -> list[float]:
    """Every number printed in ``line``, in order."""
    return [float(x) for x in re.findall(r"-?\d+(?:\.\d+)?(?:e[-+]?\d+)?", line)]


@pytest.fixture(scope="module")
def data(tmp_path_factory, synthetic_arm):
    _, _, truth = synthetic_arm
    root = tmp_path_factory.mktemp("data")
    q, cluster = cluster_design(step_deg=15.0)
    write_recording(measure(truth.fk, q, 0.02, 0.01, 1, cluster), root / "train.csv")
    q_test = np.random.default_rng(3).uniform(-0.8, 0.8, (7, 6))
    np.savetxt(root / "q.csv", q_test, delimiter=",")
    return root


def test_fit_and_predict_json_hold_the_printed_figures(tmp_path, data, capsys):
    model = tmp_path / "m.yaml"
    assert main(["fit", "--robot", "R1", "--train", str(data / "train.csv"), "--method", "nls1", "--out", str(model),
                 "--json", str(tmp_path / "fit.json")]) == 0
    line = capsys.readouterr().out.strip().splitlines()[-1]
    fit = json.loads((tmp_path / "fit.json").read_text())
    n_par, n_samples, seconds = numbers(line.split("->")[0].split(":", 1)[1])
    assert (fit["method"], fit["robot"], fit["out"]) == ("nls1", "R1", str(model))
    assert (fit["n_parameters"], fit["samples"]) == (n_par, n_samples)
    assert f"{fit['fit_seconds']:.3f}" == f"{seconds:.3f}"

    poses = tmp_path / "poses.csv"
    assert main(["predict", "--model", str(model), "--joints", str(data / "q.csv"), "--out", str(poses),
                 "--json", str(tmp_path / "predict.json")]) == 0
    line = capsys.readouterr().out.strip().splitlines()[-1]
    predict = json.loads((tmp_path / "predict.json").read_text())
    assert predict["poses"] == numbers(line)[0] == 7 == len(poses.read_text().splitlines()) - 1
    assert predict["outside_fitted_region"] == 0 and predict["method"] == "nls1"


def test_plan_collect_export_json_hold_the_printed_figures(tmp_path, capsys):
    plan = tmp_path / "plan.json"
    assert main(["plan", "--robot", "R1", "--out", str(plan), "--design", "grid", "--q2-step", "50", "--q3-step", "50",
                 "--validation", "2", "--json", str(tmp_path / "plan_summary.json")]) == 0
    line = capsys.readouterr().out.strip().splitlines()[-1]
    summary = json.loads((tmp_path / "plan_summary.json").read_text())
    assert summary["targets"] == numbers(line)[1] == len(json.loads(plan.read_text())["targets"])
    for kind, n in summary["kinds"].items():
        assert f"{n} {kind}" in line
    assert sum(summary["kinds"].values()) == summary["targets"]

    session = tmp_path / "s"
    assert main(["collect", "--robot", "R1", "--plan", str(plan), "--session", str(session), "--sim",
                 *SIM_FAST, "--no-progress"]) == 0
    capsys.readouterr()
    out = tmp_path / "anchors.csv"
    assert main(["export", "--session", str(session), "--out", str(out), "--kinds", "anchor",
                 "--json", str(tmp_path / "export.json")]) == 0
    line = capsys.readouterr().out.strip().splitlines()[-1]
    export = json.loads((tmp_path / "export.json").read_text())
    assert export["samples"] == numbers(line)[0] == summary["kinds"]["anchor"] == len(out.read_text().splitlines()) - 1
    assert export["kinds"] == ["anchor"] and export["out"] == str(out)


def test_export_targets_json_holds_the_printed_figures(tmp_path, capsys):
    pytest.importorskip("casadi")
    plan = tmp_path / "plan.json"
    assert main(["plan-dual", "--path", "sweep:3", "--out", str(plan), "--json", str(tmp_path / "pd.json")]) == 0
    line = capsys.readouterr().out.strip().splitlines()[-1]
    pd = json.loads((tmp_path / "pd.json").read_text())
    assert pd["waypoints"] == numbers(line)[0] == 3
    assert f"{pd['solve_ms_median']:.2f}" in line and f"{pd['min_clearance_mm']:.0f} mm" in line
    out = tmp_path / "targets.json"
    assert main(["export-targets", "--plan", str(plan), "--out", str(out), "--frame", "tool",
                 "--json", str(tmp_path / "et.json")]) == 0
    line = capsys.readouterr().out.strip().splitlines()[-1]
    et = json.loads((tmp_path / "et.json").read_text())
    assert et["targets"] == numbers(line)[0] == 6 and et["frame"] == "tool" and f"({et['frame']} frame)" in line


def test_the_rehearsal_processes_write_their_counters_at_stop(tmp_path):
    """fake-controller, fake-motive and mocap-bridge as real processes: each --json holds its printed counters."""
    import time

    from app.collection.rehearsal import Process, write_rehearsal_cell
    from cell_config import load_cell
    from drivers.bus import ZenohMocapSource

    cell = write_rehearsal_cell(tmp_path)
    procs = {name: Process(cell, name, *args, "--json", str(tmp_path / f"{name}.json"))
             for name, args in (("fake-controller", ()), ("fake-motive", ("--seed", "5")), ("mocap-bridge", ()))}
    try:
        for p in procs.values():
            p.start()
        spec = load_cell(cell)
        with ZenohMocapSource(spec.name, config=spec.zenoh_for("collector"), rigid_bodies=["weldgun"]) as sub:
            deadline = time.monotonic() + 30  # until the bridge has connected to the fake Motive and publishes
            while not sub.read(0.5):
                assert time.monotonic() < deadline, "no mocap frame through the bridge within 30 s"
    finally:
        codes = {name: p.stop() for name, p in reversed(list(procs.items()))}
    assert codes == dict.fromkeys(procs, 0), {n: procs[n].output[-1500:] for n in procs}
    out = {name: json.loads((tmp_path / f"{name}.json").read_text()) for name in procs}
    stopped = {name: next(line for line in p.lines if "stopped" in line) for name, p in procs.items()}
    bridge = out["mocap-bridge"]
    assert numbers(stopped["mocap-bridge"])[:3] == [bridge["frames_published"], bridge["connections"],
                                                     bridge["handshakes"]]
    assert bridge["frames_published"] > 0
    assert numbers(stopped["fake-motive"])[0] == out["fake-motive"]["frames_sent"] > 0
    assert numbers(stopped["fake-controller"])[0] == out["fake-controller"]["trajectory_points_received"] == 0
