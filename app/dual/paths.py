"""Paths for the dual-robot planner: the cell's reference configuration, tool poses, the default sweep, and
the relative pose and path files ``cellcal plan-dual`` reads (poses as x, y, z [mm] + unit quaternion w, x, y, z).

``plan_dual`` is the one-call entry point ``cellcal plan-dual`` runs: build the planner for two models, hold
a relative pose (the reference one by default) along a path of workpiece poses (the inward-to-outstretched
sweep by default).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from app.collection.plans.dual import PlanResult
from app.dual.planner import DualPlanner, PlannerOptions
from calibration.data.files import read_input_text
from calibration.data.recording import MAX_ABS_POSITION_MM
from calibration.errors import DataError, ModelError
from calibration.kinematics import so3
from cell_config.loader import CellSpec

#: Reference configuration of the cell [deg]: tools about 410 mm apart, facing, 300 mm arm clearance.
Q_REF_DEG = np.array([0.0, 15.0, 5.0, 0.0, 30.0, 0.0, 0.0, 0.0, 0.0, 0.0, -30.0, 0.0])
#: Most waypoints a path (``sweep:N`` or a path file) may have: each one is an IK solve and a stored
#: waypoint, so a typo like sweep:100000000 would grow without limit; a real seam has a few thousand.
MAX_WAYPOINTS = 100_000


def tool_pose(planner: DualPlanner, name: str, q: np.ndarray) -> np.ndarray:
    """Tool pose of robot ``name`` in the cell frame for joint angles q [rad] (6,), shape (4, 4) [mm]."""
    R, p = planner.models[name].fk(np.asarray(q, dtype=float)[None])
    T = planner.T_cell_base[name]
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = T[:3, :3] @ R[0], T[:3, :3] @ p[0] + T[:3, 3]
    return out


def relative_pose(planner: DualPlanner, q: np.ndarray) -> np.ndarray:
    """Gun pose in the workpiece frame at q [rad] (12,), shape (4, 4) [mm]: a relative pose known to be reachable."""
    q = np.asarray(q, dtype=float)
    T_wp_gun: np.ndarray = np.linalg.inv(tool_pose(planner, "R2", q[6:])) @ tool_pose(planner, "R1", q[:6])
    return T_wp_gun


def sweep_path(planner: DualPlanner, n: int = 200, q_inward_deg: np.ndarray | None = None,
               q_outward_deg: np.ndarray | None = None) -> np.ndarray:
    """Workpiece poses sweeping R2 from tucked-in to outstretched (joint-space interpolation of R2).

    Args:
        planner: gives R2's model and base pose.
        n: number of waypoints.
        q_inward_deg, q_outward_deg: R2 end configurations [deg], shape (6,).

    Returns:
        Workpiece target poses in the cell frame, shape (n, 4, 4) [mm].
    """
    if not 2 <= n <= MAX_WAYPOINTS:
        raise ModelError(f"a sweep needs 2 <= n <= {MAX_WAYPOINTS} waypoints, got {n}")
    qa = np.radians([-5.0, -5.0, 5.0, -10.0, -35.0, 10.0] if q_inward_deg is None else q_inward_deg)
    qb = np.radians([10.0, 25.0, -5.0, 10.0, -20.0, -10.0] if q_outward_deg is None else q_outward_deg)
    s = 0.5 - 0.5 * np.cos(np.linspace(0.0, np.pi, n))  # rest-to-rest timing
    return np.array([tool_pose(planner, "R2", qa + si * (qb - qa)) for si in s])


def pose_from_numbers(v: Any, where: str) -> np.ndarray:
    """A pose (4, 4) [mm] from 7 numbers ``x, y, z [mm], qw, qx, qy, qz`` (unit quaternion, scalar first).

    Raises:
        DataError: not 7 finite numbers, or a quaternion whose norm is not 1 (within 1e-3).
    """
    try:
        if any(isinstance(x, str) and "_" in x for x in (v if isinstance(v, (list, tuple)) else [v])):
            raise ValueError("digit separators")  # float() and numpy accept "1_000"; a CSV number has none
        a = np.asarray(v, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        a = np.full(0, np.nan)
    if a.shape != (7,) or not np.all(np.isfinite(a)):
        raise DataError(where, None, None, "expected a pose as 7 numbers: x, y, z [mm], qw, qx, qy, qz")
    if np.any(np.abs(a[:3]) > MAX_ABS_POSITION_MM):
        raise DataError(where, None, None, f"position {np.abs(a[:3]).max():.6g} mm is physically absurd "
                                           f"(|x|, |y|, |z| <= {MAX_ABS_POSITION_MM:g} mm)")
    if abs(np.linalg.norm(a[3:]) - 1.0) > 1e-3:
        raise DataError(where, None, None, f"quaternion norm is {np.linalg.norm(a[3:]):.4g}, expected 1")
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = so3.quat_to_R(a[3:]), a[:3]
    return T


def _read_pose_file(path: Path) -> str:
    """The text of a pose or path file: a regular UTF-8 file of at most
    :data:`calibration.data.files.MAX_INPUT_BYTES` (a FIFO, a device or binary content is refused naming the file).

    Raises:
        DataError: naming the file and what is wrong.
    """
    try:
        return read_input_text(path)
    except IsADirectoryError:
        raise DataError(path, None, None, "is a folder, expected a pose file (CSV or JSON)") from None
    except UnicodeDecodeError as e:
        raise DataError(path, None, None, f"not a pose file (not UTF-8 text: {e.reason})") from None
    except OSError as e:
        raise DataError(path, None, None, f"cannot read ({e.strerror or e})") from None


def _poses_from_text(text: str, where: str) -> list[Any]:
    """Pose entries of a JSON document or a CSV (header ``x,y,z,qw,qx,qy,qz`` optional), one per row."""
    text = text.strip()
    if text[:1] in "[{":
        try:
            doc = json.loads(text)
        except json.JSONDecodeError as e:
            raise DataError(where, None, None, f"not valid JSON ({e})") from e
        except RecursionError:
            raise DataError(where, None, None, "not a pose file (JSON nested too deep)") from None
        doc = doc.get("poses", doc) if isinstance(doc, dict) else doc
        items = doc if isinstance(doc, list) else [doc]
        out = []
        for it in items:
            if isinstance(it, dict):
                it = list(it.get("p_mm", [])) + list(it.get("quat", []))
            out.append(it)
        return out
    rows = [r.strip() for r in text.splitlines() if r.strip() and not r.lstrip().startswith("#")]
    if rows and rows[0].replace(" ", "").lower() == ",".join(("x", "y", "z", "qw", "qx", "qy", "qz")):
        rows = rows[1:]
    return [r.split(",") for r in rows]


def read_pose(spec: str) -> np.ndarray:
    """A relative pose (4, 4) [mm] from a file (JSON ``{p_mm, quat}`` or one CSV row) or inline 7 numbers."""
    path = Path(spec)
    text = _read_pose_file(path) if path.exists() else spec
    items = _poses_from_text(text, spec)
    if len(items) != 1:
        raise DataError(spec, None, None, f"expected one pose (x, y, z [mm], qw, qx, qy, qz), got {len(items)}")
    return pose_from_numbers(items[0], spec)


def read_path(spec: str, planner: DualPlanner) -> np.ndarray:
    """Workpiece poses (N, 4, 4) [mm] in the cell frame: a CSV/JSON file of poses, or ``sweep:N``."""
    if spec.startswith("sweep:"):
        try:
            n = int(spec[6:])
        except ValueError:
            raise DataError(spec, None, None, "expected sweep:N with an integer N >= 2") from None
        if n > MAX_WAYPOINTS:
            raise DataError(spec, None, None, f"{n} waypoints is more than the limit of {MAX_WAYPOINTS}; "
                                              f"use sweep:N with 2 <= N <= {MAX_WAYPOINTS}")
        return sweep_path(planner, n)
    path = Path(spec)
    if not path.exists():
        raise DataError(spec, None, None, "path file not found (or use sweep:N)")
    items = _poses_from_text(_read_pose_file(path), spec)
    if not items:
        raise DataError(spec, None, None, "the path has no poses")
    if len(items) > MAX_WAYPOINTS:
        raise DataError(spec, None, None, f"{len(items)} poses is more than the limit of {MAX_WAYPOINTS} "
                                          f"waypoints; split the path")
    return np.array([pose_from_numbers(it, f"{spec} pose {i}") for i, it in enumerate(items)])


def plan_dual(cell: CellSpec, model_R1: Any = None, model_R2: Any = None, path: np.ndarray | None = None,
              T_wp_gun: np.ndarray | None = None, n: int = 200, q_start: np.ndarray | None = None,
              options: PlannerOptions | None = None) -> PlanResult:
    """Plan a dual-robot path in one call (what ``cellcal plan-dual`` runs).

    Args:
        cell: the loaded cell.
        model_R1, model_R2: kinematic models (``load_model`` results); nominal when None.
        path: workpiece poses in the cell frame (N, 4, 4) [mm]; the inward-to-outstretched sweep when None.
        T_wp_gun: gun pose in the workpiece frame (4, 4) [mm]; the reference one (:data:`Q_REF_DEG`) when None.
        n: waypoints of the default sweep.
        q_start: first guess (12,) [rad]; the reference configuration when None.
        options: planner options.
    """
    planner = DualPlanner(cell, model_R1, model_R2, options or PlannerOptions())
    try:
        q0 = np.radians(Q_REF_DEG) if q_start is None else np.asarray(q_start, dtype=float)
        T_rel = relative_pose(planner, np.radians(Q_REF_DEG)) if T_wp_gun is None else T_wp_gun
        return planner.plan(sweep_path(planner, n) if path is None else path, T_rel, q0)
    finally:
        planner.close()

