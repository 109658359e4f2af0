"""Frame checks on the command line: fit and compare name a planted tool-marker error and fit the frames first;
compare and evaluate say when a test recording is off its training recording by a frame."""

import json

import numpy as np
import pytest

from app.cli.commands import main
from calibration.data.recording import put_in, write_recording
from calibration.kinematics import so3
from calibration.kinematics.so3 import make_T
from calibration.models import load_model
from tests.conftest import R1_TRAIN, assert_bad_input, cluster_design, measure, needs_shared_data

T_TOOL_ERR = make_T(so3.exp(np.radians(0.5) * np.array([0.6, 0.0, 0.8])), np.array([12.0, 12.0, -6.0]))
T_BASE_ERR = make_T(so3.exp(np.radians(0.3) * np.array([0.0, 0.6, 0.8])), np.array([2.0, -1.5, 1.0]))


@pytest.fixture(scope="module")
def data(tmp_path_factory, synthetic_arm):
    _, _, truth = synthetic_arm
    root = tmp_path_factory.mktemp("frames")
    q, cluster = cluster_design(step_deg=15.0)
    train = measure(truth.fk, q, 0.02, 0.01, 1, cluster)
    test = measure(truth.fk, np.random.default_rng(3).uniform(-0.8, 0.8, (200, 6)), 0.02, 0.01, 2)
    write_recording(train, root / "train.csv")
    write_recording(test, root / "test.csv")
    write_recording(put_in(train, np.eye(4), T_TOOL_ERR), root / "train_tool.csv")
    write_recording(put_in(test, np.eye(4), T_TOOL_ERR), root / "test_tool.csv")
    write_recording(put_in(test, T_BASE_ERR, np.eye(4)), root / "test_moved.csv")
    return root


