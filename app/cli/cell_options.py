"""Operator options shared by every command that moves an arm: where, how fast, with what margins, confirmed.

* ``--sim`` selects the simulated cell; without it the real devices are built from ``cell.yaml``
  (:class:`app.collection.runtime.real.RealCell`).
* ``--speed`` is a fraction of the maximum joint speeds, refused (not clamped) above the cell's cap
  (``controller.max_speed_fraction``).
* Joint margins come from the cell file (``controller.joint_margin_deg``) on the real cell.
* ``--dry-run`` runs every check and prints the plan's summary without moving.
* Before the first motion on real hardware the operator confirms (``--yes`` skips the question; with no
  terminal to ask on, the command stops instead of moving).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from dataclasses import replace
from typing import TYPE_CHECKING, Any

from app.cli.common import non_negative_int
from calibration.errors import CellCalError

if TYPE_CHECKING:
    from app.collection.runtime.cell import Cell

#: Speed fraction used when --speed is not given (and the cap allows it).
DEFAULT_SPEED = 0.2
#: Largest ``--time-scale`` of the simulated cell: beyond it the paced sleeps are already negligible next to the
#: waits for Zenoh (and ``inf`` would make the bridge's timeouts infinite).
MAX_TIME_SCALE = 1000.0


def checked_time_scale(value: float) -> float:
    """``--time-scale`` when it is in (0, MAX_TIME_SCALE]; raises CellCalError naming the value otherwise."""
    if not 0.0 < value <= MAX_TIME_SCALE:
        raise CellCalError(f"--time-scale must be in (0, {MAX_TIME_SCALE:g}] simulated seconds per real second, "
                           f"got {value:g}")
    return value


class NotConfirmed(CellCalError):
    """The operator did not confirm the motion; nothing moved."""


def add_motion_options(p: argparse.ArgumentParser) -> None:
    """Add ``--sim``, ``--seed``, ``--time-scale``, ``--speed``, ``--dry-run``, ``--yes`` and ``--no-progress``."""
    p.add_argument("--sim", action="store_true",
                   help="use the simulated arms and mocap (over Zenoh on loopback) instead of the real devices "
                        "named in the cell file")
    p.add_argument("--seed", type=non_negative_int, default=0, help="seed of the simulated cell (its planted errors); --sim only")
    p.add_argument("--time-scale", type=float, default=20.0, help="simulated seconds per real second; --sim only")
    p.add_argument("--speed", type=float, help=f"fraction of the maximum joint speeds (default {DEFAULT_SPEED}, or "
                                               "the cell's cap if lower); refused above the cell's cap")
    p.add_argument("--dry-run", action="store_true", help="run every check and print the plan; no motion")
    p.add_argument("--yes", action="store_true", help="do not ask for confirmation before the first real motion")
    p.add_argument("--reset-alarms", action="store_true",
                   help="let the controller reset a standing alarm when motion starts (MotoROS's START_TRAJ_MODE "
                        "does); without it a standing alarm refuses motion until it is cleared on the pendant")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")


def speed_cap(cell: Any, args: argparse.Namespace) -> float:
    """The largest speed fraction allowed: the controller's cap on the real cell, 1 in simulation."""
    if args.sim or cell.controller is None:
        return 1.0
    return float(cell.controller.max_speed_fraction)


def speed_fraction(cell: Any, args: argparse.Namespace, default: float = DEFAULT_SPEED) -> float:
    """The speed fraction to move at.

    Raises:
        CellCalError: ``--speed`` is not in (0, 1] or above the cell's cap (never silently clamped).
    """
    cap = speed_cap(cell, args)
    speed = getattr(args, "speed", None)
    if speed is None:
        return min(default, cap)
    if not 0.0 < speed <= 1.0:
        raise CellCalError(f"--speed must be in (0, 1], got {speed:g}")
    if speed > cap:
        raise CellCalError(f"--speed {speed:g} is above the cell's cap controller.max_speed_fraction = {cap:g} "
                           f"({cell.path}); raise the cap in the cell file to go faster")
    return float(speed)


def motion_config(cell: Any, args: argparse.Namespace, base: Any = None) -> Any:
    """The collection options (:class:`~app.collection.collect.CollectConfig`) with the chosen speed; on the real cell
    with the cell file's dwell window (``mocap.dwell_s``) when it names one."""
    from app.collection.collect import DEMO_COLLECT, CollectConfig

    if base is None:
        base = DEMO_COLLECT if args.sim else CollectConfig()
    if not args.sim and cell.mocap is not None and cell.mocap.dwell_s is not None:
        base = replace(base, dwell_s=cell.mocap.dwell_s)
    return replace(base, speed_fraction=speed_fraction(cell, args, base.speed_fraction if args.sim else DEFAULT_SPEED))


def safety_for(cell: Any, args: argparse.Namespace) -> Any:
    """The cell's safety checker; on the real cell with the joint margin of the cell file."""
    from app.collection.safety import CellSafety, SafetyConfig

    if args.sim or cell.controller is None:
        return CellSafety(cell)
    return CellSafety(cell, SafetyConfig(joint_margin_deg=float(cell.controller.joint_margin_deg)))


def confirm_motion(args: argparse.Namespace, summary: str) -> None:
    """Ask the operator before the first motion on real hardware (not with ``--sim`` or ``--yes``).

    Raises:
        NotConfirmed: the answer was not ``yes``, or there is no terminal to ask on.
    """
    if args.sim or args.yes:
        return
    if not sys.stdin.isatty():
        raise NotConfirmed(f"real motion needs confirmation: {summary}; no terminal to ask on, pass --yes to "
                           "confirm (or --dry-run to check only)")
    answer = input(f"{summary}.\nThe arms will move. Type 'yes' to start: ").strip().lower()
    if answer != "yes":
        raise NotConfirmed("not confirmed; nothing moved")


def open_runtime(cell: Any, args: argparse.Namespace, robots: Sequence[str] | None = None, *,
                 registered: bool = True) -> Cell:
    """The cell runtime to use: a SimCell with ``--sim``, else the real devices of the cell file (not yet open).

    With ``registered=False`` the mocap reads the mocap world (registration): the simulated cell then reports
    its markers in a hidden world frame derived from ``--seed``, as a real Motive does.
    """
    if args.sim:
        from app.collection.runtime.sim import SimCell, SimCellOptions

        return SimCell(cell, SimCellOptions(time_scale=checked_time_scale(args.time_scale), seed=args.seed, mocap_world=not registered,
                                            deterministic=True))  # the same --seed measures the same values
    from app.collection.runtime.real import RealCell

    return RealCell(cell, robots, registered=registered, reset_alarms=args.reset_alarms)
