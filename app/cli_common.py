"""Helpers shared by the ``cellcal`` subcommands: the cell, recordings, fitters and JSON outputs."""

from __future__ import annotations

import argparse
import json
from typing import Any


def cell_spec(args: argparse.Namespace) -> Any:
    """The cell of ``--cell``, or the packaged Motoman cell."""
    from cell_config import load_cell

    return load_cell(args.cell) if args.cell else load_cell()


def read_recording_arg(path: str, robot: Any | None = None) -> Any:
    """A recording (CSV or Welding_Motoman folder), checked against ``robot``'s joint limits when given."""
    from calibration.recording import read_recording

    if robot is None:
        return read_recording(path)
    return read_recording(path, robot.robot.lower_rad, robot.robot.upper_rad)


def fitter_from_args(args: argparse.Namespace) -> Any:
    """A Fitter for ``--robot``/``--train``/``--cpa``/``--a``, and the robot's cell entry."""
    from calibration.methods import FitOptions, Fitter

    robot = cell_spec(args).robot(args.robot)
    train = read_recording_arg(args.train, robot)
    cpa = read_recording_arg(args.cpa, robot) if args.cpa else None
    return Fitter(args.robot, robot.model(), train, FitOptions(a=args.a), cpa), robot


def write_json(path: str | None, data: dict[str, Any]) -> None:
    """Write ``data`` as JSON to ``path`` atomically; nothing when ``path`` is None."""
    if path:
        from calibration.files import atomic_write_text

        atomic_write_text(path, json.dumps(data, indent=1))
