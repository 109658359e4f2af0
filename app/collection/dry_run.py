"""What a plan would do, without moving anything: targets, joint ranges, estimated duration, safety verdict.

:func:`summarize_plan` backs ``--dry-run`` on every motion command. The duration is estimated the way the
MotoROS driver times its moves: each joint move from the previous pose is a cubic Hermite segment with zero end
velocities, whose peak speed is ``CUBIC_PEAK_RATIO`` (1.5) times its mean speed, so a move lasts
``1.5 * max_j |dq_j| / (speed_fraction * max_speed_j)``. The safety verdict is the full check the collector runs
before its first motion (:func:`~app.collection.plan_safety.plan_defects`, the one definition of a safe plan: every target
and every path, against the limits, the floor and the other arms at the given poses).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from app.collection.plan_safety import plan_defects
from app.collection.plans.collection import KINDS, Plan
from app.collection.safety import CellSafety
from calibration.errors import ConfigError
from drivers.motoros.driver import CUBIC_PEAK_RATIO


@dataclass(frozen=True)
class PlanSummary:
    """The dry run of a plan.

    Attributes:
        robot: the arm the plan moves.
        n_targets: targets in the plan.
        targets_per_kind: kind -> count, in :data:`~app.collection.plans.collection.KINDS` order (kinds absent from the plan left out).
        q_min_rad, q_max_rad: joint range visited from the start pose through every target [rad], shape (6,)
            (joint-space moves are linear, so the paths stay inside it).
        speed_fraction: fraction of the maximum joint speeds the estimate assumes.
        motion_s: estimated time in motion [s] (every move, the one from the start pose included).
        per_target_s: time assumed at each target (settling, dwell) [s].
        duration_s: ``motion_s + n_targets * per_target_s`` [s].
        longest_move_s: the longest single move [s].
        safe: the full safety check passed.
        safety_error: why it did not (the first unsafe target or path), else None.
    """

    robot: str
    n_targets: int
    targets_per_kind: Mapping[str, int]
    q_min_rad: np.ndarray
    q_max_rad: np.ndarray
    speed_fraction: float
    motion_s: float
    per_target_s: float
    duration_s: float
    longest_move_s: float
    safe: bool
    safety_error: str | None

    def lines(self) -> list[str]:
        """Human-readable summary (what ``--dry-run`` prints)."""
        kinds = ", ".join(f"{n} {k}" for k, n in self.targets_per_kind.items()) or "nothing"
        ranges = ", ".join(f"q{j + 1} {math.degrees(lo):.1f}..{math.degrees(hi):.1f}"
                           for j, (lo, hi) in enumerate(zip(self.q_min_rad, self.q_max_rad)))
        verdict = "every target and path is safe" if self.safe else f"REFUSED: {self.safety_error}"
        return [f"{self.robot}: {self.n_targets} targets ({kinds})",
                f"joint ranges visited [deg]: {ranges}",
                f"estimated duration at {100 * self.speed_fraction:g}% speed: {self.duration_s / 60:.1f} min "
                f"(motion {self.motion_s:.0f} s, longest move {self.longest_move_s:.1f} s, "
                f"{self.per_target_s:g} s per target)",
                f"safety: {verdict}"]

    def to_json(self) -> dict[str, Any]:
        return {"robot": self.robot, "targets": self.n_targets, "targets_per_kind": dict(self.targets_per_kind),
                "q_min_deg": np.degrees(self.q_min_rad).tolist(), "q_max_deg": np.degrees(self.q_max_rad).tolist(),
                "speed_fraction": self.speed_fraction, "motion_s": self.motion_s, "per_target_s": self.per_target_s,
                "duration_s": self.duration_s, "longest_move_s": self.longest_move_s, "safe": self.safe,
                "safety_error": self.safety_error}


def move_durations_s(q: np.ndarray, max_speed_rad_s: np.ndarray, speed_fraction: float) -> np.ndarray:
    """Duration of each joint move between consecutive rows of ``q`` (N, 6) [rad] -> (N - 1,) [s]."""
    dq = np.abs(np.diff(np.atleast_2d(q), axis=0))
    durations_s: np.ndarray = CUBIC_PEAK_RATIO * np.max(dq / (speed_fraction * np.asarray(max_speed_rad_s)), axis=1,
                                                        initial=0.0)
    return durations_s


def summarize_plan(plan: Plan, safety: CellSafety, others: Mapping[str, np.ndarray] | None, q_start: np.ndarray, *,
                   speed_fraction: float = 0.2, per_target_s: float = 0.0) -> PlanSummary:
    """Dry-run ``plan``: nothing is moved or connected.

    Args:
        plan: a single-robot plan.
        safety: the cell's safety checker (its cell gives the joint speeds).
        others: the other arms' joint angles [rad] (6,), held still.
        q_start: the arm's joint angles now [rad], shape (6,).
        speed_fraction: fraction (0, 1] of the maximum joint speeds.
        per_target_s: time spent at each target (settling, dwell) [s], >= 0.

    Raises:
        ConfigError: an empty plan or one moving several robots, a bad speed fraction or time, or a start pose
            that is not 6 finite numbers. An unsafe plan is not an error: it is reported in ``safe`` / ``safety_error``.
    """
    if len(plan.robots) != 1:
        raise ConfigError("summarize_plan", "plan", f"expected targets of one robot, got "
                                                    f"{', '.join(plan.robots) or 'no target'}")
    if not 0.0 < speed_fraction <= 1.0:
        raise ConfigError("summarize_plan", "speed_fraction", f"expected a value in (0, 1], got {speed_fraction!r}")
    if not per_target_s >= 0.0:
        raise ConfigError("summarize_plan", "per_target_s", f"expected a time >= 0 s, got {per_target_s!r}")
    q_start = np.asarray(q_start, dtype=float)
    if q_start.shape != (6,) or not np.all(np.isfinite(q_start)):
        raise ConfigError("summarize_plan", "q_start", f"expected 6 finite joint angles [rad], got {q_start!r}")
    robot, n = plan.robots[0], len(plan)
    q = np.concatenate([q_start[None], plan.q])
    moves = move_durations_s(q, safety.cell.robot(robot).robot.max_speed_rad_s, speed_fraction)
    counts = {k: sum(t.kind == k for t in plan.targets) for k in KINDS}
    defects = plan_defects(safety.cell, plan, safety=safety, others=others, q_start={robot: q_start}, first_only=True)
    error = str(defects[0]) if defects else None
    motion_s = float(moves.sum())
    return PlanSummary(robot, n, {k: c for k, c in counts.items() if c}, q.min(axis=0), q.max(axis=0),
                       speed_fraction, motion_s, per_target_s, motion_s + n * per_target_s,
                       float(moves.max(initial=0.0)), error is None, error)


__all__ = ["PlanSummary", "move_durations_s", "summarize_plan"]
