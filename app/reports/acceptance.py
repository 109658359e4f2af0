"""Acceptance against a tolerance (:class:`Tolerance`, :func:`acceptance`) and the ISO 9283 table of a report."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from calibration.data.recording import Recording
from calibration.errors import CellCalError
from calibration.evaluation.iso9283 import RepeatedPose, accuracy_per_pose, repeated_poses
from calibration.evaluation.metrics import Errors, predict


@dataclass(frozen=True)
class Tolerance:
    """The acceptance tolerance: largest position error [mm] and largest orientation error [deg]."""

    position_mm: float = 1.0
    orientation_deg: float = 1.0

    def __post_init__(self) -> None:
        for name, v in (("--tolerance-mm", self.position_mm), ("--tolerance-deg", self.orientation_deg)):
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise CellCalError(f"{name}: expected a positive finite number, got {v!r}")


@dataclass(frozen=True)
class Acceptance:
    """Pass/fail of one model on the evaluation poses.

    Attributes:
        model: row name.
        n_poses: evaluation poses.
        max_position_mm, max_orientation_deg: largest errors on them.
        within: fraction of poses with both errors within the tolerance; None when per-pose errors are not kept.
        passed: both largest errors within the tolerance.
    """

    model: str
    n_poses: int
    max_position_mm: float
    max_orientation_deg: float
    within: float | None
    passed: bool


def acceptance(name: str, e: Errors, tol: Tolerance) -> Acceptance:
    """Pass/fail of one model from its per-pose errors."""
    pos, ori = np.asarray(e.position_mm), np.asarray(e.orientation_deg)
    ok = (pos <= tol.position_mm) & (ori <= tol.orientation_deg)
    max_p, max_o = float(np.max(pos)), float(np.max(ori))
    return Acceptance(name, len(pos), max_p, max_o, float(np.mean(ok)),
                      bool(max_p <= tol.position_mm and max_o <= tol.orientation_deg))


def acceptance_from_max(name: str, n: int, max_mm: float, max_deg: float, tol: Tolerance) -> Acceptance:
    """Pass/fail from the largest errors alone (the fraction within is then not available)."""
    return Acceptance(name, n, float(max_mm), float(max_deg), None,
                      bool(max_mm <= tol.position_mm and max_deg <= tol.orientation_deg))


@dataclass(frozen=True)
class IsoTable:
    """ISO 9283 figures of one recording: the repeated poses with RP_l, and AP_p per model (or why not)."""

    source: str
    poses: list[RepeatedPose] = field(default_factory=list)
    ap_mm: dict[str, np.ndarray] = field(default_factory=dict)
    reason: str | None = None

    @property
    def min_visits(self) -> int:
        return min(r.n for r in self.poses)

    @property
    def max_visits(self) -> int:
        return max(r.n for r in self.poses)


def iso_table(models: dict[str, Any], rec: Recording, label: str) -> IsoTable:
    """ISO 9283 AP_p (per model) and RP_l on the poses ``rec`` repeats; ``label`` names the recording."""
    poses = repeated_poses(rec.q, rec.p)
    if not poses:
        return IsoTable(label, reason=f"no repeated poses (no two rows of {label} have identical joint values)")
    return IsoTable(label, poses, {n: accuracy_per_pose(poses, rec.p, predict(m, rec)[1]) for n, m in models.items()})


def iso_unavailable(label: str, reason: str) -> IsoTable:
    return IsoTable(label, reason=reason)
