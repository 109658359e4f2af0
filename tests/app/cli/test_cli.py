"""The command line end to end on synthetic recordings, and every bad-input path."""

import json

import numpy as np
import pytest

from app.cli.commands import main
from calibration.data.recording import write_recording
from tests.conftest import assert_bad_input, cluster_design, measure


@pytest.fixture(scope="module")
def data(tmp_path_factory, synthetic_arm):
    _, _, truth = synthetic_arm
    root = tmp_path_factory.mktemp("data")
    q, cluster = cluster_design(step_deg=15.0)
    write_recording(measure(truth.fk, q, 0.02, 0.01, 1, cluster), root / "train.csv")
    q_test = np.random.default_rng(3).uniform(-0.8, 0.8, (200, 6))
    write_recording(measure(truth.fk, q_test, 0.02, 0.01, 2), root / "test.csv")
    np.savetxt(root / "q.csv", q_test[:10], delimiter=",")
    return root


def test_fit_predict_evaluate(tmp_path, data, capsys):
    model = tmp_path / "m.yaml"
    assert main(["fit", "--robot", "R1", "--train", str(data / "train.csv"), "--method", "nls1",
                 "--out", str(model)]) == 0
    poses = tmp_path / "poses.csv"
    assert main(["predict", "--model", str(model), "--joints", str(data / "q.csv"), "--out", str(poses)]) == 0
    header = poses.read_text().splitlines()[0]
    assert header == "x,y,z,qw,qx,qy,qz"
    assert len(poses.read_text().splitlines()) == 11
    out = tmp_path / "eval.json"
    assert main(["evaluate", "--model", str(model), "--test", str(data / "test.csv"), "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    assert result["test"]["position_mm"]["mean"] < 0.1  # planted errors recovered, noise 0.02 mm per axis


def test_compare_json_shape_and_report(tmp_path, data, capsys):
    out = tmp_path / "cmp.json"
    report = tmp_path / "report"
    assert main(["compare", "--robot", "R1", "--train", str(data / "train.csv"), "--test", str(data / "test.csv"),
                 "--methods", "nominal,base,nls1,fbf13,fbf7", "--json", str(out), "--report", str(report)]) == 0
    cmp = json.loads(out.read_text())
    assert cmp["robot"] == "R1"
    assert cmp["recommended"] in ("nominal", "base", "nls1", "fbf13", "fbf7")
    assert cmp["analysis"]["recommendation"]["method"] == cmp["recommended"]
    assert f"recommended: {cmp['recommended']} (" in capsys.readouterr().out
    for m in ("nominal", "base", "nls1", "fbf13", "fbf7"):
        entry = cmp["methods"][m]
        assert entry["fit_seconds"] >= 0
        for split in ("train", "test"):
            for kind in ("position_mm", "orientation_deg"):
                assert set(entry[split][kind]) >= {"mean", "std", "max", "rms"}
    assert cmp["methods"]["nls1"]["test"]["position_mm"]["mean"] < cmp["methods"]["nominal"]["test"]["position_mm"]["mean"]
    for name in ("report.md", "report.html", "error_workspace.png", "error_cdf.png"):
        assert (report / name).stat().st_size > 0
    fourier = cmp["recommended"] == "fbf13"  # its own plots only when it is the model put into service (issue 34)
    assert all((report / n).exists() == fourier for n in ("fourier_singular_values.png", "fourier_correction_map.png"))


def test_bad_inputs_exit_2_and_write_nothing(tmp_path, data, capsys):
    out = tmp_path / "never.yaml"
    bad = tmp_path / "bad.csv"
    bad.write_text("q1,q2,q3,q4,q5,q6,x,y,z,qw,qx,qy,qz\n0,0,0,0,0,0,1,2,nan,1,0,0,0\n")
    assert_bad_input(capsys, ["fit", "--robot", "R1", "--train", str(bad), "--method", "nls1", "--out", str(out)],
         "row 2", "'z'", "not a finite number")
    assert_bad_input(capsys, ["fit", "--robot", "R9", "--train", str(data / "train.csv"), "--method", "nls1", "--out", str(out)],
         "unknown robot 'R9'")
    assert_bad_input(capsys, ["compare", "--robot", "R1", "--train", str(data / "train.csv"), "--test", str(data / "test.csv"),
                  "--methods", "fbf13,magic", "--json", str(tmp_path / "c.json")], "unknown method 'magic'")
    short = tmp_path / "short"
    short.mkdir()
    (short / "robot_q_align.csv").write_text("0,0,0,0,0,0\n0,0,0,0,0,0\n")
    (short / "mocap_T_align.csv").write_text("1,2,3,1,0,0,0\n")
    assert_bad_input(capsys, ["evaluate", "--model", str(out), "--test", str(short)], "not found")
    quat = tmp_path / "quat.csv"
    quat.write_text("q1,q2,q3,q4,q5,q6,x,y,z,qw,qx,qy,qz\n0,0,0,0,0,0,1,2,3,0.5,0,0,0\n")
    assert_bad_input(capsys, ["fit", "--robot", "R1", "--train", str(quat), "--method", "base", "--out", str(out)],
         "row 2", "quaternion norm")
    limits = tmp_path / "limits.csv"
    limits.write_text("q1,q2,q3,q4,q5,q6,x,y,z,qw,qx,qy,qz\n0,0,3.0,0,0,0,1,2,3,1,0,0,0\n")
    assert_bad_input(capsys, ["fit", "--robot", "R1", "--train", str(limits), "--method", "base", "--out", str(out)],
         "row 2", "'q3'", "joint limits")
    assert not out.exists() and not (tmp_path / "c.json").exists()
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


@pytest.mark.parametrize("a", ["nan", "inf", "-5"])
def test_an_orientation_weight_that_is_not_finite_and_non_negative_is_refused(tmp_path, data, capsys, a):
    # --a nan and --a inf crashed the observability SVD with a traceback (exit 1); nominal took --a -5 silently
    out, js = tmp_path / "m.yaml", tmp_path / "m.json"
    for command, method in (("fit", ["--method", "nominal", "--out", str(out)]),
                            ("compare", ["--test", str(data / "test.csv"), "--methods", "nls1"])):
        assert_bad_input(capsys, [command, "--robot", "R1", "--train", str(data / "train.csv"), "--a", a, *method,
                                  "--json", str(js)], "orientation weight a (--a) must be a finite number >= 0")
    assert list(tmp_path.iterdir()) == []


def test_compare_of_only_cpa_without_sweeps_says_why_and_writes_nothing(tmp_path, data, capsys):
    # it said "no method has held-out errors to choose from; fitted: none"
    js, report = tmp_path / "c.json", tmp_path / "report"
    assert_bad_input(capsys, ["compare", "--robot", "R1", "--train", str(data / "train.csv"), "--test",
                              str(data / "test.csv"), "--methods", "cpa", "--json", str(js), "--report", str(report)],
                     "no method to compare: cpa skipped: no single-joint sweep data given (--cpa DATA)")
    assert list(tmp_path.iterdir()) == []


def test_fit_of_cpa_without_sweeps_names_the_option_and_writes_nothing(tmp_path, data, capsys):
    # it said "cpa needs single-joint sweep data (...); none was given", naming no option
    out, js = tmp_path / "m.yaml", tmp_path / "m.json"
    assert_bad_input(capsys, ["fit", "--robot", "R1", "--train", str(data / "train.csv"), "--method", "cpa",
                              "--out", str(out), "--json", str(js)],
                     "--method cpa needs --cpa SWEEPS: a single-joint sweep recording")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("argv, line", [
    (["fit", "--robot", "R1", "--train", "t.csv", "--methd", "nls1", "--out", "m.yaml"],
     "cellcal fit: unrecognized arguments: --methd (did you mean --method for --methd?); the following arguments "
     "are required: --method; cellcal fit --help lists the options"),
    (["plan", "--robot", "R1", "--out", "p.json", "--q2-stp=50"],
     "cellcal plan: unrecognized arguments: --q2-stp=50 (did you mean --q2-step for --q2-stp=50?); "
     "cellcal plan --help lists the options"),
    (["fit", "--robot", "R1", "--train", "t.csv", "--method", "nls1", "--out", "m.yaml", "--bogus"],
     "cellcal fit: unrecognized arguments: --bogus; cellcal fit --help lists the options"),
    (["fit", "--robot", "R1", "--train", "t.csv", "--method", "nls1", "--out", "m.yaml", "--a", "x"],
     "cellcal fit: argument --a: invalid float value: 'x'; cellcal fit --help lists the options"),
    ([], "cellcal: the following arguments are required: command; cellcal --help lists the options"),
])
def test_a_usage_error_is_one_line_exit_2_naming_a_mistyped_option(tmp_path, capsys, monkeypatch, argv, line):
    # argparse printed the whole usage first (4-10 lines), and for --methd said only that --method was missing
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 2
    assert capsys.readouterr().err.splitlines() == [line]
    assert list(tmp_path.iterdir()) == []


def test_too_few_training_clusters_for_held_out_figures_or_a_cdc_method_are_refused_naming_the_file(tmp_path, data,
                                                                                                    capsys):
    # one cluster: compare ended in a numpy traceback (a fold refit on no poses), fit --method fbf13 said
    # "x: empty array of shape (0, 2)"; two or three: "anchors: need at least d + 1 = 3 anchors ..., got 1"
    lines = (data / "train.csv").read_text().splitlines()
    out, js = tmp_path / "m.yaml", tmp_path / "c.json"
    for n in (1, 3):
        few = tmp_path / f"few{n}.csv"
        few.write_text("\n".join(lines[:1 + 7 * n]) + "\n")
        assert_bad_input(capsys, ["fit", "--robot", "R1", "--train", str(few), "--method", "fbf13", "--out", str(out)],
                         f"few{n}.csv: {n} cluster{'s' if n > 1 else ''} of training poses; a CDC method",
                         "needs at least 4")
    assert_bad_input(capsys, ["compare", "--robot", "R1", "--train", str(tmp_path / "few1.csv"), "--test",
                              str(data / "test.csv"), "--methods", "nominal,nls1", "--json", str(js)],
                     "few1.csv: 1 cluster of training poses; held-out figures", "need at least 2")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["few1.csv", "few3.csv"]


def test_training_anchors_on_a_line_are_refused_for_a_cdc_method_naming_the_file(tmp_path, data, capsys):
    # four clusters of one q2: fit --method fbf13 said "anchors: the 3 anchors span no 2-dimensional volume", a
    # fold's count and no file; with a fifth cluster off the line, the fold holding it out leaves four on it
    lines = (data / "train.csv").read_text().splitlines()
    rows = lines[1:]  # clusters of 7 rows, q2-major on the (q2, q3) grid of 5 q3 values
    out = tmp_path / "m.yaml"
    for name, clusters, fragment in (("line4.csv", (0, 1, 2, 3), "4 clusters of training poses whose anchors span "
                                      "no area in (q2, q3)"),
                                     ("line5.csv", (0, 1, 2, 3, 5), "5 clusters of training poses whose anchors, "
                                      "without the 1 held out in fold")):
        path = tmp_path / name
        path.write_text("\n".join([lines[0], *(r for c in clusters for r in rows[7 * c:7 * c + 7])]) + "\n")
        assert_bad_input(capsys, ["fit", "--robot", "R1", "--train", str(path), "--method", "fbf13", "--out",
                                  str(out)], f"{name}: {fragment}", "a CDC method interpolates over (q2, q3)")
    assert not out.exists()


def test_compare_shows_the_papers_column_only_for_a_test_recording_of_its_own_cell(tmp_path, data, capsys):
    # the R1 table carried the paper's Table IV figures beside any test recording, a simulated one included
    from app.reports.sections import PAPER_R1_TEST
    from calibration.data.recording import read_recording

    test = read_recording(data / "test.csv")
    folder = tmp_path / "welding"  # the same poses in the Welding_Motoman layout of the paper's cell
    folder.mkdir()
    np.savetxt(folder / "robot_q_align.csv", test.q, delimiter=",", fmt="%.17g")
    np.savetxt(folder / "mocap_T_align.csv", np.hstack([test.p, test.quat]), delimiter=",", fmt="%.17g")
    paper = " / ".join(f"{v:.2f}" for v in PAPER_R1_TEST["nominal"])  # the table prints its own figures to 3 places
    tables = {}
    for name, path in (("csv", data / "test.csv"), ("welding", folder)):
        assert main(["compare", "--robot", "R1", "--train", str(data / "train.csv"), "--test", str(path),
                     "--methods", "nominal,base"]) == 0
        tables[name] = capsys.readouterr().out
    assert paper not in tables["csv"] and "paper" not in tables["csv"]
    assert paper in tables["welding"] and "paper's Table IV on its R1 test set" in tables["welding"]


def test_predict_rejects_bad_joint_file(tmp_path, data, capsys):
    model = tmp_path / "m.json"
    assert main(["fit", "--robot", "R1", "--train", str(data / "train.csv"), "--method", "nls1",
                 "--out", str(model)]) == 0
    q = tmp_path / "q.csv"
    q.write_text("q1,q2,q3,q4,q5,q6\n0,0,x,0,0,0\n")
    out = tmp_path / "poses.csv"
    assert_bad_input(capsys, ["predict", "--model", str(model), "--joints", str(q), "--out", str(out)], "row 2", "'q3'")
    assert not out.exists()


def test_paired_tests_between_methods(tmp_path, data):
    out = tmp_path / "cmp.json"
    assert main(["compare", "--robot", "R1", "--train", str(data / "train.csv"), "--test", str(data / "test.csv"),
                 "--methods", "nominal,nls1,fbf13", "--json", str(out)]) == 0
    analysis = json.loads(out.read_text())["analysis"]
    vs_nominal = analysis["paired_tests_vs_nominal"]["nls1"]
    assert vs_nominal["mean_difference"] < 0 and vs_nominal["t_pvalue"] < 1e-6 and vs_nominal["wilcoxon_pvalue"] < 1e-6
    assert set(analysis["paired_tests_vs_fbf13"]) == {"nominal", "nls1"}
    assert len(analysis["nominal_error_joint_correlation_test"]) == 6


def test_compare_adds_saved_models_as_rows(tmp_path, data, capsys):
    """A saved model (a diagnose result, a model fitted elsewhere) is a row of compare like any method."""
    model = tmp_path / "mine.yaml"
    assert main(["fit", "--robot", "R1", "--train", str(data / "train.csv"), "--method", "nls1",
                 "--out", str(model)]) == 0
    out = tmp_path / "cmp.json"
    assert main(["compare", "--robot", "R1", "--train", str(data / "train.csv"), "--test", str(data / "test.csv"),
                 "--methods", "nominal,nls1", "--model", str(model), "--json", str(out)]) == 0
    assert "| mine (file) |" in capsys.readouterr().out
    methods = json.loads(out.read_text())["methods"]
    assert methods["mine (file)"]["test"] == methods["nls1"]["test"]  # the same fit, evaluated the same way
    other = tmp_path / "r2.yaml"
    other.write_text(model.read_text().replace("robot: R1", "robot: R2"))
    assert "robot: R2" in other.read_text()
    assert_bad_input(capsys, ["compare", "--robot", "R1", "--train", str(data / "train.csv"), "--test",
                              str(data / "test.csv"), "--methods", "nominal", "--model", str(other), "--json",
                              str(tmp_path / "c2.json")], "r2", "robot 'R2'")
    assert not (tmp_path / "c2.json").exists()


def test_version_and_ctrl_c(tmp_path, capsys, monkeypatch):
    """--version prints the package version; Ctrl-C is one line and exit 130, with no traceback."""
    import app.cli.commands as cli

    with pytest.raises(SystemExit) as e:
        cli.main(["--version"])
    assert e.value.code == 0 and capsys.readouterr().out.startswith("cellcal ")

    def interrupted(args):  # what a KeyboardInterrupt in the middle of a collection looks like to main()
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "cmd_fit", interrupted)
    argv = ["fit", "--robot", "R1", "--train", str(tmp_path / "x.csv"), "--method", "nls1", "--out", "m.yaml"]
    assert cli.main(argv) == 130
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["cellcal fit: stopped"]


def test_ctrl_c_during_a_collection_is_one_line_exit_130_and_resumable(tmp_path):
    import signal
    import subprocess
    import sys
    import time

    from app.collection.rehearsal import REPO, sample_count

    plan, session = tmp_path / "plan.json", tmp_path / "s"
    assert main(["plan", "--robot", "R1", "--design", "grid", "--q2-step", "50", "--q3-step", "50", "--out", str(plan)]) == 0
    # Ctrl-C as a terminal delivers it: a suite started as a background job of a non-interactive shell runs with
    # SIGINT ignored, and a child inherits that (Python then never raises KeyboardInterrupt)
    proc = subprocess.Popen([sys.executable, "-m", "app.cli", "collect", "--robot", "R1", "--plan", str(plan),
                             "--session", str(session), "--sim", "--time-scale", "2", "--no-progress"], cwd=REPO,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + 60
    while sample_count(session) < 2 and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.1)
    n_seen = sample_count(session)
    assert proc.poll() is None, f"the collection ended before the signal (exit {proc.returncode}, {n_seen} samples seen)"
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    lines = [line for line in err.strip().splitlines() if not line.startswith("target ")]
    assert lines[-1] == "cellcal collect: stopped (continue with --resume)" and "Traceback" not in err
    assert 2 <= sample_count(session) < 56


def test_rebase_moves_a_model_onto_a_shifted_day_and_refuses_another_robots_model(tmp_path, capsys):
    """cellcal rebase: a rigid base + marker change of a new day is taken up by the frames alone."""
    from calibration.data.recording import Recording, write_recording
    from calibration.kinematics import so3
    from calibration.models import ConstantModel, load_model, save_model
    from cell_config import load_cell
    from tests.conftest import assert_bad_input, cluster_design

    cell = load_cell()
    nominal = cell.robot("R1").model()
    model = ConstantModel("R1", "nls1", nominal)
    save_model(model, tmp_path / "m.yaml")
    q, cluster = cluster_design(step_deg=30.0)
    q = q[cluster < 3]  # three clusters: a few poses of the new day
    R, p = nominal.fk(q)
    R_b, p_b = so3.exp(np.radians([0.05, -0.03, 0.2])), np.array([1.5, -0.8, 0.6])  # the day's new frame
    R_t, p_t = so3.exp(np.radians([0.1, 0.0, -0.1])), np.array([0.3, 0.2, -0.4])  # the marker re-glued
    R_new = R_b @ R @ R_t
    p_new = p @ R_b.T + p_b + np.einsum("nij,j->ni", R_b @ R, p_t)
    write_recording(Recording(q, p_new, so3.R_to_quat(R_new)), tmp_path / "day.csv")
    assert main(["rebase", "--robot", "R1", "--model", str(tmp_path / "m.yaml"), "--data", str(tmp_path / "day.csv"),
                 "--out", str(tmp_path / "r.yaml"), "--json", str(tmp_path / "r.json")]) == 0
    rebased = load_model(tmp_path / "r.yaml", "R1", nominal)
    R_fit, p_fit = rebased.fk(q)
    held = json.loads((tmp_path / "r.json").read_text())["held"]
    # what the poses see is recovered; a direction they cannot see is held and named, not guessed
    assert np.max(np.linalg.norm(p_fit - p_new, axis=1)) < 0.05 and isinstance(held, list)
    assert json.loads((tmp_path / "r.json").read_text())["position_mean_mm"]["after"] < 0.05
    assert_bad_input(capsys, ["rebase", "--robot", "R2", "--model", str(tmp_path / "m.yaml"), "--data",
                              str(tmp_path / "day.csv"), "--out", str(tmp_path / "x.yaml")], "R1")
    assert not (tmp_path / "x.yaml").exists()


@pytest.mark.parametrize("tolerance", ["0", "-0.01", "nan", "inf", "1", "1e3"])
def test_rebase_refuses_a_tolerance_that_is_not_a_fraction_and_writes_nothing(tmp_path, data, capsys, tolerance):
    """--tolerance is a fraction of the largest singular value: 0, negative, NaN, inf or 1 and more held nothing or
    everything and went on without a word."""
    from calibration.models import ConstantModel, save_model
    from cell_config import load_cell

    save_model(ConstantModel("R1", "nls1", load_cell().robot("R1").model()), tmp_path / "m.yaml")
    out, js = tmp_path / "r.yaml", tmp_path / "r.json"
    assert_bad_input(capsys, ["rebase", "--model", str(tmp_path / "m.yaml"), "--data", str(data / "train.csv"),
                              "--out", str(out), "--json", str(js), "--tolerance", tolerance],
                     "--tolerance must be a fraction in (0, 1)", f"got {float(tolerance):g}")
    assert not out.exists() and not js.exists()


def test_diagnose_takes_train_and_test_like_every_command_and_the_old_names_still_work():
    from app.cli.commands import build_parser

    new = build_parser().parse_args(["diagnose", "--robot", "R1", "--train", "a.csv", "--test", "b.csv"])
    old = build_parser().parse_args(["diagnose", "--robot", "R1", "--data", "a.csv", "--heldout", "b.csv"])
    assert (new.train, new.test) == (old.train, old.test) == (["a.csv"], "b.csv")  # --train repeats (days)
