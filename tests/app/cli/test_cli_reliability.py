"""Bad input found by a reliability pass (issue 12): each path refused in one line with exit 2, or accepted
where the spec says it is valid."""

import numpy as np
import pytest

from app.cli.commands import main
from calibration.data.recording import write_recording
from tests.conftest import assert_bad_input, cluster_design, measure

BOM = b"\xef\xbb\xbf"


@pytest.fixture(scope="module")
def data(tmp_path_factory, synthetic_arm):
    _, _, truth = synthetic_arm
    root = tmp_path_factory.mktemp("data")
    q, cluster = cluster_design(step_deg=45.0)
    write_recording(measure(truth.fk, q, 0.02, 0.01, 1, cluster), root / "train.csv")
    np.savetxt(root / "q.csv", np.random.default_rng(3).uniform(-0.8, 0.8, (5, 6)), delimiter=",")
    assert main(["fit", "--robot", "R1", "--train", str(root / "train.csv"), "--method", "base",
                 "--out", str(root / "m.json")]) == 0
    assert main(["fit", "--robot", "R1", "--train", str(root / "train.csv"), "--method", "base",
                 "--out", str(root / "m.yaml")]) == 0
    return root


def with_bom(src, dst):
    dst.write_bytes(BOM + src.read_bytes())
    return dst


def test_utf8_bom_accepted_in_csv_model_and_plan_files(tmp_path, data):
    train = with_bom(data / "train.csv", tmp_path / "train.csv")
    assert main(["fit", "--robot", "R1", "--train", str(train), "--method", "base",
                 "--out", str(tmp_path / "m.json")]) == 0
    joints = with_bom(data / "q.csv", tmp_path / "q.csv")
    for name in ("m.json", "m.yaml"):
        model = with_bom(data / name, tmp_path / f"bom-{name}")
        out = tmp_path / f"poses-{name}.csv"
        assert main(["predict", "--model", str(model), "--joints", str(joints), "--out", str(out)]) == 0
        assert len(out.read_text().splitlines()) == 6
    plan = tmp_path / "plan.json"
    assert main(["plan", "--robot", "R1", "--design", "grid", "--q2-step", "50", "--q3-step", "50", "--out", str(plan)]) == 0
    from app.collection.plans.reader import read_plan

    read_plan(with_bom(plan, tmp_path / "bom-plan.json"))


def test_fit_refuses_a_recording_above_the_row_limit(tmp_path, data, capsys, monkeypatch):
    import calibration.data.recording as recording

    monkeypatch.setattr(recording, "MAX_ROWS", 10)
    out = tmp_path / "m.yaml"
    assert_bad_input(capsys, ["fit", "--robot", "R1", "--train", str(data / "train.csv"), "--method", "base",
                              "--out", str(out)], str(data / "train.csv"), "more than 10 data rows")
    assert not out.exists()


def test_plan_dual_refuses_a_sweep_above_the_waypoint_limit(tmp_path, capsys):
    from app.dual.paths import MAX_WAYPOINTS

    assert MAX_WAYPOINTS == 100_000
    out = tmp_path / "plan.json"
    for n in ("100000000", "100001"):
        assert_bad_input(capsys, ["plan-dual", "--path", f"sweep:{n}", "--no-compile", "--out", str(out)],
                         f"sweep:{n}", "more than the limit of 100000")
    assert not out.exists()


def test_plan_dual_refuses_a_path_file_above_the_waypoint_limit(tmp_path, capsys, monkeypatch):
    import app.dual.paths as paths

    monkeypatch.setattr(paths, "MAX_WAYPOINTS", 2)
    path = tmp_path / "path.csv"
    path.write_text("x,y,z,qw,qx,qy,qz\n" + "0,0,0,1,0,0,0\n" * 3)
    out = tmp_path / "plan.json"
    assert_bad_input(capsys, ["plan-dual", "--path", str(path), "--no-compile", "--out", str(out)],
                     str(path), "3 poses is more than the limit of 2")
    assert not out.exists()


def test_predict_and_evaluate_check_the_model_robots_joint_limits(tmp_path, data, capsys):
    # no --robot: the model file records R1, the cell gives its limits (q3 of R1 stops short of 3 rad)
    joints = tmp_path / "q.csv"
    joints.write_text("q1,q2,q3,q4,q5,q6\n0,0,0,0,0,0\n0,0,3.0,0,0,0\n")
    out = tmp_path / "poses.csv"
    for extra in ([], ["--robot", "R1"]):
        assert_bad_input(capsys, ["predict", "--model", str(data / "m.json"), "--joints", str(joints),
                                  "--out", str(out), *extra], str(joints), "row 3", "'q3'", "joint limits")
    headerless = tmp_path / "q0.csv"
    headerless.write_text("0,0,0,0,0,0\n0,0,0,0,0,-6\n")
    assert_bad_input(capsys, ["predict", "--model", str(data / "m.yaml"), "--joints", str(headerless),
                              "--out", str(out)], "row 2", "'q6'", "joint limits")
    test = tmp_path / "test.csv"
    test.write_text("q1,q2,q3,q4,q5,q6,x,y,z,qw,qx,qy,qz\n0,0,3.0,0,0,0,1,2,3,1,0,0,0\n")
    js = tmp_path / "eval.json"
    assert_bad_input(capsys, ["evaluate", "--model", str(data / "m.json"), "--test", str(test), "--json", str(js)],
                     str(test), "row 2", "'q3'", "joint limits")
    assert not out.exists() and not js.exists()


