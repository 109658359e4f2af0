"""Configuration-dependent calibration: local identification per cluster, then interpolation.

Every cluster (an anchor pose and its +1 deg neighbours) gets its own minimal parameter vector from one
batched identification of all clusters at once. Each cluster's fit is pulled toward a global fit by a weak
ridge prior (in millimetre-equivalent units), so directions a 7-sample cluster cannot see stay at the
global values instead of absorbing noise. The local parameters are then interpolated over the anchors'
shoulder and elbow angles (q2, q3).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import numpy as np

from calibration.errors import ModelError
from calibration.identification import GeometricProblem
from calibration.models import CdcModel
from calibration.observability import Observability
from calibration.parameterisation import MinimalParameterisation
from calibration.recording import Recording

log = logging.getLogger("cellcal.calibration")
CDC_INPUTS = (1, 2)  # q2, q3 (0-based)


@dataclass(frozen=True)
class LocalFits:
    """Per-cluster parameters.

    Attributes:
        anchors: interpolation inputs of each cluster's anchor (q2, q3) [rad], shape (K, 2).
        x: local parameters, shape (K, m).
        rms_mm: position RMS of each local fit [mm], shape (K,).
        x_global: the global fit the local fits were pulled toward, shape (m,).
        converged: per cluster, shape (K,).
        seconds: wall time of the batched local fits.
    """

    anchors: np.ndarray
    x: np.ndarray
    rms_mm: np.ndarray
    x_global: np.ndarray
    converged: np.ndarray
    seconds: float


def cluster_anchors(rec: Recording, cluster_size: int = 7) -> tuple[np.ndarray, np.ndarray]:
    """Cluster index (0..K-1) of each sample and the anchor joint angles (K, 6) (the first sample of each)."""
    ids = rec.clusters(cluster_size)
    uniq, first, index = np.unique(ids, return_index=True, return_inverse=True)
    return index, rec.q[first]


def fit_local(par: MinimalParameterisation, rec: Recording, x_global: np.ndarray, obs: Observability,
              a: float, prior: float, cluster_size: int = 7) -> LocalFits:
    """Identify every cluster's parameters in one batched problem.

    Args:
        par: parameterisation.
        rec: training recording with clusters.
        x_global: global fit used as each cluster's reference, shape (m,).
        obs: observability of the whole set (its scale converts parameters to millimetre equivalents).
        a: orientation weight.
        prior: ridge strength toward ``x_global`` [1/mm-equivalent].
    """
    if prior <= 0:
        raise ModelError(f"local prior must be > 0 (clusters cannot see every direction), got {prior}")
    groups, anchor_q = cluster_anchors(rec, cluster_size)
    start = time.perf_counter()
    problem = GeometricProblem(par, rec.q, rec.R, rec.p, groups=groups, a=a, prior_weight=prior / obs.scale,
                               x_ref=x_global)
    res = problem.solve()
    seconds = time.perf_counter() - start
    if not res.converged.all():
        log.warning("%d of %d local fits stopped before converging", int((~res.converged).sum()), len(res.x))
    return LocalFits(anchor_q[:, list(CDC_INPUTS)], res.x, res.rms_mm, np.asarray(x_global), res.converged, seconds)


def build_cdc(robot: str, method: str, par: MinimalParameterisation, local: LocalFits, **options: object) -> CdcModel:
    """Fit interpolator ``method`` (nearest, linear, cubic, rbf, fbf13, fbf7, nn, ae) to the local parameters."""
    from calibration.interpolation import make_interpolator

    interp = make_interpolator(method, **options).fit(local.anchors, local.x)
    n_params = local.x.shape[1] * _effective_terms(interp, local.x.shape[0])
    return CdcModel(robot, method, par, interp, CDC_INPUTS, {"n_parameters": int(n_params), "clusters": len(local.x)})


def _effective_terms(interp: object, n_anchors: int) -> int:
    """Number of stored values per parameter: basis size for Fourier kinds, anchors for the rest."""
    coefficients = getattr(interp, "coefficients", None)
    if coefficients is not None:
        return int(np.asarray(coefficients).shape[-1])
    return n_anchors
