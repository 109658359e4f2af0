"""ISO 9283 pose accuracy and pose repeatability (positional part) on poses a recording repeats.

ISO 9283:1998 section 7.2: a commanded pose visited n times, attained positions ``p_j`` (j = 1..n):

- positional accuracy ``AP_p = |p_bar - p_c|``, the distance from the barycentre ``p_bar`` of the attained
  positions to the commanded position ``p_c`` (here: the position a model predicts for the commanded joints);
- positional repeatability ``RP_l = l_bar + 3 S_l`` with ``l_j = |p_j - p_bar|``, ``l_bar`` their mean and
  ``S_l = sqrt(sum (l_j - l_bar)^2 / (n - 1))``.

A pose counts as repeated when the recording holds two or more rows with identical joint values (the
commanded configuration recorded again, bit for bit); the standard's own test uses n = 30 cycles, so figures
from fewer visits are noted as such by the caller. The orientation parts (AP_a,b,c, RP_a,b,c) are not computed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class RepeatedPose:
    """One commanded configuration visited several times.

    Attributes:
        rows: indices of the recording's rows that visit it, shape (n,).
        q: the joint values [rad], shape (6,).
        rp_mm: positional repeatability RP_l [mm] (independent of any model).
    """

    rows: np.ndarray
    q: np.ndarray
    rp_mm: float

    @property
    def n(self) -> int:
        return len(self.rows)

    @property
    def q_deg_text(self) -> str:
        """The joint values in degrees, for a report."""
        return ", ".join(f"{v:.2f}" for v in np.degrees(self.q))


def repeated_rows(q: np.ndarray) -> list[np.ndarray]:
    """Row indices of every group of identical joint rows with two or more members, in order of first visit.

    Args:
        q: joint values [rad], shape (N, n_joints).
    """
    q = np.asarray(q, dtype=float)
    if len(q) == 0:
        return []
    _, first, inverse, counts = np.unique(q, axis=0, return_index=True, return_inverse=True, return_counts=True)
    inverse = np.asarray(inverse).reshape(-1)
    groups = [np.flatnonzero(inverse == g) for g in np.argsort(first) if counts[g] >= 2]
    return groups


def repeatability_mm(p: np.ndarray) -> float:
    """ISO 9283 RP_l of the attained positions ``p`` [mm], shape (n >= 2, 3)."""
    p = np.asarray(p, dtype=float)
    if len(p) < 2:
        raise ValueError(f"repeatability needs at least 2 visits, got {len(p)}")
    l = np.linalg.norm(p - p.mean(axis=0), axis=1)
    return float(l.mean() + 3.0 * np.std(l, ddof=1))


def accuracy_mm(p: np.ndarray, p_commanded: np.ndarray) -> float:
    """ISO 9283 AP_p [mm]: distance of the barycentre of ``p`` (n, 3) from the commanded position (3,)."""
    return float(np.linalg.norm(np.asarray(p, dtype=float).mean(axis=0) - np.asarray(p_commanded, dtype=float)))


def repeated_poses(q: np.ndarray, p: np.ndarray) -> list[RepeatedPose]:
    """Every repeated configuration of a recording with its RP_l.

    Args:
        q: joint values [rad], shape (N, 6).
        p: measured positions [mm], shape (N, 3).
    """
    return [RepeatedPose(rows, np.asarray(q[rows[0]]), repeatability_mm(p[rows])) for rows in repeated_rows(q)]


def accuracy_per_pose(poses: list[RepeatedPose], p: np.ndarray, p_model: np.ndarray) -> np.ndarray:
    """AP_p [mm] of each repeated pose, the commanded position being the model's prediction ``p_model`` (N, 3)."""
    return np.array([accuracy_mm(p[r.rows], p_model[r.rows].mean(axis=0)) for r in poses])
