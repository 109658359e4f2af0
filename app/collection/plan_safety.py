"""The one definition of "a plan is safe to hand to a controller or a person", checked at every exit.

plan-dual runs it on the plan it has just solved, and every command that hands a plan's motion on runs it again
on the plan file (export-targets, preview, validate-dual, collect), so a plan edited by hand, or written by
another tool, gets exactly the checks the planner's own output gets. Nothing is read from the file as proof:
``converged``, ``residual_mm`` and ``clearance_mm`` are the file's claims; the checks recompute what they claim.

A dual plan (:class:`~app.collection.plans.dual.PlanResult`) is safe when

* its models are of a known kind, and its relative pose ``T_wp_gun`` is a rigid transform (a rotation,
  determinant +1);
* every waypoint is marked solved, within the joint limits less the planner's margin
  (:attr:`~app.dual.planner.PlannerOptions.limit_margin_deg`);
* the relative-pose residual, recomputed at every waypoint from the models (the nominal models unless others are
  given), is within :data:`RESIDUAL_TOLERANCE_MM` and :data:`RESIDUAL_TOLERANCE_DEG`;
* every move between consecutive waypoints (both arms together, linear in joint space) keeps the floor and arm
  clearances of :class:`~app.collection.safety.CellSafety` (``check_dual_path``; the process zone, gun and workpiece
  ends, is left to the relative pose only when the plan records one);
* along every such move the gun stays within :data:`MAX_DRIFT_MM` of the pose the workpiece asks of it (the
  step between waypoints: a move does not hold the relative pose, and the process zone is not clearance-checked).

A collection plan (:class:`~app.collection.plans.collection.Plan`) is safe when :meth:`~app.collection.safety.CellSafety.check_plan`
passes for each of its arms (every target and path against limits, floor and the other arms at their poses).

:func:`plan_defects` lists every defect (the preview marks them); :func:`check_plan_safe` raises for the first.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from app.collection.plans.dual import PlanResult
from app.collection.safety import CellSafety, SafetyConfig
from calibration.errors import CellCalError, ConfigError, UnsafeTarget
from calibration.models import ConstantModel
from cell_config.capsules import PROCESS_ZONE
from cell_config.loader import CellSpec

if TYPE_CHECKING:
    from app.collection.plans.collection import Plan
    from app.collection.plans.dual import PlanResult

__all__ = ["MAX_DRIFT_MM", "PLAN_MODEL_KINDS", "PlanDefect", "UnsafePlan", "check_plan_safe", "plan_defects"]

#: Relative-pose residual a waypoint may show when recomputed from the models [mm], [deg]. The planner solves to
#: 1e-6 mm and 1e-8 rad with its casadi expression; the numpy kinematics evaluated here agree with it to ~1e-9 mm
#: (sweep:200, nominal), so this only absorbs evaluation differences, never a pose that was not reached.
RESIDUAL_TOLERANCE_MM = 1e-3
RESIDUAL_TOLERANCE_DEG = 1e-4

#: Largest distance [mm] of the gun from the pose the workpiece asks of it anywhere along a move between two
#: waypoints (joint-space linear, sampled every ``SafetyConfig.path_step_deg``): the cell's arm-to-arm clearance
#: (``SafetyConfig.clearance_mm``), since the process zone's capsules are not clearance-checked against each other.
#: Measured on the nominal cell's planned sweeps (plan-dual --path sweep:N, then ``plan_defects``): N = 20: 0.9 mm,
#: N = 10: 4.0 mm, N = 4: 34 mm, N = 3: 35 mm, N = 2: 137 mm (refused); one R1 joint moved by 1.5 rad: 2071 mm.
MAX_DRIFT_MM = 50.0

#: Model kinds a dual plan may record (the planner's casadi expression kinds, optionally with ``+dq``).
PLAN_MODEL_KINDS = ("constant", "pi", "cdc", "cdc-frozen", "physics", "diagnosed", "rebased", "poe")

#: The planner's joint-limit margin [deg] (:attr:`app.dual.planner.PlannerOptions.limit_margin_deg`, which is
#: defined from this).
DUAL_LIMIT_MARGIN_DEG = 2.0

#: How the reason of an unsolved waypoint begins.
NOT_SOLVED = "not solved:"

#: Largest entry of ``R^T R - I`` accepted in a plan's ``T_wp_gun`` (a JSON round trip keeps 17 digits).
ROTATION_TOLERANCE = 1e-6


@dataclass(frozen=True)
class PlanDefect:
    """Why a plan must not leave: the waypoint (None: the whole plan) and the reason."""

    waypoint: int | None
    reason: str
    what: str = "waypoint"

    def __str__(self) -> str:
        return self.reason if self.waypoint is None else f"{self.what} {self.waypoint}: {self.reason}"


class UnsafePlan(UnsafeTarget):
    """A plan refused by :func:`check_plan_safe`: one line naming the plan and its first defect (the check stops at
    the first kind of defect it finds, so how many more there are is not known; the preview lists them all)."""

    def __init__(self, source: str, defects: list[PlanDefect]) -> None:
        more = "; cellcal preview marks every defect" if len(defects) > 1 else ""
        CellCalError.__init__(self, f"{source}: unsafe plan, {defects[0]}{more}; nothing written")
        self.robot, self.joint, self.value, self.limit = "R1+R2", None, float("nan"), float("nan")
        self.defects = defects


def _kind_defects(plan: PlanResult, models: Mapping[str, Any]) -> list[PlanDefect]:
    out = []
    for robot in ("R1", "R2"):
        kind = plan.models.get(robot, "constant") if isinstance(plan.models, dict) else None
        base = kind.removesuffix("+dq") if isinstance(kind, str) else None
        if base not in PLAN_MODEL_KINDS:
            out.append(PlanDefect(None, f"models.{robot}: unknown model kind {kind!r}; valid: "
                                        f"{', '.join(PLAN_MODEL_KINDS)}"))
        elif base != "constant" and robot not in models:
            out.append(PlanDefect(None, f"the plan was solved with a {kind} model for {robot}; give that model "
                                        f"(--models {robot}=FILE) so its relative pose is recomputed from it"))
    return out


def _rotation_defect(T: np.ndarray) -> PlanDefect | None:
    R = T[:3, :3]
    err = float(np.max(np.abs(R.T @ R - np.eye(3))))
    if not err <= ROTATION_TOLERANCE:
        return PlanDefect(None, f"T_wp_gun is not a rigid transform: its rotation's columns are not orthonormal "
                                f"(R^T R - I up to {err:.2g}, tolerance {ROTATION_TOLERANCE:g})")
    if not np.linalg.det(R) > 0:
        return PlanDefect(None, "T_wp_gun is not a rigid transform: its rotation has determinant -1 (a reflection)")
    return None


def _cell_poses(cell: CellSpec, model: Any, robot: str, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tool poses of ``model`` at q (N, 6) in the cell frame: ``(R (N, 3, 3), p (N, 3) [mm])``."""
    R, p = model.fk(q)
    T = cell.robot(robot).T_cell_base
    return np.einsum("ij,njk->nik", T[:3, :3], R), p @ T[:3, :3].T + T[:3, 3]


