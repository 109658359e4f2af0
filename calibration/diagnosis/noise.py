"""The measurement noise floor of each channel (position, orientation): what a perfect model would still leave.

Two estimates per channel of the RMS error *norm* that noise alone causes (``sqrt(3) sigma`` for isotropic
noise of standard deviation ``sigma`` per axis), in mm for the position and in degrees for the orientation:

- *within clusters*: samples of one cluster are a few degrees apart, so a smooth residual barely changes
  inside a cluster and its scatter about the cluster mean is repeatability;
- *after the full fit*: the residual of the final model, corrected for the parameters it fitted.

The floor is the smaller of the two (the first is inflated by effects that change sample to sample, such
as backlash; the second by anything the final model still misses).

The two floors weigh the channels against each other (:func:`channel_weight`): the evidence for an effect is
a Gaussian likelihood with one variance per channel, so the orientation counts by its own noise rather than by
a fixed exchange rate between millimetres and degrees.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: Bounds of the estimated orientation weight relative to the fixed one (a factor 1000 either way: beyond it one
#: channel's noise estimate is degenerate, e.g. noise-free simulated orientations).
WEIGHT_RANGE = 1e3


@dataclass(frozen=True)
class NoiseFloor:
    """Noise-floor estimates per channel (RMS of the error norm); ``nan`` when not available.

    Attributes:
        floor_mm: position floor, the smaller of the two position estimates [mm].
        within_cluster_mm: position scatter about each cluster's mean [mm].
        fit_residual_mm: position residual of the final fit, corrected for its parameters [mm].
        floor_deg: orientation floor [deg].
        within_cluster_deg: orientation scatter about each cluster's mean [deg].
        fit_residual_deg: orientation residual of the final fit, corrected for its parameters [deg].
    """

    floor_mm: float
    within_cluster_mm: float
    fit_residual_mm: float
    floor_deg: float = float("nan")
    within_cluster_deg: float = float("nan")
    fit_residual_deg: float = float("nan")


def within_cluster_rms(residual: np.ndarray, groups: np.ndarray) -> float:
    """Pooled scatter of residual vectors (N, 3) about their cluster means; nan without repeats."""
    _, idx, counts = np.unique(groups, return_inverse=True, return_counts=True)
    dof = int(np.sum(counts - 1))
    if dof <= 0:
        return float("nan")
    means = np.stack([np.bincount(idx, residual[:, k]) / counts for k in range(3)], axis=1)
    return float(np.sqrt(np.sum((residual - means[idx]) ** 2) / dof))


def _channel(residual: np.ndarray, groups: np.ndarray, correction: float) -> tuple[float, float, float]:
    fit = float(np.sqrt(np.mean(np.sum(residual**2, axis=1)) * correction))
    within = within_cluster_rms(residual, groups)
    return (fit if not np.isfinite(within) else min(fit, within)), within, fit


def noise_floor(residual: np.ndarray, groups: np.ndarray, n_parameters: int, w_rot: float | None = None
                ) -> NoiseFloor:
    """Noise floors from a weighted residual (N, 6) on the fit data.

    Args:
        residual: residual ``[p (mm); w_rot * rotation (rad)]``, shape (N, 6).
        groups: cluster id per sample (N,).
        n_parameters: parameters the model fitted.
        w_rot: the rotation scale of ``residual``; None leaves the orientation floors unestimated.
    """
    residual = np.asarray(residual, dtype=float)
    n_res = residual.size
    correction = n_res / max(n_res - n_parameters, 1)
    pos = _channel(residual[:, :3], groups, correction)
    if w_rot is None or w_rot <= 0:
        return NoiseFloor(*pos)
    rot = _channel(np.degrees(residual[:, 3:] / w_rot), groups, correction)
    return NoiseFloor(*pos, *rot)


def channel_weight(noise: NoiseFloor, a_fixed: float) -> tuple[float, str]:
    """The orientation weight ``a`` that whitens both channels, and a note when it could not be estimated.

    With per-axis standard deviations ``s_p`` [mm] and ``s_r`` [rad], the Gaussian likelihood with one variance
    per channel is, up to the common factor ``1 / s_p^2``, the least-squares cost with rotation residuals scaled
    by ``s_p / s_r``, i.e. ``a = (s_p / s_r)^2 / 2`` (see
    :func:`calibration.identification.rotation_residual_scale`).

    Args:
        noise: the floors of both channels.
        a_fixed: the fixed weight, used when a floor is missing and bounding the estimate.
    """
    s_p, s_r = noise.floor_mm, math.radians(noise.floor_deg) if np.isfinite(noise.floor_deg) else float("nan")
    if not (np.isfinite(s_p) and np.isfinite(s_r) and s_p > 0 and s_r > 0):
        return a_fixed, f"the noise floors could not be estimated; the orientation weight stays a = {a_fixed:g}"
    a = 0.5 * (s_p / s_r) ** 2
    lo, hi = a_fixed / WEIGHT_RANGE, a_fixed * WEIGHT_RANGE
    if not lo <= a <= hi:
        bounded = min(max(a, lo), hi)
        return bounded, (f"the noise floors ({noise.floor_mm:.3g} mm, {noise.floor_deg:.3g} deg) give an orientation "
                         f"weight a = {a:.3g}, outside {lo:.3g}..{hi:.3g}; it is bounded to {bounded:.3g}")
    return a, ""