def test_fit_names_the_tool_frame_and_fits_it_first(tmp_path, data, capsys):
    out = tmp_path / "m.json"
    assert main(["fit", "--robot", "R1", "--train", str(data / "train_tool.csv"), "--method", "nls1",
                 "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "tool frame (tool-marker-to-flange registration) is off" in err and "The tool frame is fitted first" in err
    model = load_model(out)
    assert model.kind == "rebased" and model.info["frames_first"]["frame"] == "tool"
    result = tmp_path / "e.json"
    assert main(["evaluate", "--model", str(out), "--test", str(data / "test_tool.csv"), "--json", str(result)]) == 0
    assert json.loads(result.read_text())["test"]["position_mm"]["mean"] < 0.1


def test_clean_fit_says_nothing_about_frames(tmp_path, data, capsys):
    assert main(["fit", "--robot", "R1", "--train", str(data / "train.csv"), "--method", "nls1",
                 "--out", str(tmp_path / "m.json")]) == 0
    assert "frame" not in capsys.readouterr().err
    assert load_model(tmp_path / "m.json").kind == "constant"


def test_compare_and_evaluate_say_when_the_test_recording_is_off_by_a_frame(tmp_path, data, capsys):
    out = tmp_path / "cmp.json"
    for test, found in (("test.csv", False), ("test_moved.csv", True)):
        assert main(["compare", "--robot", "R1", "--train", str(data / "train.csv"), "--test", str(data / test),
                     "--methods", "nominal,nls1", "--json", str(out)]) == 0
        frames = json.loads(out.read_text())["analysis"]["frames"]
        assert frames["training"]["frame"] is None and frames["test"]["model"] == "nls1"
        assert (frames["test"]["frame"] is not None) == found
        err = capsys.readouterr().err
        assert ("test recording, against the nls1 fit of the training recording, is off by a frame" in err) == found
    assert main(["fit", "--robot", "R1", "--train", str(data / "train.csv"), "--method", "nls1",
                 "--out", str(tmp_path / "m.json")]) == 0
    assert main(["evaluate", "--model", str(tmp_path / "m.json"), "--test", str(data / "test_moved.csv"),
                 "--json", str(out)]) == 0
    assert "base frame (mocap-to-base registration)" in capsys.readouterr().err
    assert json.loads(out.read_text())["frames"]["frame"] == "base"


def test_several_training_recordings_fit_one_arm_with_frames_each(tmp_path, data, capsys):
    out = tmp_path / "cmp.json"
    train_moved = tmp_path / "train_moved.csv"
    from calibration.data.recording import read_recording

    write_recording(put_in(read_recording(data / "train.csv"), T_BASE_ERR, np.eye(4)), train_moved)
    assert main(["compare", "--robot", "R1", "--train", str(data / "train.csv"), "--train", str(train_moved),
                 "--test", str(data / "test.csv"), "--methods", "nominal,nls1", "--json", str(out)]) == 0
    err = capsys.readouterr().err
    assert "2 recordings in one arm model" in err and "Accuracy: the frames explain the differences" in err
    days = json.loads(out.read_text())["analysis"]["days"]
    moved = days["days"][1]["frames"]
    assert abs(moved["base_mm"] - np.linalg.norm(T_BASE_ERR[:3, 3])) < 0.1 and not days["kinematics_changed"]
    assert json.loads(out.read_text())["methods"]["nls1"]["test"]["position_mm"]["mean"] < 0.1
    model_file = tmp_path / "m.json"
    assert main(["fit", "--robot", "R1", "--train", str(data / "train.csv"), "--train", str(train_moved),
                 "--method", "nls1", "--out", str(model_file)]) == 0
    assert load_model(model_file).info["days"]["days"][1]["frames"]["base_mm"] == moved["base_mm"]


def test_the_same_training_recording_twice_is_refused(tmp_path, data, capsys):
    """fit and compare took one recording given twice as two days that agree (twice the samples, exit 0); diagnose
    refused it. The same file by another path (a symlink) is the same recording."""
    train = str(data / "train.csv")
    alias = tmp_path / "alias.csv"
    alias.symlink_to(data / "train.csv")
    out = tmp_path / "out.yaml"
    for second in (train, str(alias)):
        for argv in (["fit", "--robot", "R1", "--train", train, "--train", second, "--method", "nls1",
                      "--out", str(out)],
                     ["compare", "--robot", "R1", "--train", train, "--train", second, "--test",
                      str(data / "test.csv"), "--methods", "nls1", "--json", str(out)]):
            assert_bad_input(capsys, argv, second, "given twice")
    assert not out.exists()


def test_another_arms_recording_is_refused_not_called_a_frame_error(tmp_path, capsys):
    from calibration.models import ConstantModel, save_model
    from cell_config import load_cell

    cell = load_cell()
    q, cluster = cluster_design(step_deg=15.0)
    r2 = tmp_path / "r2.csv"
    write_recording(measure(cell.robot("R2").model().fk, q, 0.02, 0.01, 1, cluster), r2)  # R2's poses
    r1 = tmp_path / "r1.csv"
    write_recording(measure(cell.robot("R1").model().fk, q, 0.02, 0.01, 1, cluster), r1)
    r1_model = tmp_path / "r1.yaml"
    save_model(ConstantModel("R1", "nominal", cell.robot("R1").model(), 0, {}), r1_model)
    out = tmp_path / "out.yaml"
    before = sorted(p.name for p in tmp_path.iterdir())
    for argv in (["fit", "--robot", "R1", "--train", str(r2), "--method", "nls1", "--out", str(out)],
                 ["fit", "--robot", "R1", "--train", str(r2), "--train", str(r2), "--method", "nls1",
                  "--out", str(out)],
                 ["evaluate", "--model", str(r1_model), "--test", str(r2), "--json", str(out)],
                 ["rebase", "--robot", "R1", "--model", str(r1_model), "--data", str(r2), "--out", str(out)],
                 # diagnose and select took another arm's recording (held-out RMS 385 mm, a subset chosen by R1's
                 # Jacobian), exit 0
                 ["diagnose", "--robot", "R1", "--train", str(r2), "--json", str(out)],
                 ["diagnose", "--robot", "R1", "--train", str(r1), "--test", str(r2),
                  "--json", str(out)],
                 ["select", "--robot", "R1", "--data", str(r2), "--budget", "3", "--out", str(out)]):
        assert_bad_input(capsys, argv, str(r2), "not R1's poses", "the wrong --robot")
    assert sorted(p.name for p in tmp_path.iterdir()) == before


@pytest.mark.parametrize("which", ["test", "train"])
def test_compare_refuses_another_arms_recording_before_fitting_anything(tmp_path, data, capsys, monkeypatch, which):
    """compare checked a test recording of another arm only after fitting every method (seconds to minutes)."""
    import app.workflows.compare
    import calibration.methods.fitter
    from cell_config import load_cell

    def never(*args, **kwargs):
        raise AssertionError("fitted before the recordings were checked")

    monkeypatch.setattr(calibration.methods.fitter.Fitter, "fit", never)
    monkeypatch.setattr(app.workflows.compare, "run_comparison", never)
    q, cluster = cluster_design(step_deg=15.0)
    r2 = tmp_path / "r2.csv"
    write_recording(measure(load_cell().robot("R2").model().fk, q, 0.02, 0.01, 1, cluster), r2)  # R2's poses
    inputs = {"train": str(data / "train.csv"), "test": str(data / "test.csv"), which: str(r2)}
    out = tmp_path / "cmp.json"
    assert_bad_input(capsys, ["compare", "--robot", "R1", "--train", inputs["train"], "--test", inputs["test"],
                              "--methods", "nominal,nls1", "--json", str(out)],
                     f"{r2}: not R1's poses", "R1's nominal arm", "the wrong --robot, or a recording of another arm?")
    assert not out.exists()


@needs_shared_data()
def test_a_real_day_read_as_the_other_arm_is_refused(tmp_path, capsys):
    assert_bad_input(capsys, ["fit", "--robot", "R2", "--train", str(R1_TRAIN), "--method", "pi",
                              "--out", str(tmp_path / "wrong.yaml")], "not R2's poses", "R2's nominal arm")
    assert not (tmp_path / "wrong.yaml").exists()


def test_a_frame_found_on_poses_the_model_never_saw_says_it_may_be_extrapolation(tmp_path, synthetic_arm, capsys):
    _, _, truth = synthetic_arm
    q, cluster = cluster_design(step_deg=15.0, spread_wrist=False)  # q1 and the wrist within 1-2 deg
    train = tmp_path / "train.csv"
    write_recording(measure(truth.fk, q, 0.02, 0.01, 1, cluster), train)
    wide = np.random.default_rng(3).uniform(-0.8, 0.8, (200, 6))  # every joint turned widely
    inside = q[np.random.default_rng(4).choice(len(q), 200)]  # the training poses' own joint range
    model = tmp_path / "m.json"
    assert main(["fit", "--robot", "R1", "--train", str(train), "--method", "nls1", "--out", str(model)]) == 0
    out = tmp_path / "e.json"
    for name, poses, caveat in (("wide", wide, True), ("inside", inside, False)):
        moved = tmp_path / f"{name}.csv"
        write_recording(put_in(measure(truth.fk, poses, 0.02, 0.01, 2), T_BASE_ERR, np.eye(4)), moved)
        capsys.readouterr()
        assert main(["evaluate", "--model", str(model), "--test", str(moved), "--json", str(out)]) == 0
        err = capsys.readouterr().err
        frames = json.loads(out.read_text())["frames"]
        assert frames["frame"] is not None and "is off by a frame" in err  # the base error is found either way
        assert ("may be the model's extrapolation rather than a frame" in err) == caveat
        assert (frames["caveat"] is not None) == caveat


def test_a_rebase_on_fewer_than_three_clusters_warns_that_its_figure_is_in_sample(tmp_path, synthetic_arm, capsys):
    from calibration.models import ConstantModel, save_model

    par, _, truth = synthetic_arm
    q, cluster = cluster_design(step_deg=15.0)
    model = tmp_path / "m.yaml"
    save_model(ConstantModel("R1", "nominal", par.nominal, 0, {}), model)
    for clusters, warned in ((1, True), (2, True), (3, False)):
        keep = np.isin(cluster, np.unique(cluster)[[0, 17, 34][:clusters]])
        data = tmp_path / f"few{clusters}.csv"
        write_recording(measure(truth.fk, q[keep], 0.02, 0.01, 1, cluster[keep]), data)
        capsys.readouterr()
        assert main(["rebase", "--robot", "R1", "--model", str(model), "--data", str(data),
                     "--out", str(tmp_path / f"r{clusters}.yaml")]) == 0
        err = capsys.readouterr().err
        assert ("warning:" in err and f"{7 * clusters} poses in {clusters} cluster(s)" in err) == warned, err
    # without a cluster column and in no whole clusters of 7 it goes by the pose count (3 clusters' worth: 21)
    for n, warned in ((20, True), (22, False)):
        data = tmp_path / f"rows{n}.csv"
        write_recording(measure(truth.fk, q[::5][:n], 0.02, 0.01, 1), data)
        assert main(["rebase", "--robot", "R1", "--model", str(model), "--data", str(data),
                     "--out", str(tmp_path / f"n{n}.yaml")]) == 0
        err = capsys.readouterr().err
        assert ("warning:" in err and f"{n} poses in no clusters" in err) == warned, err
