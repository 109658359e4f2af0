"""Controller targets from a dual plan: joint angles, encoder pulses and "filtered" nominal poses.

Rows are written as CSV (one line per waypoint and robot) or JSON, and optionally as an INFORM job (``.JBI``) of
joint moves in pulses; an unsolved waypoint or a joint beyond its limit refuses the whole export before anything
is written.

The job (``export-targets --jbi``) is written by :mod:`app.jobs.plan_job` from the same rows.
"""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from app.collection.plan_safety import check_plan_safe
from app.collection.plans.dual import PlanResult
from app.collection.plans.reader import read_plan
from calibration.data.files import atomic_write_text
from calibration.errors import DataError, ModelError, UnsafeTarget
from cell_config.loader import CellSpec


def rpy_deg(R: np.ndarray) -> np.ndarray:
    """Yaskawa fixed-axis angles ``(Rx, Ry, Rz)`` [deg] with ``R = Rz @ Ry @ Rx``, shape (..., 3)."""
    rx = np.arctan2(R[..., 2, 1], R[..., 2, 2])
    ry = np.arctan2(-R[..., 2, 0], np.hypot(R[..., 0, 0], R[..., 1, 0]))
    rz = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    rpy: np.ndarray = np.degrees(np.stack([rx, ry, rz], axis=-1))
    return rpy


def R_from_rpy_deg(rpy: np.ndarray) -> np.ndarray:
    """Inverse of :func:`rpy_deg`: ``R = Rz @ Ry @ Rx`` from Yaskawa's ``(Rx, Ry, Rz)`` [deg], shape (..., 3, 3)."""
    rx, ry, rz = np.moveaxis(np.radians(np.asarray(rpy, dtype=float)), -1, 0)
    cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
    rows = [[cz * cy, cz * sy * sx - sz * cx, cz * sy * cx + sz * sx],
            [sz * cy, sz * sy * sx + cz * cx, sz * sy * cx - cz * sx],
            [-sy, cy * sx, cy * cx]]
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


def export_rows(plan: PlanResult, cell: CellSpec, frame: str = "flange", skip_failed: bool = False
                ) -> list[dict[str, Any]]:
    """Controller targets of a plan: joint angles, encoder pulses and "filtered" nominal poses.

    The pose of each row is what the controller's nominal kinematics gives at the planned q, in the robot's
    base frame: sent as a Cartesian target, the controller's inverse kinematics returns the planned q, so the
    real arm lands where the calibrated model says (the program is filtered through the model).

    Args:
        plan: a planned sequence.
        cell: gives pulses per radian, limits and the nominal geometry.
        frame: ``"flange"`` (tool 0 of the controller) or ``"tool"`` (the cell's tool marker frame).
        skip_failed: leave out waypoints that did not converge instead of refusing the export.

    Returns:
        One dict per (waypoint, robot): ``index, robot, q_rad (6), pulses (6), p_mm (3), rpy_deg (3)``.

    Raises:
        UnsafeTarget: a waypoint did not converge (unless ``skip_failed``) or is outside the joint limits.
        ModelError: unknown frame.
    """
    if frame not in ("flange", "tool"):
        raise ModelError(f"unknown frame {frame!r}; valid: flange, tool")
    rows: list[dict[str, Any]] = []
    for i, w in enumerate(plan.waypoints):
        if not w.converged:
            if skip_failed:
                continue
            raise UnsafeTarget("R1+R2", None, w.clearance_mm, 0.0, f"waypoint {i} was not solved: {w.reason}")
        for name, q in (("R1", w.q_R1), ("R2", w.q_R2)):
            spec = cell.robot(name)
            bad = np.flatnonzero((q < spec.robot.lower_rad) | (q > spec.robot.upper_rad))
            if bad.size:
                j = int(bad[0])
                lim = spec.robot.lower_rad[j] if q[j] < spec.robot.lower_rad[j] else spec.robot.upper_rad[j]
                raise UnsafeTarget(name, j + 1, float(q[j]), float(lim), f"waypoint {i}")
            nominal = spec.robot.model(spec.tool if frame == "tool" else None)
            R, p = nominal.fk(q[None])
            rows.append({"index": i, "robot": name, "q_rad": q.tolist(),
                         "pulses": spec.robot.to_pulses(q).tolist(),
                         "p_mm": p[0].tolist(), "rpy_deg": rpy_deg(R[0]).tolist()})
    return rows


