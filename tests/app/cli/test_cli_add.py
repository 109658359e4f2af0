"""``--add PICKED.csv`` on fit, compare and diagnose: extra poses fitted with the training recording as one day."""

import json

import numpy as np
import pytest

from app.cli.commands import main
from calibration.data.recording import DEFAULT_ADD_WEIGHT, write_recording
from tests.calibration.methods.test_standalone_poses import wide_poses
from tests.conftest import assert_bad_input, cluster_design, measure


@pytest.fixture(scope="module")
def files(synthetic_arm, tmp_path_factory):
    _, _, truth = synthetic_arm
    folder = tmp_path_factory.mktemp("add")
    q, _ = cluster_design(step_deg=15.0, spread_wrist=False)
    write_recording(measure(truth.fk, q, 0.02, 0.01, 1), folder / "grid.csv")  # 7-row blocks, no cluster column
    write_recording(measure(truth.fk, wide_poses(10), 0.02, 0.01, 2), folder / "picked.csv")  # not a multiple of 7
    write_recording(measure(truth.fk, wide_poses(4, seed=4), 0.02, 0.01, 3), folder / "more.csv")
    write_recording(measure(truth.fk, wide_poses(60, seed=9), 0.0, 0.0, 4), folder / "test.csv")
    return folder, len(q)


def test_fit_counts_the_added_poses_and_they_help_where_the_grid_never_went(files):
    folder, n_grid = files
    base = ["fit", "--robot", "R1", "--train", str(folder / "grid.csv"), "--method", "pi"]
    assert main(base + ["--out", str(folder / "grid.yaml"), "--json", str(folder / "grid.json")]) == 0
    assert main(base + ["--add", str(folder / "picked.csv"), "--add", str(folder / "more.csv"), "--add-weight", "1",
                        "--out", str(folder / "added.yaml"), "--json", str(folder / "added.json")]) == 0
    assert json.loads((folder / "added.json").read_text())["samples"] == n_grid + 14
    assert main(base + ["--add", str(folder / "picked.csv"), "--out", str(folder / "w.yaml"),
                        "--json", str(folder / "w.json")]) == 0
    assert json.loads((folder / "w.json").read_text())["samples"] == n_grid + 10 * DEFAULT_ADD_WEIGHT
    means = []
    for name in ("grid", "added"):
        assert main(["evaluate", "--model", str(folder / f"{name}.yaml"), "--test", str(folder / "test.csv"),
                     "--json", str(folder / f"{name}-eval.json")]) == 0
        means.append(json.loads((folder / f"{name}-eval.json").read_text())["test"]["position_mm"]["mean"])
    assert means[1] < 0.5 * means[0], means


def test_compare_fits_every_listed_method_with_the_added_poses(files):
    folder, n_grid = files
    assert main(["compare", "--robot", "R1", "--train", str(folder / "grid.csv"), "--add", str(folder / "picked.csv"),
                 "--test", str(folder / "test.csv"), "--methods", "nls1,pi,pi+linear",
                 "--json", str(folder / "cmp.json")]) == 0
    out = json.loads((folder / "cmp.json").read_text())
    assert out["recommended"] in ("nls1", "pi", "pi+linear")


def test_add_with_several_training_days_is_refused(files, capsys):
    folder, _ = files
    assert_bad_input(capsys, ["fit", "--robot", "R1", "--train", str(folder / "grid.csv"), "--train",
                              str(folder / "grid.csv"), "--add", str(folder / "picked.csv"), "--method", "nls1",
                              "--out", str(folder / "x.yaml")], "--add", "2 --train")
    assert not (folder / "x.yaml").exists()