def _relative_error(cell: CellSpec, models: Mapping[str, Any], q: np.ndarray, T_wp_gun: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    """The gun's distance [mm] and angle [deg] from the pose the workpiece asks of it (as the planner measures it:
    the target taken forward from the workpiece, compared in the cell frame), at q (N, 12)."""
    Rg, pg = _cell_poses(cell, models["R1"], "R1", q[:, :6])
    Rw, pw = _cell_poses(cell, models["R2"], "R2", q[:, 6:])
    p_des = pw + Rw @ T_wp_gun[:3, 3]
    E = np.swapaxes(Rw @ T_wp_gun[:3, :3], 1, 2) @ Rg  # R_des^T R_gun
    sin = 0.5 * np.linalg.norm(np.stack([E[:, 2, 1] - E[:, 1, 2], E[:, 0, 2] - E[:, 2, 0], E[:, 1, 0] - E[:, 0, 1]],
                                        axis=1), axis=1)
    cos = 0.5 * (np.trace(E, axis1=1, axis2=2) - 1.0)
    return np.linalg.norm(pg - p_des, axis=1), np.degrees(np.arctan2(sin, cos))


def _moves(safety: CellSafety, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Samples of every move (waypoint i - 1 to i; the first from itself) and the waypoint each belongs to."""
    pts = [safety.path(q[max(i - 1, 0)], q[i]) for i in range(len(q))]
    owner = np.concatenate([np.full(len(p), i) for i, p in enumerate(pts)])
    return np.concatenate(pts), owner


def _dual_defects(cell: CellSpec, plan: PlanResult, models: Mapping[str, Any], skip_failed: bool,
                  first_only: bool) -> list[PlanDefect]:

    out = _kind_defects(plan, models)
    T = plan.T_wp_gun
    if T is not None:
        d = _rotation_defect(T)
        if d is not None:
            out.append(d)
    if out and first_only:
        return out
    index = [i for i, w in enumerate(plan.waypoints) if w.converged or not skip_failed]
    for i in index:
        w = plan.waypoints[i]
        if not w.converged:
            out.append(PlanDefect(i, f"{NOT_SOLVED} {w.reason or 'not marked converged'}"))
        elif not (w.residual_mm <= RESIDUAL_TOLERANCE_MM and w.residual_deg <= RESIDUAL_TOLERANCE_DEG):
            if not (np.isnan(w.residual_mm) and np.isnan(w.residual_deg)):  # a hand-written plan records none
                out.append(PlanDefect(i, f"marked converged but records a relative-pose residual of "
                                         f"{w.residual_mm:.3g} mm, {w.residual_deg:.3g} deg (tolerance "
                                         f"{RESIDUAL_TOLERANCE_MM:g} mm, {RESIDUAL_TOLERANCE_DEG:g} deg): "
                                         "the file contradicts itself"))
    if (out and first_only) or not index:
        return out
    q = np.array([np.concatenate([plan.waypoints[i].q_R1, plan.waypoints[i].q_R2]) for i in index])
    safety = CellSafety(cell, SafetyConfig(joint_margin_deg=DUAL_LIMIT_MARGIN_DEG,
                                           process_zone=PROCESS_ZONE if T is not None else ()))
    n_before = len(out)
    for k, robot in enumerate(("R1", "R2")):  # limits first: no path is sampled to a target beyond them
        lower, upper = safety.limits(robot)
        qr = q[:, 6 * k:6 * k + 6]
        for n, j in np.argwhere(~((qr >= lower) & (qr <= upper))):
            out.append(PlanDefect(index[n], f"{robot} joint {j + 1} at {math.degrees(qr[n, j]):.6g} deg is outside "
                                            f"its limits less the planner's {DUAL_LIMIT_MARGIN_DEG:g} deg margin "
                                            f"({math.degrees(lower[j]):.6g}..{math.degrees(upper[j]):.6g} deg)"))
    beyond_limits = len(out) > n_before
    if out and first_only:
        return out
    given = ", ".join(f"{n} {'given' if n in models else 'nominal'}" for n in ("R1", "R2"))
    models = {n: models[n] if n in models else ConstantModel(n, "nominal", cell.robot(n).model())
              for n in ("R1", "R2")}
    if T is not None:
        mm, deg = _relative_error(cell, models, q, T)
        for n in np.flatnonzero(~((mm <= RESIDUAL_TOLERANCE_MM) & (deg <= RESIDUAL_TOLERANCE_DEG))):
            out.append(PlanDefect(index[n], f"relative pose not held: the gun is {mm[n]:.3g} mm, {deg[n]:.3g} deg "
                                            f"from T_wp_gun, recomputed from the models ({given}; tolerance "
                                            f"{RESIDUAL_TOLERANCE_MM:g} mm, {RESIDUAL_TOLERANCE_DEG:g} deg)"))
        pts, owner = _moves(safety, q)
        drift, _ = _relative_error(cell, models, pts, T)
        for n in np.unique(owner[(drift > MAX_DRIFT_MM) & (owner > 0)]):  # waypoint 0's move has no length
            worst = float(drift[owner == n].max())
            out.append(PlanDefect(index[n], f"the move to it from waypoint {index[n - 1]} takes the gun {worst:.0f} "
                                            f"mm from its relative pose (step too large: at most {MAX_DRIFT_MM:g} "
                                            "mm; plan more waypoints)"))
    if (out and first_only) or beyond_limits:  # the clearance check would only name the limit again
        return sorted(out, key=lambda d: -1 if d.waypoint is None else d.waypoint)
    out += _clearance_defects(safety, q, index, first_only)
    return sorted(out, key=lambda d: -1 if d.waypoint is None else d.waypoint)


def _clearance_defects(safety: CellSafety, q: np.ndarray, index: list[int], first_only: bool) -> list[PlanDefect]:
    """Floor and arm clearances along every move (:meth:`CellSafety.check_dual_path`, one batched screen); a plan
    that fails it is checked move by move (the same samples) to name the unsafe waypoints."""
    try:
        safety.check_dual_path(q)
        return []
    except UnsafeTarget:
        pass
    out = []
    for n in range(len(q)):
        try:
            safety.check_dual_motion(q[max(n - 1, 0)], q[n])
        except UnsafeTarget as e:
            out.append(PlanDefect(index[n], str(e)))
            if first_only:
                break
    return out


def _collection_defects(cell: CellSpec, plan: Plan, safety: CellSafety, others: Mapping[str, np.ndarray] | None,
                        q_start: Mapping[str, np.ndarray] | None, first_only: bool,
                        numbers: Sequence[int] | None) -> list[PlanDefect]:
    """:meth:`CellSafety.check_plan` on each run of one arm's targets, the other arms where the plan leaves them
    (``others``, ``q_start``: where the arms stand at the start; home, q = 0, when not given). A run that fails is
    checked target by target (the same paths) to name the unsafe targets."""
    home = others is None and q_start is None  # the preview's assumption; a caller who knows the poses gives them
    current = {n: np.zeros(6) for n in cell.robots} if home else {}
    current.update({n: np.asarray(v, dtype=float) for n, v in dict(others or {}).items()})
    current.update({n: np.asarray(v, dtype=float) for n, v in dict(q_start or {}).items()})
    out: list[PlanDefect] = []
    targets = list(plan.targets)
    number = list(range(len(targets))) if numbers is None else [int(n) for n in numbers]
    i = 0
    while i < len(targets) and not (out and first_only):
        robot = targets[i].robot
        j = i
        while j < len(targets) and targets[j].robot == robot:
            j += 1
        if robot not in cell.robots:
            out.append(PlanDefect(number[i], f"unknown robot {robot!r}; valid: {', '.join(cell.robots)}", "target"))
            i = j
            continue
        q = np.array([t.q for t in targets[i:j]])
        rest = {n: v for n, v in current.items() if n != robot}
        try:
            safety.check_plan(robot, q, rest, current.get(robot))
        except (UnsafeTarget, ConfigError):
            prev = current.get(robot)
            for k in range(len(q)):
                try:
                    safety.check_plan(robot, q[k:k + 1], rest, prev)
                except (UnsafeTarget, ConfigError) as e:
                    reason = str(e).replace(" (target 0)", "").replace(" at target 0", "")
                    out.append(PlanDefect(number[i + k], reason, "target"))
                    if first_only:
                        break
                prev = q[k]
        current[robot] = q[-1]
        i = j
    return out


def plan_defects(cell: CellSpec, plan: Any, *, models: Mapping[str, Any] | None = None,
                 safety: CellSafety | None = None, others: Mapping[str, np.ndarray] | None = None,
                 q_start: Mapping[str, np.ndarray] | None = None, skip_failed: bool = False,
                 first_only: bool = False, numbers: Sequence[int] | None = None) -> list[PlanDefect]:
    """Every reason ``plan`` must not leave for a controller or a person (empty: safe).

    Args:
        cell: the cell (limits, capsules, base poses, nominal models).
        plan: a :class:`~app.collection.plans.dual.PlanResult` or a :class:`~app.collection.plans.collection.Plan`.
        models: a dual plan's models per robot (``R1``, ``R2``); the nominal model for a robot not given.
        safety: a collection plan's checker (the cell's default one when None); a dual plan is always checked
            with the planner's margins (:data:`DUAL_LIMIT_MARGIN_DEG`, the process zone).
        others, q_start: a collection plan's other arms and its own arm where they stand [rad] (home when None).
        skip_failed: leave out a dual plan's unsolved waypoints (export-targets --skip-failed); the moves between
            the remaining ones are checked.
        first_only: stop at the first kind of defect found (the cheap path of :func:`check_plan_safe`).
        numbers: a collection plan's target numbers for the messages (the plan's order when None; a resumed
            session checks its pending targets under their own numbers).

    Returns:
        The defects, plan-wide ones (``waypoint`` None) first, then by waypoint (target for a collection plan).
    """

    if isinstance(plan, PlanResult):
        return _dual_defects(cell, plan, dict(models or {}), skip_failed, first_only)
    return _collection_defects(cell, plan, safety or CellSafety(cell), others, q_start, first_only, numbers)


def check_plan_safe(cell: CellSpec, plan: Any, source: str = "<plan>", **kwargs: Any) -> None:
    """Raise :class:`UnsafePlan` naming the first defect of :func:`plan_defects` (same arguments), if any."""
    defects = plan_defects(cell, plan, first_only=True, **kwargs)
    if defects:
        raise UnsafePlan(source, defects)