def write_targets(rows: list[dict[str, Any]], path: str | Path, frame: str = "flange") -> None:
    """Write export rows as CSV (one line per waypoint and robot) or JSON (by suffix), atomically."""
    path = Path(path)
    if path.suffix.lower() == ".json":
        atomic_write_text(path, json.dumps({"schema": "cellcal.targets/1", "frame": frame, "rows": rows}, indent=1))
        return
    if path.suffix.lower() != ".csv":
        raise ModelError(f"unknown target file type {path.suffix!r}; valid: .csv, .json")
    buf = io.StringIO()
    wr = csv.writer(buf, lineterminator="\n")
    wr.writerow(["index", "robot"] + [f"q{j}_rad" for j in range(1, 7)] + [f"pulse{j}" for j in range(1, 7)]
                + ["x_mm", "y_mm", "z_mm", "rx_deg", "ry_deg", "rz_deg"])
    for r in rows:
        wr.writerow([r["index"], r["robot"]] + [repr(v) for v in r["q_rad"]] + r["pulses"]
                    + [f"{v:.4f}" for v in r["p_mm"] + r["rpy_deg"]])
    atomic_write_text(path, buf.getvalue())


def checked_rows(plan: PlanResult | str | Path, cell: CellSpec, frame: str = "flange", skip_failed: bool = False,
                 models: Mapping[str, Any] | None = None) -> list[dict[str, Any]]:
    """The rows of :func:`export_rows` of a plan (object or plan file) that passed
    :func:`app.collection.plan_safety.check_plan_safe` (see :func:`export_targets` for the checks and errors)."""
    source = "<plan>" if isinstance(plan, PlanResult) else str(plan)
    if not isinstance(plan, PlanResult):
        plan = read_plan(plan, "dual")
    check_plan_safe(cell, plan, source, models=models, skip_failed=skip_failed)
    rows = export_rows(plan, cell, frame, skip_failed)
    if not rows:  # a header-only target file, exit 0, read as a job with nothing to do
        raise DataError(source, None, None, "no targets to export: the plan has no waypoints" if not plan.waypoints
                        else f"no targets to export: none of its {len(plan.waypoints)} waypoints was solved")
    return rows


def export_targets(plan: PlanResult | str | Path, cell: CellSpec, out: str | Path, frame: str = "flange",
                   skip_failed: bool = False, models: Mapping[str, Any] | None = None) -> int:
    """Export a plan (object or plan file) as controller targets to ``out`` (.csv or .json).

    The plan must first pass :func:`app.collection.plan_safety.check_plan_safe`, the checks plan-dual made when it
    solved it (clearances and floor along every move, the step between waypoints, the relative pose recomputed
    from ``models``, the nominal ones for a robot not given), so a plan edited since cannot leave unchecked.

    Returns:
        The number of rows written (waypoints x 2 robots).

    Raises:
        UnsafeTarget: an unsolved waypoint (unless ``skip_failed``), a joint beyond its limit, or any defect of
            :func:`~app.collection.plan_safety.check_plan_safe` (an :class:`~app.collection.plan_safety.UnsafePlan` naming the
            waypoint); nothing is written.
        DataError, ModelError: unreadable plan, nothing to export (no waypoints, or none solved with
            ``skip_failed``), unknown frame or file type.
    """
    if Path(out).suffix.lower() not in (".csv", ".json"):
        raise ModelError(f"unknown target file type {Path(out).suffix!r}; valid: .csv, .json")
    rows = checked_rows(plan, cell, frame, skip_failed, models)
    write_targets(rows, out, frame)
    return len(rows)
