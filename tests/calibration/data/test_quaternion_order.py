"""A recording whose quaternions are stored x, y, z, w (Motive's order) under the spec's qw, qx, qy, qz columns is
refused naming the columns (issue 30, safety): it was accepted silently and gave a model 28 deg off."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from calibration.data.recording import Recording, check_quaternion_order, read_recording, write_recording
from calibration.errors import DataError
from calibration.models import ConstantModel, save_model
from cell_config import load_cell
from tests.conftest import R1_TEST, R1_TRAIN, assert_bad_input, cluster_design, measure, needs_shared_data


def _swapped(rec: Recording) -> Recording:
    """The same recording with x, y, z, w written where the spec wants w, x, y, z."""
    return Recording(rec.q, rec.p, rec.quat[:, [1, 2, 3, 0]], dict(rec.extra), rec.source)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    root = tmp_path_factory.mktemp("quat_order")
    nominal = load_cell().robot("R1").model()
    q, cluster = cluster_design(step_deg=30.0)
    rec = measure(nominal.fk, q, 0.05, 0.05, 1, cluster)
    write_recording(rec, root / "good.csv")
    write_recording(_swapped(rec), root / "xyzw.csv")
    save_model(ConstantModel("R1", "nls1", nominal, 27, {}), root / "r1.yaml")
    return root, nominal


def test_the_check_refuses_the_swapped_order_and_passes_the_right_one(files):
    root, nominal = files
    check_quaternion_order(read_recording(root / "good.csv"), nominal)
    with pytest.raises(DataError, match=r"column 'qw, qx, qy, qz': the quaternions look stored in x, y, z, w order"):
        check_quaternion_order(read_recording(root / "xyzw.csv"), nominal)


def test_a_tool_frame_off_by_a_constant_rotation_is_not_taken_for_a_swap(files):
    """The check is made up to a constant tool offset: a marker frame turned 30 deg on the tool still passes."""
    root, nominal = files
    from calibration.kinematics import so3

    rec = read_recording(root / "good.csv")
    turned = rec.R @ so3.exp(np.radians([30.0, -10.0, 5.0]))
    check_quaternion_order(Recording(rec.q, rec.p, so3.R_to_quat(turned), rec.extra, rec.source), nominal)


@pytest.mark.parametrize("command", ["fit", "evaluate", "diagnose", "rebase"])
def test_commands_refuse_a_swapped_recording_naming_the_columns(files, tmp_path, capsys, command):
    root, _ = files
    out = tmp_path / "out.yaml"
    argv = {"fit": ["fit", "--robot", "R1", "--method", "nls1", "--train", str(root / "xyzw.csv"), "--out", str(out)],
            "evaluate": ["evaluate", "--robot", "R1", "--model", str(root / "r1.yaml"), "--test",
                         str(root / "xyzw.csv"), "--json", str(out)],
            "diagnose": ["diagnose", "--robot", "R1", "--train", str(root / "xyzw.csv"), "--json", str(out)],
            "rebase": ["rebase", "--robot", "R1", "--model", str(root / "r1.yaml"), "--data", str(root / "xyzw.csv"),
                       "--out", str(out)]}[command]
    assert_bad_input(capsys, argv, "xyzw.csv", "qw, qx, qy, qz", "x, y, z, w order")
    assert not out.exists()


@needs_shared_data()
@pytest.mark.parametrize("folder", [R1_TRAIN, R1_TEST], ids=["PH_grad_data", "kinematic_raw_data"])
def test_the_0801_recordings_pass_and_their_swapped_copies_are_refused(tmp_path, capsys, folder):
    nominal = load_cell().robot("R1").model()
    check_quaternion_order(read_recording(folder), nominal)
    copy = tmp_path / "day"
    shutil.copytree(folder, copy)
    pose = next(copy.glob("*mocap_T_align.csv"))
    T = np.loadtxt(pose, delimiter=",")
    np.savetxt(pose, np.c_[T[:, :3], T[:, [4, 5, 6, 3]]], delimiter=",")
    with pytest.raises(DataError, match="x, y, z, w order"):
        check_quaternion_order(read_recording(copy), nominal)
    save_model(ConstantModel("R1", "nls1", nominal, 27, {}), tmp_path / "r1.yaml")
    assert_bad_input(capsys, ["evaluate", "--robot", "R1", "--model", str(tmp_path / "r1.yaml"), "--test", str(copy)],
                     f"{pose.name} columns 4-7", "x, y, z, w order")
