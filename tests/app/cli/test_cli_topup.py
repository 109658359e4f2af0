"""``cellcal select --given TRAIN --task TASK --poses K``: the candidate rows a task needs beyond TRAIN."""

import csv
import json

import numpy as np
import pytest

from app.cli.commands import main
from calibration.data.recording import read_recording, write_recording, write_table
from calibration.methods.fitter import Fitter
from calibration.methods.topup import SIGMA_RESIDUAL_MM
from calibration.methods.topup_sigma import held_out_residual
from cell_config import load_cell
from tests.app.jobs.test_jbi import crlf, pulses
from tests.calibration.methods.test_standalone_poses import wide_poses
from tests.conftest import assert_bad_input, cluster_design, measure


@pytest.fixture(scope="module")
def files(synthetic_arm, tmp_path_factory):
    _, _, truth = synthetic_arm
    folder = tmp_path_factory.mktemp("topup")
    q, _ = cluster_design(step_deg=30.0, spread_wrist=False)
    write_recording(measure(truth.fk, q, 0.02, 0.01, 1), folder / "grid.csv")
    write_recording(measure(truth.fk, wide_poses(30, seed=11), 0.02, 0.01, 2), folder / "cand.csv")
    q_task = wide_poses(12, seed=12)
    write_table(folder / "task.csv", {f"q{i + 1}": q_task[:, i] for i in range(6)})
    return folder, q_task


def select(folder, task, *extra):
    return ["select", "--robot", "R1", "--data", str(folder / "cand.csv"), "--given", str(folder / "grid.csv"),
            "--task", str(task), *extra]


def test_the_chosen_rows_are_written_as_they_are_in_the_candidates(files):
    folder, _ = files
    out, js = folder / "picked.csv", folder / "picked.json"
    assert main(select(folder, folder / "task.csv", "--poses", "5", "--out", str(out), "--json", str(js))) == 0
    result = json.loads(js.read_text())
    with open(folder / "cand.csv") as f:
        rows = list(csv.reader(f))
    with open(out) as f:
        picked = list(csv.reader(f))
    assert picked[0] == rows[0] and len(picked) == 6
    assert picked[1:] == [rows[1 + i] for i in result["rows"]]  # the candidates' own text, in their order
    assert sorted(result["order"]) == result["rows"]
    assert result["predicted_sigma_mm"]["after"]["mean"] < result["predicted_sigma_mm"]["before"]["mean"]


def test_a_dual_plan_and_a_job_give_the_same_choice_as_their_joints(files):
    folder, q_task = files
    cell = load_cell()
    q_task_pulsed = cell.robot("R1").robot.from_pulses(cell.robot("R1").robot.to_pulses(q_task))
    write_table(folder / "pulsed.csv", {f"q{i + 1}": q_task_pulsed[:, i] for i in range(6)})
    plan = {"schema": "cellcal.plan/1", "kind": "dual", "models": {}, "T_wp_gun": None, "converged": True,
            "waypoints": [{"R1": q.tolist(), "R2": [0.0] * 6, "converged": True} for q in q_task_pulsed]}
    (folder / "task.json").write_text(json.dumps(plan))
    p = pulses(cell, "R1", np.degrees(q_task))
    (folder / "task.jbi").write_bytes(crlf(
        ["/JOB", "//NAME TASK", "//POS", f"///NPOS {len(p)},0,0,0,0,0", "///TOOL 0", "///POSTYPE PULSE", "///PULSE",
         *(f"C{i:05d}={v}" for i, v in enumerate(p)), "//INST", "///DATE 2026/12/01 12:00", "///ATTR SC,RW",
         "///GROUP1 RB1", "NOP", *(f"MOVJ C{i:05d} VJ=10.00" for i in range(len(p))), "END"]))
    orders = []
    for task in ("pulsed.csv", "task.json", "task.jbi"):
        js = folder / f"{task}.out.json"
        assert main(select(folder, folder / task, "--poses", "4", "--out", str(folder / f"{task}.out.csv"),
                           "--json", str(js))) == 0
        orders.append(json.loads(js.read_text())["order"])
    assert orders[0] == orders[1] == orders[2]


