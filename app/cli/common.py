"""Helpers shared by the ``cellcal`` subcommands: the cell, recordings, fitters from arguments and JSON outputs."""

from __future__ import annotations

import argparse
import json
import logging
from typing import Any

log = logging.getLogger("cellcal.app")


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


def load_model_for(path: str, robot: Any) -> Any:
    """The model file ``path``, checked to be ``robot``'s (a cell entry): its recorded robot and its geometry.

    Raises:
        DataError: the file is unusable, or records another robot, or holds another robot type's geometry.
    """
    from calibration.models import load_model

    return load_model(path, robot.name, robot.model())


def fitter_from_args(args: argparse.Namespace) -> Any:
    """A Fitter for ``--robot``/``--train``/``--cpa``/``--a``, and the robot's cell entry."""
    from app.analysis.fitting import fitter_for
    from calibration.methods import FitOptions

    robot = cell_spec(args).robot(args.robot)
    train = read_recording_arg(args.train, robot)
    cpa = read_recording_arg(args.cpa, robot) if args.cpa else None
    return fitter_for(robot, train, cpa, FitOptions(a=args.a, epoch_progress=epoch_bar(args))), robot


#: File outputs every subcommand may take; ``demo --out`` is a folder and is left to the demo.
OUTPUT_FILE_OPTIONS = ("out", "json", "html")


def check_output_args(args: argparse.Namespace) -> None:
    """Refuse an empty, symlink, device, FIFO or folder output path before any work, so nothing is written.

    Raises:
        OutputError: the first such ``--out``/``--json``/``--html`` path.
    """
    from calibration.files import check_output_path

    for name in OUTPUT_FILE_OPTIONS:
        value = getattr(args, name, None)
        if isinstance(value, str) and not (name == "out" and args.command == "demo"):
            check_output_path(value)


def show_progress(args: argparse.Namespace) -> bool:
    """Whether this command shows progress bars: the CLI's policy (a terminal, no ``--quiet``) and no
    ``--no-progress``."""
    from app.progress import enabled

    return enabled() and not getattr(args, "no_progress", False)


def epoch_bar(args: argparse.Namespace) -> Any:
    """The training-epoch bar of the neural interpolators (``FitOptions.epoch_progress``), or None without bars."""
    if not show_progress(args):
        return None
    from app.progress import EpochBar

    return EpochBar("nn/ae training")


def write_json(path: str | None, data: dict[str, Any]) -> None:
    """Write ``data`` as JSON to ``path`` atomically; nothing when ``path`` is None."""
    if path:
        from calibration.files import atomic_write_text

        atomic_write_text(path, json.dumps(data, indent=1))
