"""Workspace probes of a CDC fit: configurations beyond the trained anchors (:func:`probe_grid`,
:func:`workspace_probes`), how far a prediction leaves the trained range (:func:`range_excess`) and how much worse
than its reference a fit predicts there (:func:`workspace_ratio`)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from calibration.kinematics.arrays import FloatArray

#: A model's forward kinematics, ``q (N, n) [rad] -> (R (N, 3, 3), p (N, 3) [mm])`` (``KinematicModel.fk``).
PoseFunction = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]

#: A CDC fit whose workspace correction (p99) exceeds its training correction by this factor is flagged; the
#: local prior is chosen among the strengths that stay below it.
WORKSPACE_RATIO_LIMIT = 2.0


#: A CDC fit whose parameters at a probe leave the anchors' range by more than this (x range) is flagged.
RANGE_EXCESS_LIMIT = 5.0


def probe_grid(anchors: np.ndarray, margin_rad: float = np.radians(10.0), n: int = 25) -> np.ndarray:
    """An n x n grid over the anchors' (q2, q3) box widened by ``margin_rad`` on each side, shape (n^2, 2)."""
    lo, hi = anchors.min(axis=0) - margin_rad, anchors.max(axis=0) + margin_rad
    axes = [np.linspace(a, b, n) for a, b in zip(lo, hi)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, anchors.shape[1])


def range_excess(predicted: np.ndarray, x_local: np.ndarray, floor: np.ndarray | float = 1e-12) -> np.ndarray:
    """How far each predicted row leaves the local fits' per-parameter range, in units of that range, (N,).

    Args:
        predicted: interpolated parameters, shape (N, g).
        x_local: the local fits, shape (K, g).
        floor: smallest range per parameter (g,) or scalar, for parameters the clusters all hold at the
            reference (e.g. 0.01 mm-equivalent: ``0.01 * scale``).
    """
    lo, hi = x_local.min(axis=0), x_local.max(axis=0)
    width = np.maximum(hi - lo, floor)
    excess: FloatArray = ((np.maximum(predicted - hi, 0.0) + np.maximum(lo - predicted, 0.0)) / width).max(axis=1)
    return excess


def workspace_probes(anchors_q23: np.ndarray, joint_limits: tuple[np.ndarray, np.ndarray] | None, n_joints: int,
                     inputs: tuple[int, ...], n: int = 2000, seed: int = 0) -> np.ndarray:
    """Joint configurations (n, n_joints) [rad]: the interpolation inputs at random anchors, every other joint
    uniform within ``joint_limits`` (within +-pi when None)."""
    rng = np.random.default_rng(seed)
    lo, hi = (np.full(n_joints, -np.pi), np.full(n_joints, np.pi)) if joint_limits is None else joint_limits
    q = rng.uniform(lo, hi, (n, n_joints))
    q[:, list(inputs)] = anchors_q23[rng.integers(0, len(anchors_q23), n)]
    return q


def workspace_ratio(fk: PoseFunction, reference_fk: PoseFunction, q_train: np.ndarray, q_probe: np.ndarray
                    ) -> tuple[float, float, float]:
    """``(ratio, p99 probe [mm], p99 train [mm])`` of the position correction ``|p(q) - p_ref(q)|``."""
    train = np.percentile(np.linalg.norm(fk(q_train)[1] - reference_fk(q_train)[1], axis=1), 99)
    probe = np.percentile(np.linalg.norm(fk(q_probe)[1] - reference_fk(q_probe)[1], axis=1), 99)
    return float(probe / max(train, 1e-9)), float(probe), float(train)