@pytest.mark.parametrize("extra, fragments", [
    (["--poses", "31"], ("--poses", "1..30")),
    (["--poses", "0"], ("--poses", "1..30")),
    (["--poses", "3", "--budget", "3"], ("--budget", "top-up")),
])
def test_bad_top_up_requests_are_refused_and_nothing_is_written(files, capsys, extra, fragments):
    folder, _ = files
    out = folder / "bad.csv"
    assert_bad_input(capsys, select(folder, folder / "task.csv", *extra, "--out", str(out)), *fragments)
    assert not out.exists()


def test_a_missing_part_of_a_top_up_is_named(files, capsys):
    folder, _ = files
    out = folder / "bad.csv"
    assert_bad_input(capsys, ["select", "--robot", "R1", "--data", str(folder / "cand.csv"), "--given",
                              str(folder / "grid.csv"), "--poses", "3", "--out", str(out)], "missing --task")
    assert_bad_input(capsys, ["select", "--robot", "R1", "--data", str(folder / "cand.csv"), "--out", str(out)],
                     "--budget", "--given")
    assert not out.exists()
    assert_bad_input(capsys, ["select", "--robot", "R1", "--data", str(folder / "grid.csv"), "--budget", "3",
                              "--keep-all", "--out", str(out)], "--keep-all")
    assert not out.exists()


def test_a_task_outside_the_joint_limits_is_refused(files, capsys):
    folder, q_task = files
    far = q_task.copy()
    far[3, 1] = 4.0  # q2 at 229 deg
    write_table(folder / "far.csv", {f"q{i + 1}": far[:, i] for i in range(6)})
    out = folder / "bad.csv"
    assert_bad_input(capsys, select(folder, folder / "far.csv", "--poses", "2", "--out", str(out)), "far.csv", "q2")
    assert not out.exists()


def test_plan_tops_up_a_given_recording_for_a_task_with_safe_poses(files):
    from app.collection.plans.reader import read_plan
    from app.collection.runtime.sim import park_q
    from app.collection.safety import CellSafety

    folder, _ = files
    out, js = folder / "topup-plan.json", folder / "topup-plan.out.json"
    assert main(["plan", "--robot", "R1", "--design", "optimal", "--given", str(folder / "grid.csv"), "--task",
                 str(folder / "task.csv"), "--budget", "6", "--out", str(out), "--json", str(js)]) == 0
    plan = read_plan(out, "collection")
    assert len(plan) == 6 and {t.kind for t in plan.targets} == {"anchor"}
    assert len({t.cluster for t in plan.targets}) == 6  # each pose its own id: they stand alone
    cell = load_cell()
    CellSafety(cell).check_plan("R1", plan.q, {n: park_q(n) for n in cell.robots if n != "R1"}, park_q("R1"))
    sigma = json.loads(js.read_text())["predicted_sigma_mm"]
    floor = np.sqrt(3) * SIGMA_RESIDUAL_MM  # what a global fit never learns, however close its poses
    assert floor - 1e-9 <= sigma["after"]["mean"] < sigma["before"]["mean"] - 0.05


def test_plan_from_scratch_for_a_task_without_given_poses(files):
    folder, _ = files
    js = folder / "scratch.json"
    assert main(["plan", "--robot", "R1", "--design", "optimal", "--task", str(folder / "task.csv"), "--budget", "30",
                 "--out", str(folder / "scratch-plan.json"), "--json", str(js)]) == 0
    sigma = json.loads(js.read_text())["predicted_sigma_mm"]
    assert sigma["after"]["mean"] < sigma["before"]["mean"]


@pytest.mark.parametrize("extra, fragment", [(["--budget", "6"], "missing --task"),
                                             (["--task", "TASK", "--budget", "6", "--for", "rebase"], "--for"),
                                             (["--task", "TASK"], "missing --budget")])