def test_a_bad_added_file_names_itself_and_nothing_is_written(files, capsys):
    folder, _ = files
    bad = folder / "bad.csv"
    bad.write_text("q1,q2,q3,q4,q5,q6,x,y,z,qw,qx,qy,qz\n0,0,0,0,0,0,1,2,3,1,0,0,0\n0,0,0,0,0,0,1,2,nan,1,0,0,0\n")
    assert_bad_input(capsys, ["fit", "--robot", "R1", "--train", str(folder / "grid.csv"), "--add", str(bad),
                              "--method", "nls1", "--out", str(folder / "y.yaml")], "bad.csv", "z")
    assert not (folder / "y.yaml").exists()


def test_diagnose_takes_the_added_poses(files):
    folder, n_grid = files
    assert main(["diagnose", "--robot", "R1", "--train", str(folder / "grid.csv"), "--add", str(folder / "picked.csv"),
                 "--json", str(folder / "diag.json")]) == 0
    samples = json.loads((folder / "diag.json").read_text())["samples"]
    assert samples["fit"] + samples["heldout"] == n_grid + 10 * DEFAULT_ADD_WEIGHT  # the split: clusters and poses


def test_recalibrate_fits_the_added_poses_with_the_session(tmp_path, capsys):
    from calibration.data.recording import read_recording
    from calibration.models import load_model
    from tests.app.workflows.test_recalibrate import _sim_recalibrate

    args, models = _sim_recalibrate(tmp_path, "nls1", 6)
    bad = tmp_path / "bad.csv"
    bad.write_text("q1,q2\n0,0\n")
    assert_bad_input(capsys, args + ["--add", str(bad)], "bad.csv")  # refused before any motion
    assert not (models / "current.yaml").exists()
    assert main(args) == 0
    (stamp,) = (models / "sessions").iterdir()
    picked = tmp_path / "picked.csv"  # poses of the same simulated arm, as a top-up would measure them
    top_up = read_recording(stamp / "train.csv").subset(np.arange(0, 60, 6))
    top_up.p[3] += [50.0, 0.0, 0.0]  # one marker swap among the added poses: warned about, as fit warns
    write_recording(top_up, picked)
    again = [a if a != "--plan" else "--session" for a in args]
    again[again.index("--session") + 1] = str(stamp / "train")
    again[again.index("--model-dir") + 1] = str(tmp_path / "fresh")  # installed there: no model to beat
    capsys.readouterr()
    assert main(again + ["--add", str(picked)]) == 0
    gross = [line for line in capsys.readouterr().err.splitlines() if "gross" in line]
    assert len(gross) == 1 and gross[0].startswith("warning: "), gross
    text = json.dumps(load_model(tmp_path / "fresh" / "current.yaml").info, default=str)
    assert "picked.csv" in text  # the added poses are named among the model's inputs


@pytest.mark.parametrize("command", ["fit", "compare", "diagnose", "recalibrate"])
@pytest.mark.parametrize("weight", ["101", "100000", "1000000000"])
def test_a_weight_beyond_the_bound_is_refused_before_any_work(tmp_path, capsys, command, weight):
    """The weight repeats each added pose's rows: 1e9 exhausted memory with a traceback, 1e5 ran for minutes."""
    with pytest.raises(SystemExit) as stop:  # argparse's one line
        main([command, "--robot", "R1", "--train", str(tmp_path / "grid.csv"), "--add", str(tmp_path / "picked.csv"),
              "--add-weight", weight])
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--add-weight" in err[0] and "1..100" in err[0] and weight in err[0], err


def test_with_added_refuses_a_weight_beyond_the_bound(synthetic_arm):
    from calibration.data.recording import MAX_ADD_WEIGHT, with_added
    from calibration.errors import ModelError

    _, _, truth = synthetic_arm
    q, _ = cluster_design(step_deg=45.0, spread_wrist=False)
    rec = measure(truth.fk, q, 0.0, 0.0, 1)
    assert len(with_added(rec, [rec.subset(np.arange(2))], weight=MAX_ADD_WEIGHT)) == len(rec) + 2 * MAX_ADD_WEIGHT
    with pytest.raises(ModelError, match="1..100"):
        with_added(rec, [rec.subset(np.arange(2))], weight=MAX_ADD_WEIGHT + 1)
