"""Nonlinear least squares identification of minimal POE parameters.

The cost of one problem is ``sum_i |p_i - p(q_i, x)|^2 + (2a) |log(R_i R(q_i, x)^T)|^2`` (+ an optional prior),
so with the paper's weight ``a = 1641`` one millimetre of position error weighs as much as one degree of
orientation error (``2a = (180/pi)^2``). Many independent problems (one per cluster) are solved at once
by the batched Levenberg-Marquardt of :mod:`.lm` on analytic Jacobians: one vectorised pass per iteration for
all of them. :class:`GeometricProblem` supplies the residuals, the Jacobian and the prior; the solver the rest.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from calibration.errors import ModelError
from calibration.identification import lm
from calibration.identification.lm import Groups, Linearisation, LMSettings, Residuals, StopReason
from calibration.kinematics import so3
from calibration.kinematics.arrays import FloatArray


class Kinematics(Protocol):
    """A parameterised arm: what identification and observability need (MinimalParameterisation, ExtendedKinematics)."""

    @property
    def size(self) -> int: ...

    def names(self) -> list[str]: ...

    def scale(self, reach_mm: float = 1000.0) -> np.ndarray: ...

    def pose(self, q: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...

    def jacobian(self, q: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...

DEFAULT_ORIENTATION_WEIGHT = 1641.0


def check_orientation_weight(a: float, label: str = "orientation weight a") -> float:
    """``a`` when it is a finite number >= 0 (NaN or inf crashed the observability SVD with a traceback).

    Raises:
        ModelError: naming ``label`` and the value.
    """
    if not (np.isfinite(a) and a >= 0):
        raise ModelError(f"{label} must be a finite number >= 0 (1641: 1 mm ~ 1 deg), got {a:g}")
    return float(a)


def rotation_residual_scale(a: float) -> float:
    """Factor applied to rotation-vector residuals [rad] so that their square carries weight ``a``."""
    return float(np.sqrt(2.0 * check_orientation_weight(a)))


def weighted_residuals(R_meas: np.ndarray, p_meas: np.ndarray, R: np.ndarray, p: np.ndarray, w_rot: float
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Residuals ``[p_meas - p; w_rot * log(R_meas R^T)]`` (N, 6) and the rotation error vectors (N, 3)."""
    e = so3.log(R_meas @ np.swapaxes(R, -1, -2))
    return np.concatenate([p_meas - p, w_rot * e], axis=-1), e


@dataclass(frozen=True)
class NlsResult:
    """Outcome of a (batched) identification.

    Attributes:
        x: identified parameters, shape (G, m) (G = 1 for a single problem).
        cost: final cost per problem, shape (G,).
        rms_mm: final position RMS per problem [mm], shape (G,).
        iterations: iterations run (the longest-running problem's).
        converged: per problem, shape (G,): a stopping criterion on the cost or the step was met.
        seconds: wall time of the solve.
        reason: why each problem stopped (see :class:`calibration.identification.lm.StopReason`).
    """

    x: np.ndarray
    cost: np.ndarray
    rms_mm: np.ndarray
    iterations: int
    converged: np.ndarray
    seconds: float
    reason: tuple[StopReason, ...] = ()


