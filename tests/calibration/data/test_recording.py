"""Recordings: both layouts read, and every bad input named by file, row and column."""

from pathlib import Path

import numpy as np
import pytest

from calibration.data.recording import FORMAT_DOC, read_joints, read_recording, write_recording
from calibration.errors import DataError
from tests.conftest import cluster_design, measure

HEADER = "q1,q2,q3,q4,q5,q6,x,y,z,qw,qx,qy,qz"
ROW = "0.1,0.2,0.3,0.4,0.5,0.6,1000,2,3,1,0,0,0"


def write(tmp_path, text, name="rec.csv"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_round_trip_with_extra_columns(tmp_path, synthetic_arm):
    _, _, truth = synthetic_arm
    q, cluster = cluster_design(step_deg=45.0)
    rec = measure(truth.fk, q, 0.02, 0.01, 0, cluster)
    path = tmp_path / "out.csv"
    write_recording(rec, path)
    back = read_recording(path)
    np.testing.assert_array_equal(back.q, rec.q)
    np.testing.assert_array_equal(back.p, rec.p)
    np.testing.assert_allclose(back.quat, rec.quat, atol=1e-15)
    np.testing.assert_array_equal(back.clusters(), cluster)


def test_welding_layout(tmp_path):
    folder = tmp_path / "run"
    folder.mkdir()
    (folder / "robot_q_align.csv").write_text("0.1,0.2,0.3,0.4,0.5,0.6\n0,0,0,0,0,0\n")
    (folder / "mocap_T_align.csv").write_text("1,2,3,1,0,0,0\n4,5,6,0,1,0,0\n")
    rec = read_recording(folder)
    assert len(rec) == 2
    np.testing.assert_array_equal(rec.p[1], [4, 5, 6])


@pytest.mark.parametrize("text, row, column, reason", [
    ("q1,q2,q3,q4,q5,q6,x,y,z,qw,qx,qy\n" + ROW[:-2], 1, "qz", "required column missing"),
    (HEADER + "\n" + ROW.replace("1000", "abc"), 2, "x", "not a number"),
    (HEADER + "\n" + ROW + "\n" + ROW.replace("1000", "nan"), 3, "x", "not a finite number"),
    (HEADER + "\n" + ROW.replace(",1,0,0,0", ",0.9,0,0,0"), 2, "qw..qz", "quaternion norm"),
    (HEADER + "\n" + ROW + ",7", 2, None, "expected 13 fields"),
    (HEADER, None, None, "no data rows"),
    (HEADER + ",t\n" + ROW + ",5\n" + ROW + ",5\n" + ROW + ",4.5", 4, "t", "time goes backwards (5 s, then 4.5 s)"),
])
def test_bad_recordings_are_named(tmp_path, text, row, column, reason):
    path = write(tmp_path, text)
    with pytest.raises(DataError) as e:
        read_recording(path)
    assert e.value.row == row and e.value.column == column
    assert reason in str(e.value) and str(path) in str(e.value)


def test_joint_limits_checked(tmp_path):
    path = write(tmp_path, HEADER + "\n" + ROW.replace("0.1,", "3.5,", 1))
    with pytest.raises(DataError, match="outside the joint limits") as e:
        read_recording(path, np.radians([-180] * 6), np.radians([180] * 6))
    assert e.value.column == "q1" and e.value.row == 2


def welding_folder(tmp_path, joints: str, poses: str = "1,2,3,1,0,0,0\n"):
    """A folder in the Welding_Motoman layout with these joint and pose rows."""
    folder = tmp_path / "run"
    folder.mkdir()
    (folder / "robot_q_align.csv").write_text(joints)
    (folder / "mocap_T_align.csv").write_text(poses)
    return folder


def test_welding_layout_row_count_mismatch(tmp_path):
    with pytest.raises(DataError, match="1 pose rows but robot_q_align.csv has 2"):
        read_recording(welding_folder(tmp_path, "0,0,0,0,0,0\n0,0,0,0,0,0\n"))


def test_read_joints_with_and_without_header(tmp_path):
    a = read_joints(write(tmp_path, "q1,q2,q3,q4,q5,q6\n0,1,2,3,4,5\n", "a.csv"))
    b = read_joints(write(tmp_path, "0,1,2,3,4,5\n", "b.csv"))
    np.testing.assert_array_equal(a, b)
    with pytest.raises(DataError, match="q6"):
        read_joints(write(tmp_path, "q1,q2,q3,q4,q5\n0,1,2,3,4\n", "c.csv"))
    with pytest.raises(DataError, match="expected 6 fields"):
        read_joints(write(tmp_path, "0,1,2\n", "d.csv"))


def test_missing_cluster_column_needs_whole_anchor_groups(tmp_path):
    path = write(tmp_path, HEADER + "\n" + ROW + "\n" + ROW)
    with pytest.raises(DataError, match="not a multiple"):
        read_recording(path).clusters()


def test_context_columns(tmp_path):
    head = HEADER + ",t,dir2,qd1,qd2,qd3,qd4,qd5,qd6,payload_kg"
    path = write(tmp_path, head + "\n" + ROW + ",1.5,-3,0.1,0.2,0.3,0.4,0.5,0.6,6\n")
    ctx = read_recording(path).context()
    assert set(ctx) == {"t", "dir2", "qd", "payload_kg"}
    assert ctx["dir2"].tolist() == [-1.0] and ctx["qd"].shape == (1, 6) and ctx["t"].tolist() == [1.5]


@pytest.mark.parametrize("text, row, column, reason", [
    (HEADER + "\n" + ROW.replace("1000", "1e300"), 2, "x", "physically absurd"),
    (HEADER + "\n" + ROW + "\n" + ROW.replace("0.1,", "-1e300,", 1), 3, "q1", "physically absurd"),
])
def test_absurd_values_are_named(tmp_path, text, row, column, reason):
    path = write(tmp_path, text)
    with pytest.raises(DataError) as e:
        read_recording(path)
    assert e.value.row == row and e.value.column == column
    assert reason in str(e.value) and str(path) in str(e.value)
    assert len(str(e.value)) < 200


def test_absurd_values_in_welding_layout_and_joint_files(tmp_path):
    folder = tmp_path / "run"
    folder.mkdir()
    (folder / "robot_q_align.csv").write_text("0.1,0.2,0.3,0.4,0.5,0.6\n")
    (folder / "mocap_T_align.csv").write_text("1,2,1e300,1,0,0,0\n")
    with pytest.raises(DataError, match="physically absurd") as e:
        read_recording(folder)
    assert e.value.row == 1 and e.value.column == "z"
    joints = write(tmp_path, "0.1,0.2,0.3,0.4,0.5,1e300\n", "q.csv")
    with pytest.raises(DataError, match="physically absurd") as e:
        read_joints(joints)
    assert e.value.row == 1 and e.value.column == "q6"


@pytest.mark.parametrize("text, row, column", [
    (HEADER + "\n" + ROW.replace("1000", "1_000"), 2, "x"),
    (HEADER + ",payload_kg\n" + ROW + ",1_0", 2, "payload_kg"),
])
def test_underscored_numbers_are_refused(tmp_path, text, row, column):
    path = write(tmp_path, text)
    with pytest.raises(DataError, match="not a number: '1_0") as e:
        read_recording(path)
    assert e.value.row == row and e.value.column == column and str(path) in str(e.value)
    joints = write(tmp_path, "q1,q2,q3,q4,q5,q6\n0.1,0.2,0.3,0.4,1_5,0\n", "q.csv")
    with pytest.raises(DataError, match="not a number") as e:
        read_joints(joints)
    assert e.value.row == 2 and e.value.column == "q5"


def test_utf8_bom_is_accepted(tmp_path):
    path = tmp_path / "rec.csv"
    path.write_bytes(b"\xef\xbb\xbf" + (HEADER + "\n" + ROW + "\n").encode())
    assert len(read_recording(path)) == 1
    joints = tmp_path / "q.csv"
    joints.write_bytes(b"\xef\xbb\xbfq1,q2,q3,q4,q5,q6\n0.1,0.2,0.3,0.4,0.5,0.6\n")
    np.testing.assert_array_equal(read_joints(joints), [[0.1, 0.2, 0.3, 0.4, 0.5, 0.6]])
    joints.write_bytes(b"\xef\xbb\xbf0.1,0.2,0.3,0.4,0.5,0.6\n")
    np.testing.assert_array_equal(read_joints(joints), [[0.1, 0.2, 0.3, 0.4, 0.5, 0.6]])


def test_unknown_columns_are_ignored(tmp_path):
    path = write(tmp_path, HEADER + ",operator,note,gain\n" + ROW + ",alice,1e300 and 1_000,2.5\n")
    rec = read_recording(path)
    assert len(rec) == 1 and "operator" not in rec.extra and "note" not in rec.extra
    np.testing.assert_array_equal(rec.extra["gain"], [2.5])  # numeric unknown columns still round-trip
    joints = write(tmp_path, "q1,q2,q3,q4,q5,q6,label\n0,0,0,0,0,0,home\n", "q.csv")
    np.testing.assert_array_equal(read_joints(joints), np.zeros((1, 6)))
    with pytest.raises(DataError, match="not a number") as e:  # known optional columns are still checked
        read_recording(write(tmp_path, HEADER + ",temp_c\n" + ROW + ",warm\n"))
    assert e.value.row == 2 and e.value.column == "temp_c"


def test_row_limit_refused_while_reading(tmp_path, monkeypatch):
    import calibration.data.recording as recording

    assert recording.MAX_ROWS == 200_000
    monkeypatch.setattr(recording, "MAX_ROWS", 3)
    assert len(read_recording(write(tmp_path, HEADER + "\n" + "\n".join([ROW] * 3) + "\n"))) == 3
    # the 5th row is never parsed: the file is refused as soon as the limit is passed
    path = write(tmp_path, HEADER + "\n" + "\n".join([ROW] * 4 + ["not,parsed"]) + "\n")
    with pytest.raises(DataError, match="more than 3 data rows") as e:
        read_recording(path)
    assert str(path) in str(e.value)
    folder = tmp_path / "run"
    folder.mkdir()
    (folder / "robot_q_align.csv").write_text("0,0,0,0,0,0\n" * 4)
    (folder / "mocap_T_align.csv").write_text("1,2,3,1,0,0,0\n" * 4)
    with pytest.raises(DataError, match="more than 3 data rows"):
        read_recording(folder)


def test_out_of_limit_messages_print_numbers_with_a_sane_precision(tmp_path, monkeypatch):
    import calibration.data.recording as recording
    from calibration.errors import UnsafeTarget

    monkeypatch.setattr(recording, "MAX_ABS_ANGLE_RAD", float("inf"))  # reach the limit check with 1e300
    lower, upper = np.full(6, -3.0), np.full(6, 3.0)
    path = write(tmp_path, HEADER + "\n" + ROW.replace("0.1,", "1e300,", 1))
    with pytest.raises(DataError, match=r"5\.72958e\+301 deg is outside the joint limits") as e:
        read_recording(path, lower, upper)
    assert len(str(e.value)) < 200
    with pytest.raises(DataError, match=r"-5\.72958e\+301 deg") as e:
        read_joints(write(tmp_path, "0,0,-1e300,0,0,0\n", "q.csv"), lower, upper)
    assert e.value.row == 1 and e.value.column == "q3" and len(str(e.value)) < 200
    msg = str(UnsafeTarget("R1", 2, 1e300, 3.0))
    assert "5.72958e+301 deg" in msg and "171.887 deg" in msg and len(msg) < 120


@pytest.mark.parametrize("sep, name", [(";", "';'"), ("\t", "tabs")])
def test_other_separator_is_named(tmp_path, sep, name):
    """A recording saved with ';' or tabs was one column to the comma reader: 'required column missing q1'."""
    path = write(tmp_path, (HEADER + "\n" + ROW + "\n").replace(",", sep))
    with pytest.raises(DataError) as e:
        read_recording(path)
    assert f"seems to be separated by {name}" in str(e.value) and "comma-separated" in str(e.value)
    assert str(path) in str(e.value) and e.value.row == 1 and "\n" not in str(e.value)
    # the page it points to is in the repository (it pointed to ../shared/spec, outside it)
    assert FORMAT_DOC in str(e.value) and (Path(__file__).resolve().parents[3] / FORMAT_DOC).is_file()
    for text in ("q1,q2,q3,q4,q5,q6\n0,1,2,3,4,5\n", "0,1,2,3,4,5\n"):  # joint files, with and without a header
        with pytest.raises(DataError, match=f"seems to be separated by {name}"):
            read_joints(write(tmp_path, text.replace(",", sep), "j.csv"))


@pytest.mark.parametrize("sep, name", [(";", "';'"), ("\t", "tabs")])
def test_other_separator_with_decimal_commas_is_named(tmp_path, sep, name):
    """A headerless joint file saved with ';' and decimal commas said only 'expected 6 fields, found 7'."""
    text = sep.join(["0,5", "1,25", "2", "3,5", "4", "5"]) + "\n"
    with pytest.raises(DataError) as e:
        read_joints(write(tmp_path, text, "j.csv"))
    msg = str(e.value)
    assert f"6 {'tab' if sep == chr(9) else chr(39) + ';' + chr(39)}-separated fields with decimal commas" in msg
    assert f"seems to be separated by {name}" in msg and "decimal points" in msg and e.value.row == 1
    assert FORMAT_DOC in msg
    assert "\n" not in msg
    # A comma file whose row merely has a wrong field count keeps the plain message
    with pytest.raises(DataError, match="expected 6 fields, found 7"):
        read_joints(write(tmp_path, "0,1,2,3,4,5\n0,1,2,3,4,5,6\n", "k.csv"))


def test_welding_layout_other_separator_is_named(tmp_path):
    with pytest.raises(DataError, match="robot_q_align.csv, row 1: .*separated by ';'"):
        read_recording(welding_folder(tmp_path, "0.1;0.2;0.3;0.4;0.5;0.6\n"))
