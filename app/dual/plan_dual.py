"""Planning both arms along a workpiece path (``cellcal plan-dual``), with the checks every plan leaving for a
controller runs.

:func:`plan_dual` takes plain :class:`PlanDualInputs` (the models already read and checked by the caller) and returns
a :class:`PlanDualResult`. It refuses a plan with unsolved waypoints, and runs
:func:`app.collection.plan_safety.check_plan_safe` on the solved plan before it writes the plan file: the planner's
own output gets exactly the checks a plan file gets at every other exit (export-targets, preview, validate-dual,
collect), whoever calls it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from app.collection.plan_safety import check_plan_safe
from app.collection.plans.dual import PlanResult, save_plan
from app.dual.paths import Q_REF_DEG, read_path, read_pose, relative_pose
from app.dual.planner import CompileMode, DualPlanner, PlannerOptions
from app.progress import bar
from calibration.errors import ModelError
from calibration.models import KinematicModel
from cell_config.loader import CellSpec

__all__ = ["PlanDualInputs", "PlanDualResult", "plan_dual"]


@dataclass(frozen=True)
class PlanDualInputs:
    """What ``plan-dual`` was asked.

    Attributes:
        path: the workpiece path: a CSV/JSON file of poses in the cell frame, or ``sweep:N``
            (:func:`app.dual.paths.read_path`).
        relative_pose: the gun pose in the workpiece frame (a file or inline ``x,y,z,qw,qx,qy,qz`` [mm],
            :func:`app.dual.paths.read_pose`); None: the reference pose.
        models: robot name -> the model it is planned with (a robot left out: its nominal model).
        compile: the planner's compile mode (:attr:`app.dual.planner.PlannerOptions.compile`).
        out: write the plan file here (only once every check passed), or None.
        json_out: where the caller writes the summary; named, with ``out``, in a refusal ("nothing written to ...").
        progress: show a progress bar over the waypoints.
    """

    path: str
    relative_pose: str | None = None
    models: Mapping[str, KinematicModel] = field(default_factory=dict)
    compile: CompileMode = "auto"
    out: str | None = None
    json_out: str | None = None
    progress: bool = False


@dataclass(frozen=True)
class PlanDualResult:
    """A solved plan that passed every check, and the planner's counts.

    Attributes:
        plan: the :class:`~app.collection.plans.dual.PlanResult` (written to ``inputs.out`` when given).
        evaluations: the planner's expression evaluations by kind (compiled or interpreted).
        out: where the plan file was written, or None.
    """

    plan: PlanResult
    evaluations: dict[str, int]
    out: str | None

    def to_json(self) -> dict[str, Any]:
        """The ``--json`` summary of ``plan-dual``."""
        plan = self.plan
        return {"waypoints": len(plan.waypoints), "converged": plan.converged, "failed": plan.failed,
                "models": plan.models, "solve_ms_median": float(np.median([w.solve_ms for w in plan.waypoints])),
                "max_residual_mm": max(w.residual_mm for w in plan.waypoints),
                "max_residual_deg": max(w.residual_deg for w in plan.waypoints),
                "min_clearance_mm": min(w.clearance_mm for w in plan.waypoints),
                "evaluations": dict(self.evaluations), "out": self.out}

    def line(self) -> str:
        """The one line ``plan-dual`` prints."""
        summary = self.to_json()
        return (f"{len(self.plan.waypoints)} waypoints solved ({self.plan.models['R1']}/{self.plan.models['R2']}), "
                f"median {summary['solve_ms_median']:.2f} ms, residual <= {summary['max_residual_mm']:.1e} mm, "
                f"clearance >= {summary['min_clearance_mm']:.0f} mm" + (f" -> {self.out}" if self.out else ""))


def plan_dual(cell: CellSpec, inputs: PlanDualInputs) -> PlanDualResult:
    """Plan both arms holding the relative pose along the path; refuse it unless every waypoint is solved and the
    plan passes :func:`~app.collection.plan_safety.check_plan_safe`; then write the plan file if asked.

    Raises:
        DataError: an unreadable path or relative pose.
        ModelError: waypoints left unsolved (named); nothing written.
        UnsafePlan: the solved plan fails a safety check; nothing written.
    """
    T_rel = read_pose(inputs.relative_pose) if inputs.relative_pose else None
    planner = DualPlanner(cell, inputs.models.get("R1"), inputs.models.get("R2"),
                          PlannerOptions(compile=inputs.compile))
    try:
        path = read_path(inputs.path, planner)
        q0 = np.radians(Q_REF_DEG)
        with bar(total=len(path), enabled=inputs.progress, desc="plan-dual", unit="waypoint") as waypoints:
            plan = planner.plan(path, relative_pose(planner, q0) if T_rel is None else T_rel, q0,
                                on_waypoint=lambda r: waypoints.update(1))
    finally:
        planner.close()  # a build still running has lost its race with the plan: it is not waited for
    if not plan.converged:  # refused whole: a plan with holes would move the arms through unchecked poses
        i = plan.failed[0]
        raise ModelError(f"{len(plan.failed)} of {len(plan.waypoints)} waypoints not solved (waypoint"
                         f"{'s' if len(plan.failed) > 1 else ''} {_index_ranges(plan.failed)}), nothing written"
                         f"{_named_outputs(inputs)}; first: waypoint {i}: {plan.waypoints[i].reason}")
    check_plan_safe(planner.cell, plan, "the solved plan", models=inputs.models)  # the checks every exit runs
    if inputs.out:
        save_plan(plan, inputs.out)
    return PlanDualResult(plan, dict(planner.evaluations), inputs.out)


def _index_ranges(indices: list[int]) -> str:
    """``[0, 1, 2, 7, 9, 10]`` -> ``0-2, 7, 9-10`` (sorted indices, runs joined)."""
    runs: list[list[int]] = []
    for i in indices:
        if runs and i == runs[-1][1] + 1:
            runs[-1][1] = i
        else:
            runs.append([i, i])
    return ", ".join(str(a) if a == b else f"{a}-{b}" for a, b in runs)


def _named_outputs(inputs: PlanDualInputs) -> str:
    """`` to --out X or --json Y``: the outputs the command was given (empty when none)."""
    named = [f"--{k} {v}" for k, v in (("out", inputs.out), ("json", inputs.json_out)) if v]
    return f" to {' or '.join(named)}" if named else ""
