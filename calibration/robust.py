"""Robustness checks of configuration-dependent (CDC) fits on the training recording alone.

Two checks, both blind to any test recording:

- **Held-out clusters.** The anchors are split into folds of whole clusters (the 7-pose groups); for each
  fold the interpolator is refitted on the other clusters' local parameters and the CDC model predicts the
  held-out clusters' poses. The figure is the position RMS over all held-out poses [mm], next to the same
  figure for the constant reference (the global fit the local fits are pulled toward). :func:`held_out` keeps
  the reference fitted on every cluster and chooses the strengths of :mod:`calibration.methods` (local prior,
  ridge); the check that flags an interpolator worse than the constant fit on clusters it has not seen
  summarises (:func:`summarise`) fold refits of the whole method and of its reference
  (:meth:`calibration.methods.Fitter.held_out_errors`, which the model selection of ``compare`` reuses).
- **Corrections over the workspace.** The CDC model's position correction over the reference at probe
  configurations spread over the joint limits (wrist and base joints anywhere, (q2, q3) at the anchors, so the
  interpolation itself stays in range) should be about as large as on the training poses: local fits that
  absorb directions a 7-pose cluster cannot see show up as corrections several times larger there. The
  figure is the ratio of the 99th percentiles [-].
- **Range at probe configurations.** The interpolated geometric parameters at a grid of (q2, q3) spread over
  the anchors' box widened by ``margin`` must stay near the range the local fits span: the excess beyond
  [min, max] per parameter, in units of that parameter's range, is reported (0 = inside).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from calibration.interpolation.base import Interpolator
from calibration.physics_informed import ExtendedKinematics
from calibration.recording import Recording

#: Default number of held-out folds (whole clusters).
N_FOLDS = 5
#: A CDC fit whose held-out RMS exceeds the reference's by this factor is flagged.
HELDOUT_RATIO_LIMIT = 1.25
#: A CDC fit whose workspace correction (p99) exceeds its training correction by this factor is flagged; the
#: local prior is chosen among the strengths that stay below it.
WORKSPACE_RATIO_LIMIT = 2.0
#: A CDC fit whose parameters at a probe leave the anchors' range by more than this (x range) is flagged.
RANGE_EXCESS_LIMIT = 5.0


@dataclass(frozen=True)
class HeldOut:
    """Held-out-cluster figures of one fit.

    Attributes:
        rms_mm: position RMS over the held-out poses of the CDC model [mm].
        reference_rms_mm: same for the constant reference.
        max_mm: worst held-out position error of the CDC model [mm].
        reference_max_mm: same for the reference.
        se_rms_mm: standard error of rms_mm over clusters [mm] (delta method on the per-cluster mean squares).
    """

    rms_mm: float
    reference_rms_mm: float
    max_mm: float
    reference_max_mm: float
    se_rms_mm: float

    @property
    def ratio(self) -> float:
        return self.rms_mm / max(self.reference_rms_mm, 1e-12)


def cluster_folds(n_clusters: int, n_folds: int = N_FOLDS, seed: int = 0) -> np.ndarray:
    """Fold (0..n_folds-1) of each cluster: a seeded shuffle dealt round-robin, shape (K,)."""
    order = np.random.default_rng(seed).permutation(n_clusters)
    folds = np.empty(n_clusters, dtype=int)
    folds[order] = np.arange(n_clusters) % n_folds
    return folds


def position_errors(kin: ExtendedKinematics, theta: np.ndarray, rec: Recording) -> np.ndarray:
    """Position error norm per sample [mm] of parameters theta (N, size) or (size,) on rec."""
    theta = np.broadcast_to(theta, (len(rec), kin.size))
    _, p = kin.pose(rec.q, np.ascontiguousarray(theta))
    return np.linalg.norm(rec.p - p, axis=1)


def held_out(make: Callable[[], Interpolator], kin: ExtendedKinematics, theta_ref: np.ndarray,
             anchors: np.ndarray, x_local: np.ndarray, groups: np.ndarray, rec: Recording,
             inputs: tuple[int, ...], clamp: bool = True, n_folds: int = N_FOLDS, seed: int = 0) -> HeldOut:
    """Held-out-cluster error of the interpolator ``make()`` over the local fits.

    Args:
        make: a new unfitted interpolator.
        kin, theta_ref: the CDC kinematics and its reference parameters.
        anchors: (K, d) interpolation inputs of the anchors; x_local (K, g) their local geometric parameters.
        groups: cluster index (0..K-1) of each sample of rec.
        rec: the training recording.
        inputs: joint indices the interpolator reads.
        clamp: clip predictions to the training folds' per-parameter range (as the fitted model does).
    """
    folds = cluster_folds(len(anchors), n_folds, seed)
    g = x_local.shape[1]
    err = np.empty(len(rec))
    for f in range(n_folds):
        train, test = folds != f, folds == f
        interp = make().fit(anchors[train], x_local[train])
        idx = np.flatnonzero(test[groups])
        q = rec.q[idx]
        x = interp.predict(q[:, list(inputs)])
        if clamp:
            x = np.clip(x, x_local[train].min(axis=0), x_local[train].max(axis=0))
        theta = np.array(np.broadcast_to(theta_ref, (len(idx), kin.size)))
        theta[:, :g] = x
        err[idx] = position_errors(kin, theta, rec.subset(idx))
    return summarise(err, position_errors(kin, theta_ref, rec), groups)


def summarise(err: np.ndarray, reference_err: np.ndarray, groups: np.ndarray) -> HeldOut:
    """:class:`HeldOut` of per-sample held-out position errors err (N,) [mm] against the reference's (N,), with
    the cluster index (0..K-1) of each sample."""
    per_cluster = np.bincount(groups, err ** 2) / np.maximum(np.bincount(groups), 1)
    rms = float(np.sqrt(np.mean(err ** 2)))
    se = float(per_cluster.std(ddof=1) / np.sqrt(len(per_cluster)) / (2.0 * max(rms, 1e-12)))
    return HeldOut(rms, float(np.sqrt(np.mean(reference_err ** 2))), float(err.max()), float(reference_err.max()), se)


def one_se_choice(strengths: tuple[float, ...], scores: list[HeldOut]) -> int:
    """Index of the strongest regularisation whose held-out RMS is within one standard error of the best
    (the one-standard-error rule: among fits the data cannot tell apart, the most regularised)."""
    best = int(np.argmin([s.rms_mm for s in scores]))
    limit = scores[best].rms_mm + scores[best].se_rms_mm
    ok = [i for i, s in enumerate(scores) if s.rms_mm <= limit]
    return max(ok, key=lambda i: strengths[i])


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
    return ((np.maximum(predicted - hi, 0.0) + np.maximum(lo - predicted, 0.0)) / width).max(axis=1)


def workspace_probes(anchors_q23: np.ndarray, joint_limits: tuple[np.ndarray, np.ndarray] | None, n_joints: int,
                     inputs: tuple[int, ...], n: int = 2000, seed: int = 0) -> np.ndarray:
    """Joint configurations (n, n_joints) [rad]: the interpolation inputs at random anchors, every other joint
    uniform within ``joint_limits`` (within +-pi when None)."""
    rng = np.random.default_rng(seed)
    lo, hi = (np.full(n_joints, -np.pi), np.full(n_joints, np.pi)) if joint_limits is None else joint_limits
    q = rng.uniform(lo, hi, (n, n_joints))
    q[:, list(inputs)] = anchors_q23[rng.integers(0, len(anchors_q23), n)]
    return q


def workspace_ratio(fk: Callable, reference_fk: Callable, q_train: np.ndarray, q_probe: np.ndarray) -> tuple[float, float, float]:
    """``(ratio, p99 probe [mm], p99 train [mm])`` of the position correction ``|p(q) - p_ref(q)|``."""
    train = np.percentile(np.linalg.norm(fk(q_train)[1] - reference_fk(q_train)[1], axis=1), 99)
    probe = np.percentile(np.linalg.norm(fk(q_probe)[1] - reference_fk(q_probe)[1], axis=1), 99)
    return float(probe / max(train, 1e-9)), float(probe), float(train)
