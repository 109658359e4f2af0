"""Results of the dual-robot planner and their plan file (JSON, schema ``cellcal.plan/1``, kind ``dual``).

A plan file holds, per waypoint, both arms' joint angles [rad], whether the planner proved the waypoint
(``converged``) and why not. Reading a file back treats any entry without ``converged: true`` as unsolved,
so nothing downstream (export, execution) can take an unproven waypoint for a solved one. Files are read
with :func:`app.collection.plans.reader.read_plan`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from app.collection.plans.schema import PLAN_SCHEMA, json_numbers
from calibration.data.files import atomic_write_text
from calibration.errors import DataError


@dataclass(frozen=True)
class WaypointResult:
    """One solved (or refused) waypoint.

    Attributes:
        q_R1, q_R2: joint angles [rad], shape (6,).
        residual_mm, residual_deg: relative-pose error in the models (numpy FK) [mm], [deg].
        track_mm, track_deg: workpiece distance from its target pose [mm], [deg].
        clearance_mm: smallest capsule surface distance between the arms [mm].
        singularity: smallest singularity measure (0 = singular, 1 = far).
        solve_ms: wall time of the solve including the checks [ms].
        iterations: Newton iterations.
        converged: every hard condition holds; only then may the waypoint be executed.
        reason: why not, or "" when converged.
    """

    q_R1: np.ndarray
    q_R2: np.ndarray
    residual_mm: float
    residual_deg: float
    track_mm: float
    track_deg: float
    clearance_mm: float
    singularity: float
    solve_ms: float
    iterations: int
    converged: bool
    reason: str = ""


@dataclass(frozen=True)
class PlanResult:
    """A planned sequence.

    Attributes:
        waypoints: per-waypoint results in path order.
        T_wp_gun: the relative pose that was held, shape (4, 4) [mm]; None for a hand-written plan that records none
            (nothing is then drawn or checked as the target).
        models: model kind per robot, e.g. ``{"R1": "cdc", "R2": "constant"}``.
    """

    waypoints: tuple[WaypointResult, ...]
    T_wp_gun: np.ndarray | None
    models: dict[str, str]

    @property
    def converged(self) -> bool:
        return all(w.converged for w in self.waypoints)

    @property
    def failed(self) -> list[int]:
        """Indices of waypoints that must not be executed."""
        return [i for i, w in enumerate(self.waypoints) if not w.converged]

    def q(self) -> np.ndarray:
        """Joint angles of all waypoints [rad], shape (N, 12): R1 then R2."""
        return np.array([np.concatenate([w.q_R1, w.q_R2]) for w in self.waypoints])

    def to_dict(self) -> dict[str, Any]:
        """The plan file content (schema ``cellcal.plan/1``)."""
        wps = []
        for w in self.waypoints:
            wps.append({"R1": w.q_R1.tolist(), "R2": w.q_R2.tolist(), "converged": w.converged, "reason": w.reason,
                        "residual_mm": w.residual_mm, "residual_deg": w.residual_deg, "track_mm": w.track_mm,
                        "clearance_mm": w.clearance_mm, "solve_ms": w.solve_ms})
        return {"schema": PLAN_SCHEMA, "kind": "dual", "models": self.models, "T_wp_gun": None if self.T_wp_gun is None else self.T_wp_gun.tolist(),
                "converged": self.converged, "waypoints": wps}

    @classmethod
    def from_dict(cls, d: dict[str, Any], source: str | Path = "<plan>") -> PlanResult:
        """A :class:`PlanResult` from a plan file's content; entries without ``converged: true`` count as unsolved.

        Raises:
            DataError: not a dual plan, or joint vectors that are not 6 finite numbers.
        """
        if not isinstance(d, dict) or d.get("schema") != PLAN_SCHEMA or not isinstance(d.get("waypoints"), list):
            raise DataError(source, None, None, f"expected a dual plan (schema {PLAN_SCHEMA!r} with 'waypoints')")
        models = d.get("models", {})
        if not isinstance(models, dict) or not all(isinstance(k, str) and isinstance(v, str)
                                                   for k, v in models.items()):
            raise DataError(source, None, "models", f"expected the model kind per robot, e.g. {{\"R1\": \"constant\", "
                                                    f"\"R2\": \"constant\"}}, got {str(models)[:80]}")
        out = []
        for i, w in enumerate(d["waypoints"]):
            if not isinstance(w, dict) or not {"R1", "R2"} <= set(w):
                raise DataError(source, None, None, f"waypoint {i}: expected R1 and R2 with 6 finite numbers each "
                                                    "[rad]; it names no robot pair")
            q1, q2 = (np.full(0, np.nan) if v is None else v for v in (json_numbers(w["R1"]), json_numbers(w["R2"])))
            if q1.shape != (6,) or q2.shape != (6,) or not np.all(np.isfinite(np.r_[q1, q2])):
                raise DataError(source, None, None, f"waypoint {i}: expected R1 and R2 with 6 finite numbers each [rad]")
            ok = w.get("converged") is True
            nan = float("nan")
            claims = {}
            for key in ("residual_mm", "residual_deg", "track_mm", "clearance_mm", "solve_ms"):
                v = w.get(key)
                if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float)) or abs(v) > 1e300):
                    raise DataError(source, None, None, f"waypoint {i}: {key} must be a number, got {str(v)[:40]!r}")
                claims[key] = nan if v is None else float(v)
            reason = w.get("reason", "")
            reason = reason if isinstance(reason, str) else str(reason)[:200]
            out.append(WaypointResult(q1, q2, claims["residual_mm"], claims["residual_deg"], claims["track_mm"], nan,
                                      claims["clearance_mm"], nan, claims["solve_ms"], 0, ok,
                                      reason if ok else (reason or "not marked converged")))
        if d.get("T_wp_gun") is None:
            return cls(tuple(out), None, dict(models))
        T = json_numbers(d["T_wp_gun"])
        T = np.full(0, np.nan) if T is None else T
        if T.shape != (4, 4) or not np.all(np.isfinite(T)) or not np.allclose(T[3], [0, 0, 0, 1]):
            raise DataError(source, None, "T_wp_gun", "expected a 4x4 homogeneous transform of finite numbers [mm]")
        return cls(tuple(out), T, dict(models))


def save_plan(plan: PlanResult, path: str | Path) -> None:
    """Write the plan file (JSON, schema ``cellcal.plan/1``) atomically."""
    atomic_write_text(Path(path), json.dumps(plan.to_dict(), indent=1))
