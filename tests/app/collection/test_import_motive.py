"""``cellcal import-motive``: a synthetic take in Motive's CSV export layout (header rows, scalar-last quaternions,
metres or millimetres, an occluded frame, other assets around) becomes the recording of the poses it holds;
bad input is one line, exit 2, nothing written."""

from __future__ import annotations

import csv
import io
import json

import numpy as np
import pytest

from app.cli.commands import main
from calibration.data.recording import read_recording
from calibration.kinematics import so3
from cell_config import load_cell
from tests.conftest import assert_bad_input

FPS = 120.0
FRAMES_PER_POSE = 12


def rigid(R, p):
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, p
    return T


def take(tmp_path, unit: str = "Meters", n_poses: int = 5, seed: int = 0, parent_row: bool = False):
    """A Motive CSV of R1's marker at ``n_poses`` static poses (Motive's world frame: Y up, R1's base placed in it),
    with a second rigid body and a marker column; returns (motive path, joints path, q, T_world_marker)."""
    cell = load_cell()
    robot = cell.robot("R1")
    rng = np.random.default_rng(seed)
    lo, hi = robot.robot.lower_rad * 0.5, robot.robot.upper_rad * 0.5
    q = rng.uniform(lo, hi, (n_poses, 6))
    R, p = robot.model().fk(q)
    T_world_base = rigid(so3.exp(np.array([-np.pi / 2, 0, 0])), np.array([500.0, 100.0, -2000.0]))  # z up -> y up
    T = T_world_base @ np.array([rigid(Rk, pk) for Rk, pk in zip(R, p)])
    scale = {"Meters": 1e-3, "Millimeters": 1.0}[unit]
    rows = [["Format Version", "1.23", "Take Name", "Take 2026-12-04", "Capture Frame Rate", "120.000000",
             "Rotation Type", "Quaternion", "Length Units", unit, "Coordinate Space", "Global"], []]
    types = ["", "Type", "Rigid Body", "Rigid Body", "Rigid Body", "Rigid Body", "Rigid Body", "Rigid Body",
             "Rigid Body", "Rigid Body", "Marker", "Marker", "Marker"] + ["Rigid Body"] * 7
    names = ["", "Name"] + ["mti"] * 8 + ["weldgun:Marker1"] * 3 + ["weldgun"] * 7
    ids = ["", "ID"] + ["2"] * 8 + ["1"] * 3 + ["1"] * 7
    kinds = ["", ""] + ["Rotation"] * 4 + ["Position"] * 3 + ["Mean Marker Error"] + ["Position"] * 3 \
        + ["Position"] * 3 + ["Rotation"] * 4  # weldgun's position before its rotation: found by label
    axes = ["Frame", "Time (Seconds)", "X", "Y", "Z", "W", "X", "Y", "Z", "", "X", "Y", "Z", "X", "Y", "Z",
            "X", "Y", "Z", "W"]
    rows += [types, names, ids] + ([["", "Parent"] + [""] * 18] if parent_row else []) + [kinds, axes]
    windows, frame = [], 0
    noise = np.random.default_rng(seed + 1)
    for k in range(n_poses):
        start = frame
        quat = so3.R_to_quat(T[k, :3, :3])  # w, x, y, z
        if k % 2:
            quat = -quat  # Motive may give either sign
        for f in range(FRAMES_PER_POSE + 6):  # 6 frames of motion to the next pose, outside the window
            t = frame / FPS
            pos = (T[k, :3, 3] + noise.normal(0, 0.01, 3)) * scale
            body = [f"{v:.9f}" for v in (*quat[[1, 2, 3, 0]], *pos)]
            if f == 3 and k == 1:
                body = [""] * 7  # occluded
            moving = f >= FRAMES_PER_POSE
            if moving:
                body = [f"{v:.6f}" for v in (*(pos * 1.5), 0.1, 0.2, 0.3, 0.927)]
            rows.append([str(frame), f"{t:.6f}"] + ["0.0", "0.0", "0.0", "1.0", "0.1", "0.2", "0.3", "0.0001"]
                        + ["0.5", "0.5", "0.5"] + body[4:] + body[:4])
            frame += 1
        windows.append(((start - 0.5) / FPS, (start + FRAMES_PER_POSE - 0.5) / FPS))
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\r\n").writerows(rows)
    motive = tmp_path / "take.csv"
    motive.write_text(buf.getvalue())
    joints = tmp_path / "joints.csv"
    table = ["q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,t_start_s,t_end_s"]
    table += [",".join([repr(float(v)) for v in np.degrees(q[k])] + [repr(w) for w in windows[k]])
              for k in range(n_poses)]
    joints.write_text("\n".join(table) + "\n")
    return motive, joints, q, T


@pytest.mark.parametrize("unit", ["Meters", "Millimeters"])
@pytest.mark.parametrize("parent_row", [False, True])
def test_import_motive_gives_the_poses_of_the_take(tmp_path, capsys, unit, parent_row):
    motive, joints, q, T = take(tmp_path, unit, parent_row=parent_row)
    out, js = tmp_path / "rec.csv", tmp_path / "i.json"
    assert main(["import-motive", "--robot", "R1", "--motive", str(motive), "--joints", str(joints), "--out",
                 str(out), "--json", str(js)]) == 0
    assert "5 poses of R1 ('weldgun', 11-12 frames each)" in capsys.readouterr().out
    rec = read_recording(out)
    np.testing.assert_allclose(rec.q, q, atol=1e-12)
    np.testing.assert_allclose(rec.p, T[:, :3, 3], atol=0.02)  # 0.01 mm noise averaged over 11-12 frames
    np.testing.assert_allclose(rec.R, T[:, :3, :3], atol=1e-7)
    assert rec.extra["frames"].tolist() == [12, 11, 12, 12, 12]
    assert json.loads(js.read_text())["poses"] == 5