def test_a_bad_top_up_plan_is_refused_and_nothing_is_written(files, capsys, extra, fragment):
    folder, _ = files
    out = folder / "bad-plan.json"
    extra = [str(folder / "task.csv") if e == "TASK" else e for e in extra]
    assert_bad_input(capsys, ["plan", "--robot", "R1", "--design", "optimal", "--given", str(folder / "grid.csv"),
                              *extra, "--out", str(out)], fragment)
    assert not out.exists()


def test_evaluate_and_predict_give_the_predicted_sigma_lower_where_the_poses_were_added(files, synthetic_arm,
                                                                                       capsys):
    _, _, truth = synthetic_arm
    folder, q_task = files
    write_recording(measure(truth.fk, q_task, 0.02, 0.01, 7), folder / "task-measured.csv")
    assert main(["fit", "--robot", "R1", "--train", str(folder / "grid.csv"), "--method", "pi",
                 "--out", str(folder / "grid-pi.yaml")]) == 0
    shares = {}
    for extra in ([], ["--add", str(folder / "task-measured.csv")]):
        js = folder / "ev.json"
        assert main(["evaluate", "--model", str(folder / "grid-pi.yaml"), "--test", str(folder / "task-measured.csv"),
                     "--given", str(folder / "grid.csv"), *extra, "--sigma-residual-mm", str(SIGMA_RESIDUAL_MM),
                     "--json", str(js)]) == 0
        shares[len(extra)] = json.loads(js.read_text())["predicted_sigma"]
        assert shares[len(extra)]["residual_from"] == "--sigma-residual-mm"
    # measured there: only the residual a global fit never learns is left
    assert np.sqrt(3) * SIGMA_RESIDUAL_MM - 1e-9 <= shares[2]["mean_mm"] < shares[0]["mean_mm"] - 0.05
    assert 0.0 <= shares[0]["share_over_2_sigma"] <= 1.0
    assert 0.0070 <= shares[0]["gaussian_share_over_2_sigma"] <= 0.0460  # isotropic .. one axis
    assert main(["predict", "--model", str(folder / "grid-pi.yaml"), "--joints", str(folder / "task.csv"),
                 "--given", str(folder / "grid.csv"), "--out", str(folder / "pred.csv")]) == 0
    with open(folder / "pred.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == len(q_task) and all(float(r["sigma_mm"]) > 0 for r in rows)
    capsys.readouterr()  # the extrapolation warnings of the commands above
    assert_bad_input(capsys, ["predict", "--model", str(folder / "grid-pi.yaml"), "--joints", str(folder / "task.csv"),
                              "--add", str(folder / "cand.csv"), "--out", str(folder / "p2.csv")], "--given")
    assert not (folder / "p2.csv").exists()


def test_without_a_residual_given_sigma_takes_the_one_chosen_on_the_given_recordings_folds(files, synthetic_arm,
                                                                                         capsys):
    """evaluate, predict and select with --given use the residual of the largest likelihood of pi refitted without
    the given recording's held-out folds (calibration.methods.topup_sigma), and say so."""
    _, _, truth = synthetic_arm
    folder, q_task = files
    write_recording(measure(truth.fk, q_task, 0.02, 0.01, 7), folder / "task-measured.csv")
    assert main(["fit", "--robot", "R1", "--train", str(folder / "grid.csv"), "--method", "pi",
                 "--out", str(folder / "grid-pi.yaml")]) == 0
    given = read_recording(folder / "grid.csv")
    expected = held_out_residual(Fitter.for_arm(load_cell().robot("R1").arm(), given)).residual_mm
    js = folder / "ev.json"
    assert main(["evaluate", "--model", str(folder / "grid-pi.yaml"), "--test", str(folder / "task-measured.csv"),
                 "--given", str(folder / "grid.csv"), "--json", str(js)]) == 0
    sigma = json.loads(js.read_text())["predicted_sigma"]
    assert sigma["residual_mm"] == expected and sigma["residual_from"] == "held-out folds of --given"
    assert main(["predict", "--model", str(folder / "grid-pi.yaml"), "--joints", str(folder / "task.csv"),
                 "--given", str(folder / "grid.csv"), "--out", str(folder / "pred.csv"), "--json", str(js)]) == 0
    assert json.loads(js.read_text())["sigma_residual_mm"] == expected
    assert main(select(folder, folder / "task.csv", "--poses", "3", "--out", str(folder / "p.csv"), "--json",
                       str(js))) == 0
    assert json.loads(js.read_text())["predicted_sigma_mm"]["residual_mm"] == expected
    out = capsys.readouterr().out
    assert out.count(f"predicted sigma: residual {expected:g} mm per coordinate, chosen on") == 3


@pytest.mark.parametrize("bad", ["missing", "nan"])
@pytest.mark.parametrize("command", ["predict", "evaluate"])
def test_a_bad_given_is_the_one_line_before_any_warning_or_output(files, tmp_path, capsys, bad, command):
    """The task's poses leave the grid model's joint range (a warning); a bad --given used to be read after that
    warning (and after evaluate's summary on stdout), so the refusal was not the command's one line."""
    folder, _ = files
    model = tmp_path / "m.yaml"
    assert main(["fit", "--robot", "R1", "--train", str(folder / "grid.csv"), "--method", "nls1",
                 "--out", str(model)]) == 0
    given = tmp_path / "given.csv"
    if bad == "nan":
        given.write_text("q1,q2,q3,q4,q5,q6,x,y,z,qw,qx,qy,qz\nnan,0,0,0,0,0,1,2,3,1,0,0,0\n")
    out = tmp_path / "p.csv"
    argv = (["predict", "--model", str(model), "--joints", str(folder / "task.csv"), "--out", str(out)]
            if command == "predict" else ["evaluate", "--model", str(model), "--test", str(folder / "cand.csv"),
                                          "--json", str(out)])
    capsys.readouterr()
    assert main([*argv, "--given", str(given)]) == 2
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert len(err) == 1 and "given.csv" in err[0], err
    assert captured.out == "" and not out.exists()


@pytest.mark.parametrize("command", ["select", "plan", "predict", "evaluate"])
def test_another_arms_given_poses_are_refused(files, tmp_path, capsys, command):
    """--given is the poses a top-up builds on: another arm's (R2's poses given for R1) was accepted, and the design
    and the predicted sigma were those of the wrong arm (hostile-input pass)."""
    from cell_config import load_cell

    folder, _ = files
    q, _ = cluster_design(step_deg=30.0, spread_wrist=False)
    r2 = tmp_path / "r2.csv"
    write_recording(measure(load_cell().robot("R2").model().fk, q, 0.02, 0.01, 1), r2)
    model = folder / "grid-nls1-given.yaml"
    if not model.exists():
        assert main(["fit", "--robot", "R1", "--train", str(folder / "grid.csv"), "--method", "nls1",
                     "--out", str(model)]) == 0
    out = tmp_path / "out.csv"
    argv = {"select": [*select(folder, folder / "task.csv", "--poses", "3", "--out", str(out))],
            "plan": ["plan", "--robot", "R1", "--design", "optimal", "--given", str(folder / "grid.csv"), "--task",
                     str(folder / "task.csv"), "--budget", "3", "--out", str(out)],
            "predict": ["predict", "--model", str(model), "--joints", str(folder / "task.csv"), "--out", str(out),
                        "--given", str(folder / "grid.csv")],
            "evaluate": ["evaluate", "--model", str(model), "--test", str(folder / "cand.csv"), "--json", str(out),
                         "--given", str(folder / "grid.csv")]}[command]
    argv[argv.index(str(folder / "grid.csv"))] = str(r2)
    capsys.readouterr()
    assert_bad_input(capsys, argv, "r2.csv", "not R1's poses")
    assert not out.exists()


def test_evaluate_report_with_given_shows_where_the_model_can_be_trusted_along_the_task(files, synthetic_arm,
                                                                                       tmp_path, capsys):
    """evaluate --report --given: a visible paragraph (2 sigma against the tolerance, the rows outside the training
    range, the share beyond 2 sigma against the Gaussian's), a table, and the sigma-along-the-task plot; the same
    share as --json."""
    _, _, truth = synthetic_arm
    folder, q_task = files
    q = np.concatenate([q_task[:4], cluster_design(step_deg=30.0, spread_wrist=False)[0][:4], q_task[4:]])
    write_recording(measure(truth.fk, q, 0.02, 0.01, 8), tmp_path / "mixed.csv")
    assert main(["fit", "--robot", "R1", "--train", str(folder / "grid.csv"), "--method", "pi",
                 "--out", str(tmp_path / "pi.yaml")]) == 0
    js = tmp_path / "ev.json"
    assert main(["evaluate", "--model", str(tmp_path / "pi.yaml"), "--test", str(tmp_path / "mixed.csv"),
                 "--given", str(folder / "grid.csv"), "--json", str(js), "--report", str(tmp_path / "rep")]) == 0
    sigma = json.loads(js.read_text())["predicted_sigma"]
    html = (tmp_path / "rep" / "report.html").read_text()
    assert (tmp_path / "rep" / "sigma_along_task.png").stat().st_size > 1000
    assert "predicted 2 sigma and the measured error" in html
    text = next(line for line in html.splitlines() if "Predicted position uncertainty" in line)
    assert f"{100 * sigma['share_over_2_sigma']:.1f} % of the poses err by more than 2 sigma" in text
    assert f"would put {100 * sigma['gaussian_share_over_2_sigma']:.1f} %" in text
    # the wide task poses leave the grid's range, the four grid poses among them do not
    assert sigma["outside_given_range"] == len(q_task) and "(rows 1-4, 9-" in text
    capsys.readouterr()


def test_candidates_far_from_a_task_the_grid_covers_are_declined(synthetic_arm, tmp_path, capsys):
    """A task among a grid's configurations (every joint spread) and candidates 80 deg away in q1 and the wrist: the
    global fit is predicted to do worse on the task with them (it bends to their region's misfit), so select keeps
    none, says so, and writes the header alone; --keep-all keeps all K."""
    _, _, truth = synthetic_arm
    q, _ = cluster_design(step_deg=15.0, spread_wrist=True)
    write_recording(measure(truth.fk, q, 0.02, 0.01, 1), tmp_path / "grid.csv")
    q_far = wide_poses(10, seed=9)
    q_far[:, [0, 3, 4, 5]] = np.radians(80.0) + 0.1 * q_far[:, [0, 3, 4, 5]]
    write_recording(measure(truth.fk, q_far, 0.02, 0.01, 2), tmp_path / "cand.csv")
    q_task = q[::5] + np.radians(1.5)
    write_table(tmp_path / "task.csv", {f"q{i + 1}": q_task[:, i] for i in range(6)})
    out, js = tmp_path / "picked.csv", tmp_path / "picked.json"
    assert main(select(tmp_path, tmp_path / "task.csv", "--poses", "4", "--out", str(out), "--json", str(js),
                       "--sigma-residual-mm", "0.1")) == 0
    assert "declined 4 of the 4 poses asked" in capsys.readouterr().out
    result = json.loads(js.read_text())
    assert result["poses"] == 0 and result["declined"] == 4 and result["rows"] == []
    risk = result["predicted_fit_error_rms_mm"]
    assert risk["each_count"][4] > risk["before"] == risk["after"]
    with open(out) as f:
        assert len(list(csv.reader(f))) == 1  # the header alone
    assert main(select(tmp_path, tmp_path / "task.csv", "--poses", "4", "--keep-all", "--out", str(out),
                       "--sigma-residual-mm", "0.1")) == 0
    with open(out) as f:
        assert len(list(csv.reader(f))) == 5