def test_input_paths_that_are_folders_are_one_line_errors(tmp_path, data, capsys):
    folder = tmp_path / "folder"
    folder.mkdir()
    out = tmp_path / "out"
    out.mkdir()
    m, train = str(data / "m.json"), str(data / "train.csv")
    cases = [
        (["predict", "--model", m, "--joints", str(folder), "--out", str(out / "p.csv")], "is a folder"),
        (["predict", "--model", str(folder), "--joints", str(data / "q.csv"), "--out", str(out / "p.csv")],
         "is a folder"),
        (["evaluate", "--model", m, "--test", str(folder)], "folder has neither"),
        (["fit", "--robot", "R1", "--train", str(folder), "--method", "base", "--out", str(out / "m.yaml")],
         "folder has neither"),
        (["fit", "--robot", "R1", "--train", train, "--cpa", str(folder), "--method", "base",
          "--out", str(out / "m.yaml")], "folder has neither"),
        (["export-targets", "--plan", str(folder), "--out", str(out / "t.csv")], "is a folder"),
        (["preview", "--plan", str(folder), "--html", str(out / "p.html")], "is a folder"),
        (["collect", "--robot", "R1", "--plan", str(folder), "--session", str(out / "s"), "--sim", "--dry-run"],
         "is a folder"),
        (["compensate-job", "--model", m, "--job", str(folder), "--out", str(out / "j.JBI")], "directory"),
        (["--cell", str(folder), "fit", "--robot", "R1", "--train", train, "--method", "base",
          "--out", str(out / "m.yaml")], "directory"),
    ]
    for argv, reason in cases:
        assert_bad_input(capsys, argv, str(folder), reason)
    assert list(out.iterdir()) == []


def test_a_robot_yaml_with_a_text_payload_is_a_one_line_error(tmp_path, data, capsys):
    import shutil

    from cell_config.loader import DEFAULT_CELL

    cell = tmp_path / "cell"
    shutil.copytree(DEFAULT_CELL.parent, cell)
    robot = cell / "robots" / "MA1440.yaml"
    robot.write_text(robot.read_text().replace("payload_kg: 6.0", "payload_kg: heavy"))
    out = tmp_path / "m.yaml"
    assert_bad_input(capsys, ["--cell", str(cell / "cell.yaml"), "fit", "--robot", "R1", "--train",
                              str(data / "train.csv"), "--method", "base", "--out", str(out)],
                     str(robot), "payload_kg", "'heavy'")
    assert not out.exists()


def test_absurd_and_underscored_numbers_are_refused_by_fit_and_predict(tmp_path, data, capsys):
    lines = (data / "train.csv").read_text().splitlines()
    header = lines[0].split(",")
    out = tmp_path / "m.yaml"
    for col, value, reason in (("x", "1e300", "physically absurd"), ("q2", "1_000", "not a number: '1_000'")):
        row = lines[1].split(",")
        row[header.index(col)] = value
        train = tmp_path / f"train-{col}.csv"
        train.write_text("\n".join([lines[0], ",".join(row)] + lines[2:]) + "\n")
        assert_bad_input(capsys, ["fit", "--robot", "R1", "--train", str(train), "--method", "base",
                                  "--out", str(out)], str(train), "row 2", f"'{col}'", reason)
    joints = tmp_path / "q.csv"
    joints.write_text("0,0,0,0,0,0\n1e300,0,0,0,0,0\n")
    poses = tmp_path / "poses.csv"
    assert_bad_input(capsys, ["predict", "--model", str(data / "m.json"), "--joints", str(joints),
                              "--out", str(poses)], str(joints), "row 2", "'q1'", "physically absurd")
    assert not out.exists() and not poses.exists()


def test_plan_dual_poses_refuse_absurd_and_underscored_numbers(tmp_path, capsys):
    out = tmp_path / "plan.json"
    assert_bad_input(capsys, ["plan-dual", "--relative-pose", "0,0,1e300,1,0,0,0", "--no-compile",
                              "--out", str(out)], "physically absurd")
    assert_bad_input(capsys, ["plan-dual", "--relative-pose", "0,0,1_00,1,0,0,0", "--no-compile",
                              "--out", str(out)], "7 numbers")
    path = tmp_path / "path.csv"
    path.write_text("x,y,z,qw,qx,qy,qz\n0,0,0,1,0,0,0\n1e300,0,0,1,0,0,0\n")
    assert_bad_input(capsys, ["plan-dual", "--path", str(path), "--no-compile", "--out", str(out)],
                     str(path), "pose 1", "physically absurd")
    assert not out.exists()