def test_a_scalar_first_misreading_would_be_caught(tmp_path):
    """The converter's order matters: read as w, x, y, z the take's quaternions do not fit the arm."""
    from app.collection.motive_import import read_motive_csv

    motive, _, _, T = take(tmp_path)
    body = read_motive_csv(motive, "weldgun")
    ok = np.isfinite(body.quat_wxyz).all(axis=1)
    R = so3.quat_to_R(body.quat_wxyz[ok][:12])
    np.testing.assert_allclose(R, np.broadcast_to(T[0, :3, :3], R.shape), atol=1e-7)
    wrong = so3.quat_to_R(body.quat_wxyz[ok][:12][:, [1, 2, 3, 0]])
    assert np.abs(wrong - T[0, :3, :3]).max() > 0.1


@pytest.mark.parametrize(("edit", "fragments"), [
    (lambda m, j: m.write_text(m.read_text().replace("Quaternion", "XYZ")), ("Rotation Type", "Quaternion")),
    (lambda m, j: m.write_text(m.read_text().replace("Meters", "Feet")), ("Length Units", "'Feet'")),
    (lambda m, j: m.write_text(m.read_text().replace("weldgun", "gun")), ("no rigid body 'weldgun'", "gun, mti")),
    (lambda m, j: m.write_text("Frame,Time\n0,0\n"), ("take.csv", "not a Motive CSV export")),
    (lambda m, j: j.write_text(j.read_text().replace("t_end_s", "t_stop")), ("joints.csv", "t_end_s", "missing")),
    (lambda m, j: j.write_text(j.read_text().replace(",", ",x", 1)), ("joints.csv", "row 1")),
    (lambda m, j: j.write_text(j.read_text() + "0,0,0,0,0,0,100,101\n"), ("joints.csv", "row 7", "0 tracked frames")),
    (lambda m, j: j.write_text(j.read_text() + "0,170,0,0,0,0,0,0.05\n"), ("joints.csv", "row 7", "q2", "outside")),
])
def test_bad_input_is_one_line_and_nothing_written(tmp_path, capsys, edit, fragments):
    motive, joints, _, _ = take(tmp_path)
    edit(motive, joints)
    out = tmp_path / "rec.csv"
    assert_bad_input(capsys, ["import-motive", "--robot", "R1", "--motive", str(motive), "--joints", str(joints),
                              "--out", str(out)], *fragments)
    assert not out.exists()


@pytest.mark.parametrize(("which", "content", "fragment"), [
    ("motive", None, "file not found"),
    ("joints", None, "file not found"),
    ("motive", "folder", "is a folder"),
    ("joints", "folder", "is a folder"),
    ("motive", b"\x94\xff\x00binary", "not UTF-8 text"),
    ("joints", b"\x94\xff\x00binary", "not UTF-8 text"),
    ("joints", b"q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,t_start_s,t_end_s\n", "no poses"),
])
def test_an_unreadable_input_file_is_one_line_naming_it(tmp_path, capsys, which, content, fragment):
    """Missing, a folder, binary, or a joint file with no rows: one line naming the file, not a traceback."""
    files = dict(zip(("motive", "joints"), take(tmp_path)[:2]))
    bad = tmp_path / "bad.csv"
    if content == "folder":
        bad.mkdir()
    elif content is not None:
        bad.write_bytes(content)
    files[which] = bad
    out = tmp_path / "rec.csv"
    assert_bad_input(capsys, ["import-motive", "--robot", "R1", "--motive", str(files["motive"]), "--joints",
                              str(files["joints"]), "--out", str(out)], "bad.csv", fragment)
    assert not out.exists()


def test_min_frames_0_still_refuses_a_window_without_frames(tmp_path, capsys):
    motive, joints, _, _ = take(tmp_path)
    joints.write_text(joints.read_text() + "0,0,0,0,0,0,100,101\n")
    out = tmp_path / "rec.csv"
    assert_bad_input(capsys, ["import-motive", "--robot", "R1", "--motive", str(motive), "--joints", str(joints),
                              "--out", str(out), "--min-frames", "0"], "joints.csv", "row 7", "0 tracked frames")
    assert not out.exists()


@pytest.mark.parametrize("cells", [{-1: "0", -2: "0", -3: "0", -4: "0"}, {-1: "1e300"}, {-5: "1e300"}])
def test_a_frame_that_is_no_tracked_pose_is_one_line_naming_the_window(tmp_path, capsys, cells):
    """A zero quaternion, a huge one, or a position beyond any volume in a window's frame: refused (a zero one was
    averaged into the pose; 1e300 gave a LinAlgError traceback)."""
    motive, joints, _, _ = take(tmp_path)
    with open(motive, newline="") as f:
        rows = list(csv.reader(f))
    for c, text in cells.items():
        rows[9][c] = text  # frame 2: inside the first pose's window
    with open(motive, "w", newline="") as f:
        csv.writer(f).writerows(rows)
    out = tmp_path / "rec.csv"
    assert_bad_input(capsys, ["import-motive", "--robot", "R1", "--motive", str(motive), "--joints", str(joints),
                              "--out", str(out)], "joints.csv", "row 2", "not a tracked pose")
    assert not out.exists()