class GeometricProblem:
    """Identification of kinematic parameters from static pose samples, built once and then solved.

    Args:
        kin: the parameterised kinematics: ``size``, ``pose(q, x)`` and ``jacobian(q, x) -> (R, p, J)`` with J rows
            ``d[p; theta] / dx`` (see :class:`Kinematics`).
        q: joint angles [rad], shape (N, n).
        R_meas: measured tool orientations, shape (N, 3, 3).
        p_meas: measured tool positions [mm], shape (N, 3).
        groups: problem index of each sample, shape (N,), values 0..G-1; None for one problem.
        a: orientation weight (``a = 1641``: 1 mm ~ 1 deg); 0 fits position only.
        basis: optional (m, k) matrix; parameters move only in its column space, ``x = x_ref + basis @ z``
            (directions outside it stay at ``x_ref``).
        prior_weight: optional (m,) weights of a Gaussian prior ``|w * (x - x_ref)|^2`` per problem, or a (p, m)
            matrix W of the prior ``|W (x - x_ref)|^2`` (a prior blind to some directions, e.g. a free base frame).
        x_ref: reference parameters (m,) or per problem (G, m); defaults to nominal (zeros).
    """

    def __init__(self, kin: Kinematics, q: np.ndarray, R_meas: np.ndarray, p_meas: np.ndarray,
                 groups: np.ndarray | None = None, a: float = DEFAULT_ORIENTATION_WEIGHT,
                 basis: np.ndarray | None = None, prior_weight: np.ndarray | None = None,
                 x_ref: np.ndarray | None = None) -> None:
        self.kin = kin
        self.q = np.atleast_2d(np.asarray(q, dtype=float))
        N = self.q.shape[0]
        if R_meas.shape != (N, 3, 3) or p_meas.shape != (N, 3):
            raise ModelError(f"measurements must be (N, 3, 3) and (N, 3) for N = {N}, got {R_meas.shape}, {p_meas.shape}")
        groups = np.zeros(N, dtype=int) if groups is None else np.asarray(groups, dtype=int)
        if groups.shape != (N,) or groups.min() < 0:
            raise ModelError("groups must be one non-negative integer per sample")
        # Samples sorted by group so per-group sums are contiguous reductions.
        order, self.groups = Groups.sorted_from_index(groups)
        self.n_groups = self.groups.n
        self.q, self.R_meas, self.p_meas, self.sample_group = self.q[order], R_meas[order], p_meas[order], groups[order]
        self.w_rot = rotation_residual_scale(a)
        m = kin.size
        self.basis = np.eye(m) if basis is None else np.asarray(basis, dtype=float)
        if self.basis.shape[0] != m:
            raise ModelError(f"basis must have {m} rows, got {self.basis.shape}")
        self.prior_weight = None if prior_weight is None else np.asarray(prior_weight, dtype=float)
        if self.prior_weight is not None and (self.prior_weight.ndim not in (1, 2) or self.prior_weight.shape[-1] != m):
            raise ModelError(f"prior_weight must be ({m},) or (p, {m}), got {self.prior_weight.shape}")
        x_ref = np.zeros(m) if x_ref is None else np.asarray(x_ref, dtype=float)
        self.x_ref = np.broadcast_to(x_ref, (self.n_groups, m)).copy()

    @property
    def shape(self) -> tuple[int, int]:
        return self.n_groups, self.basis.shape[1]

    def parameters(self, z: np.ndarray) -> np.ndarray:
        """Parameters (G, m) of the solver's variables z (G, k)."""
        x: FloatArray = self.x_ref + z @ self.basis.T
        return x

    def _prior(self, x: np.ndarray) -> np.ndarray | None:
        if self.prior_weight is None:
            return None
        if self.prior_weight.ndim == 2:
            r_prior_W: FloatArray = (x - self.x_ref) @ self.prior_weight.T
            return r_prior_W
        r_prior_w: FloatArray = self.prior_weight * (x - self.x_ref)
        return r_prior_w

    def residuals(self, z: np.ndarray) -> Residuals:
        """Weighted residual rows (N, 6) and prior residuals (G, p) at z (G, k): p = m, or the prior matrix's rows."""
        x = self.parameters(z)
        R, p = self.kin.pose(self.q, x[self.sample_group])
        return Residuals(weighted_residuals(self.R_meas, self.p_meas, R, p, self.w_rot)[0], self._prior(x))

    def linearise(self, z: np.ndarray, at: Residuals | None = None) -> Linearisation:
        """Residuals and d r / d z (N, 6, k) from one pass of the kinematics' Jacobian (``at`` is not needed)."""
        x = self.parameters(z)
        R, p, J = self.kin.jacobian(self.q, x[self.sample_group])
        r, e = weighted_residuals(self.R_meas, self.p_meas, R, p, self.w_rot)
        # d r / dx: position rows -dp; rotation rows -w * Jr^-1(e) dtheta.
        Jr = np.empty_like(J)
        Jr[:, :3] = -J[:, :3]
        Jr[:, 3:] = -self.w_rot * (so3.right_jacobian_inv(e) @ J[:, 3:])
        J_prior = None if self.prior_weight is None else (
            self.prior_weight @ self.basis if self.prior_weight.ndim == 2 else self.prior_weight[:, None] * self.basis)
        return Linearisation(Residuals(r, self._prior(x)), Jr @ self.basis, J_prior)

    def settings(self, max_iter: int = 50, tol: float = 1e-6) -> LMSettings:
        """The solver settings of :meth:`solve`: relative cost change ``tol``, step norm 1e-12, LU solves."""
        return LMSettings(max_iter=max_iter, cost_rtol=tol, step_atol=1e-12, damping0=1e-3, damping_min=1e-9,
                          diag_floor=1e-12, linear_solver="lu")

    def solve(self, z0: np.ndarray | None = None, max_iter: int = 50, tol: float = 1e-6,
              settings: LMSettings | None = None) -> NlsResult:
        """Batched Levenberg-Marquardt from ``x_ref`` (or ``x_ref + basis @ z0``); ``settings`` overrides the rest."""
        res = lm.solve(self, z0, settings or self.settings(max_iter, tol))
        r = res.residuals.r
        rms = np.sqrt(self.groups.sum(np.sum(r[:, :3] ** 2, axis=1)) / self.groups.counts)
        return NlsResult(self.parameters(res.z), res.cost, rms, int(res.iterations.max(initial=0)), res.converged,
                         res.seconds, res.reason)
