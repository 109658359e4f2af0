"""The measurement noise floor: what a perfect model would still leave on the data.

Two estimates of the RMS position error [mm] that noise alone causes (the RMS of the error *norm*, i.e.
``sqrt(3) sigma`` for isotropic noise of standard deviation ``sigma`` per axis):

- *within clusters*: samples of one cluster are a few degrees apart, so a smooth residual barely changes
  inside a cluster and its scatter about the cluster mean is repeatability;
- *after the full fit*: the residual of the final model, corrected for the parameters it fitted.

The floor is the smaller of the two (the first is inflated by effects that change sample to sample, such
as backlash; the second by anything the final model still misses).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class NoiseFloor:
    """Noise-floor estimates [mm] (RMS of the position error norm); ``nan`` when not available.

    Attributes:
        floor_mm: the smaller of the two.
        within_cluster_mm: from the scatter of the residual about each cluster's mean.
        fit_residual_mm: from the final fit's residual, corrected for its parameters.
    """

    floor_mm: float
    within_cluster_mm: float
    fit_residual_mm: float


def within_cluster_rms(residual_p: np.ndarray, groups: np.ndarray) -> float:
    """Pooled scatter of position residuals (N, 3) [mm] about their cluster means; nan without repeats."""
    _, idx, counts = np.unique(groups, return_inverse=True, return_counts=True)
    dof = int(np.sum(counts - 1))
    if dof <= 0:
        return float("nan")
    means = np.stack([np.bincount(idx, residual_p[:, k]) / counts for k in range(3)], axis=1)
    return float(np.sqrt(np.sum((residual_p - means[idx]) ** 2) / dof))


def noise_floor(residual: np.ndarray, groups: np.ndarray, n_parameters: int) -> NoiseFloor:
    """Noise floor from the final weighted residual (N, 6) on the fit data.

    Args:
        residual: final residual ``[p (mm); w * rotation]``, shape (N, 6).
        groups: cluster id per sample (N,).
        n_parameters: parameters the final model fitted.
    """
    residual = np.asarray(residual, dtype=float)
    n_res = residual.size
    fit = float(np.sqrt(np.mean(np.sum(residual[:, :3] ** 2, axis=1)) * n_res / max(n_res - n_parameters, 1)))
    within = within_cluster_rms(residual[:, :3], groups)
    floor = fit if not np.isfinite(within) else min(fit, within)
    return NoiseFloor(floor, within, fit)
