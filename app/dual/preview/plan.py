"""A plan as the preview draws it: both arms' joints per frame, the plan's residuals, its joint-limit margin.

Any plan file (:func:`app.collection.plans.reader.read_plan`): a dual plan draws both arms per waypoint; a single-robot
collection plan moves its arm target by target while the other keeps its previous configuration (its parking pose,
:func:`app.collection.runtime.sim.park_q`, at the start: where ``cellcal plan`` checked the plan with it, and where the
simulated and the fake controller's arms stand). A plan with a joint beyond its limit is refused, as
export-targets refuses it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from app.collection.plans.dual import PlanResult
from app.collection.plans.reader import read_plan
from calibration.errors import DataError, UnsafeTarget
from cell_config.loader import CellSpec


@dataclass(frozen=True)
class PreviewPlan:
    """A plan as the preview draws it.

    Attributes:
        kind: ``dual`` or ``collection``.
        q: joint angles per robot (``R1``, ``R2``) per frame [rad], shape (F, 6) each.
        residual_mm, residual_deg: recorded relative-pose residual per frame [mm], [deg], shape (F,); NaN when
            the plan records none.
        converged: per frame whether the planner proved it, shape (F,); None for a collection plan.
        notes: a short status text per frame (``converged``, the planner's reason, the collection target).
        T_wp_gun: the relative pose the dual plan holds (gun in the workpiece frame) [mm]; None for a
            collection plan.
    """

    kind: str
    q: dict[str, np.ndarray]
    residual_mm: np.ndarray
    residual_deg: np.ndarray
    converged: np.ndarray | None
    notes: tuple[str, ...]
    T_wp_gun: np.ndarray | None = None

    @property
    def n_frames(self) -> int:
        return len(self.notes)


def read_preview_plan(plan: Any) -> PreviewPlan:
    """Read a dual or collection plan for drawing.

    A dual plan draws both arms per waypoint; a collection plan moves its arm target by target while the
    other keeps its previous configuration (its parking pose at the start, as ``cellcal plan`` checked it).

    Args:
        plan: a plan file path, its parsed content, a :class:`~app.collection.plans.collection.Plan` or a
            :class:`~app.collection.plans.dual.PlanResult` (read with :func:`app.collection.plans.reader.read_plan`).

    Raises:
        DataError: unreadable or malformed plan, a robot other than R1/R2, or no waypoints.
    """

    source = str(plan) if isinstance(plan, (str, Path)) else "<plan>"  # the file the messages name
    plan = read_plan(plan)
    if isinstance(plan, PlanResult):
        w = plan.waypoints
        if not w:
            raise DataError(source, None, None, "the plan has no waypoints")
        return PreviewPlan("dual", {"R1": np.array([x.q_R1 for x in w]), "R2": np.array([x.q_R2 for x in w])},
                           np.array([x.residual_mm for x in w]), np.array([x.residual_deg for x in w]),
                           np.array([x.converged for x in w]),
                           tuple("converged" if x.converged else f"NOT converged: {x.reason}" for x in w),
                           plan.T_wp_gun)
    from app.collection.runtime.sim import park_q

    current = {"R1": park_q("R1"), "R2": park_q("R2")}
    q: dict[str, list[np.ndarray]] = {"R1": [], "R2": []}
    notes = []
    for i, t in enumerate(plan.targets):
        if t.robot not in current:
            raise DataError(source, None, None, f"entry {i}: unknown robot {t.robot!r}; valid: R1, R2")
        current[t.robot] = np.asarray(t.q, dtype=float)
        for name in q:
            q[name].append(current[name].copy())
        notes.append(f"{t.robot} target {i} ({t.kind}, cluster {t.cluster})")
    if not notes:
        raise DataError(source, None, None, "the plan has no waypoints")
    nan = np.full(len(notes), np.nan)
    return PreviewPlan("collection", {k: np.array(v) for k, v in q.items()}, nan, nan.copy(), None, tuple(notes))


def plan_frames(plan: Any) -> list[dict[str, np.ndarray]]:
    """Frames of a dual or collection plan: one ``{"R1": q (6,), "R2": q (6,)}`` per waypoint [rad].

    Raises:
        DataError: as :func:`read_preview_plan`.
    """
    p = read_preview_plan(plan)
    return [{name: p.q[name][f].copy() for name in ("R1", "R2")} for f in range(p.n_frames)]


def limit_margin(cell: CellSpec, plan: PreviewPlan) -> tuple[float, tuple[int, str, int]]:
    """Refuse a plan with a joint beyond its limit, as export-targets does (a preview must not show what the
    controller would never be sent); otherwise the smallest margin to a limit [deg] and where it is.

    Raises:
        UnsafeTarget: naming the waypoint, robot, joint, value and limit.
    """

    best: tuple[float, tuple[int, str, int]] = (float("inf"), (0, "R1", 1))
    for name in ("R1", "R2"):
        spec = cell.robot(name).robot
        q = plan.q[name]
        bad = (q < spec.lower_rad) | (q > spec.upper_rad)
        if bad.any():
            i, j = (int(v) for v in np.argwhere(bad)[0])
            limit = spec.lower_rad[j] if q[i, j] < spec.lower_rad[j] else spec.upper_rad[j]
            raise UnsafeTarget(name, j + 1, float(q[i, j]), float(limit), f"waypoint {i} of the plan is beyond the "
                                                                          "joint limits; not drawn")
        margin = np.degrees(np.minimum(q - spec.lower_rad, spec.upper_rad - q))
        i, j = (int(v) for v in np.unravel_index(int(np.argmin(margin)), margin.shape))
        if margin[i, j] < best[0]:
            best = (float(margin[i, j]), (i, name, j + 1))
    return best
