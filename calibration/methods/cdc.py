"""Configuration-dependent calibration: local identification per cluster, then interpolation.

Every cluster (an anchor pose and its +1 deg neighbours) gets its own minimal geometric parameter vector
from one batched identification of all clusters at once. The clusters share a global reference model: the
purely geometric global fit (the paper's construction) or the physics-informed fit (geometry, tool rotation,
gravity compliance, structural deflection; methods ``pi+...``); only the geometric block varies per cluster,
pulled toward the global values by a weak ridge prior (in millimetre-equivalent units) so directions a 7-sample
cluster cannot see stay at the global values instead of absorbing noise. The local geometric parameters are then
interpolated over the anchors' shoulder and elbow angles (q2, q3).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import numpy as np

from calibration.data.recording import Recording, standalone_mask
from calibration.errors import ModelError
from calibration.identification import GeometricProblem
from calibration.interpolation import make_interpolator
from calibration.kinematics.parameterisation import MinimalParameterisation
from calibration.models.cdc import CDC_INPUTS, CdcModel
from calibration.physics.extended import ExtendedKinematics

log = logging.getLogger("cellcal.calibration")
__all__ = ["CDC_INPUTS", "CdcModel", "LocalFits", "build_cdc", "cluster_anchors", "expand_anchors", "fit_local",
           "geometric_cdc"]


@dataclass(frozen=True)
class LocalFits:
    """Per-cluster parameters.

    Attributes:
        anchors: interpolation inputs of each cluster's anchor (q2, q3) [rad], shape (K, 2).
        x: local geometric parameters, shape (K, m).
        rms_mm: position RMS of each local fit [mm], shape (K,).
        theta_ref: the global extended-model parameters the local fits start from and are pulled toward.
        converged: per cluster, shape (K,).
        seconds: wall time of the batched local fits.
    """

    anchors: np.ndarray
    x: np.ndarray
    rms_mm: np.ndarray
    theta_ref: np.ndarray
    converged: np.ndarray
    seconds: float


def expand_anchors(anchors: np.ndarray, perturb_rad: float = np.radians(1.0)) -> tuple[np.ndarray, np.ndarray]:
    """The paper's cluster design: each anchor, then the anchor with ``perturb_rad`` on joint 1..n in turn.

    Args:
        anchors: anchor joint angles [rad], shape (K, n).

    Returns:
        ``(q (K (n+1), n), cluster (K (n+1),))``.
    """
    anchors = np.atleast_2d(np.asarray(anchors, dtype=float))
    K, n = anchors.shape
    q = np.repeat(anchors[:, None, :], n + 1, axis=1)
    q[:, 1:, :] += perturb_rad * np.eye(n)
    return q.reshape(-1, n), np.repeat(np.arange(K), n + 1)


def cluster_anchors(rec: Recording, cluster_size: int = 7) -> tuple[np.ndarray, np.ndarray]:
    """Cluster index (0..K-1) of each sample and the anchor joint angles (K, 6) (the first sample of each)."""
    ids = rec.clusters(cluster_size)
    uniq, first, index = np.unique(ids, return_index=True, return_inverse=True)
    return index, rec.q[first]


def fit_local(kin: ExtendedKinematics, rec: Recording, theta_ref: np.ndarray, a: float, prior: float,
              cluster_size: int = 7) -> LocalFits:
    """Identify every cluster's geometric parameters in one batched problem.

    Args:
        kin: the extended kinematics of the global reference model.
        rec: training recording with clusters (its stand-alone poses, if any, are left out).
        theta_ref: global fit; its non-geometric terms stay fixed, its geometry is each cluster's reference.
        a: orientation weight.
        prior: ridge strength toward the reference geometry [1/mm-equivalent].
    """
    if prior <= 0:
        raise ModelError(f"local prior must be > 0 (clusters cannot see every direction), got {prior}")
    alone = standalone_mask(rec)
    if alone.any():  # a stand-alone pose is no cluster: a local fit needs a cluster's poses around one anchor
        rec = rec.subset(~alone)
    groups, anchor_q = cluster_anchors(rec, cluster_size)
    view = kin.geometry_view(theta_ref)
    start = time.perf_counter()
    res = GeometricProblem(view, rec.q, rec.R, rec.p, groups=groups, a=a, prior_weight=prior / view.scale(),
                           x_ref=theta_ref[: view.size]).solve()
    seconds = time.perf_counter() - start
    if not res.converged.all():
        log.warning("%d of %d local fits stopped before converging", int((~res.converged).sum()), len(res.x))
    return LocalFits(anchor_q[:, list(CDC_INPUTS)], res.x, res.rms_mm, np.asarray(theta_ref), res.converged, seconds)


def geometric_cdc(par: MinimalParameterisation) -> tuple[ExtendedKinematics, np.ndarray]:
    """Kinematics and reference for a purely geometric CDC model (no physics terms): ``CdcModel(r, m, *this, i)``."""
    kin = ExtendedKinematics(par)
    return kin, np.zeros(kin.size)


def build_cdc(robot: str, method: str, kin: ExtendedKinematics, local: LocalFits, interpolator: str | None = None,
              **options: object) -> CdcModel:
    """Fit ``interpolator`` (nearest, linear, cubic, rbf, fbf13, fbf7, nn, ae; default: ``method``) to the local
    parameters; the model is named ``method`` (``pi+fbf13``: the fbf13 interpolator around the pi reference).

    The model clips the interpolated parameters to the local fits' per-parameter range, so a kind that
    extrapolates (rbf, Fourier, nn) or overshoots between anchors (cubic, ae decoding) stays within what the
    clusters measured."""

    interp = make_interpolator(interpolator or method, **options).fit(local.anchors, local.x)
    g = local.x.shape[1]
    n_params = g * _effective_terms(interp, local.x.shape[0]) + kin.size - g
    bounds = np.stack([local.x.min(axis=0), local.x.max(axis=0)])
    return CdcModel(robot, method, kin, local.theta_ref, interp, CDC_INPUTS,
                    {"n_parameters": int(n_params), "clusters": len(local.x)}, bounds)


def _effective_terms(interp: object, n_anchors: int) -> int:
    """Number of stored values per parameter: basis size for Fourier kinds, anchors for the rest."""
    coefficients = getattr(interp, "coefficients", None)
    if coefficients is not None:
        return int(np.asarray(coefficients).shape[-1])
    return n_anchors
