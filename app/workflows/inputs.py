"""Reading a workflow's input files against the arm they are for: recordings and model files.

A recording is checked against the arm's joint limits and its quaternion order against the arm's nominal model; a
model file against the arm it is given for (its recorded robot and its geometry). The commands and the workflows
read their inputs through these, so a bad file is the same one line whoever reads it.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from calibration.data.recording import (
    Recording,
    check_quaternion_order,
    read_recording,
    welding_layout,
    with_added,
)
from calibration.errors import CellCalError
from calibration.frames.policy import refuse_another_arms
from calibration.models import KinematicModel, load_model

__all__ = ["load_model_for", "read_given", "read_recording_for", "with_added_poses"]


def read_recording_for(path: str, robot: Any | None = None) -> Recording:
    """A recording (CSV or Welding_Motoman folder), checked against ``robot``'s joint limits when given, and its
    quaternion order against ``robot``'s nominal model (:func:`calibration.data.recording.check_quaternion_order`).

    Args:
        path: the recording.
        robot: the arm's cell entry (:meth:`cell_config.loader.CellSpec.robot`), or None for no checks.
    """
    if robot is None:
        return read_recording(path)
    rec = read_recording(path, robot.robot.lower_rad, robot.robot.upper_rad)
    check_quaternion_order(rec, robot.model(), _quaternion_columns(path))
    return rec


def read_given(path: str, robot: Any) -> Recording:
    """``--given TRAIN`` (the poses a top-up builds on): :func:`read_recording_for`, and refused when it is not
    ``robot``'s poses (:func:`calibration.frames.policy.refuse_another_arms`), as a training recording is: another
    arm's joint angles would make the design, and the predicted sigma, those of the wrong arm."""
    rec = read_recording_for(path, robot)
    refuse_another_arms(robot.arm(), rec, "--given recording")
    return rec


def _quaternion_columns(path: str) -> str:
    """How a recording names its quaternion columns: qw..qz, or a Welding_Motoman pose file's columns 4-7."""
    layout = welding_layout(path)
    return "qw, qx, qy, qz" if layout is None else f"{layout[1].name} columns 4-7"


def load_model_for(path: str, robot: Any) -> KinematicModel:
    """The model file ``path``, checked to be ``robot``'s (a cell entry): its recorded robot and its geometry.

    Raises:
        DataError: the file is unusable, or records another robot, or holds another robot type's geometry.
    """
    return load_model(path, robot.name, robot.model())


def with_added_poses(trains: Sequence[Recording], added: Sequence[str], weight: int, robot: Any) -> Recording:
    """The first training recording with the ``added`` pose files appended as stand-alone poses
    (:func:`calibration.data.recording.with_added`, ``--add``); unchanged without any.

    Raises:
        CellCalError: poses added to several training recordings (which day would they join?).
    """
    if not added:
        return trains[0]
    if len(trains) > 1:
        raise CellCalError(f"--add joins the poses to one training recording; {len(trains)} --train recordings given "
                           "(fit each day with its own --add, or add the poses to the day's recording)")
    return with_added(trains[0], [read_recording_for(path, robot) for path in added], weight=weight)
