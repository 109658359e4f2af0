"""Nonlinear least squares identification of minimal POE parameters.

The cost of one problem is ``sum_i |p_i - p(q_i, x)|^2 + (2a) |log(R_i R(q_i, x)^T)|^2`` (+ an optional prior),
so with the paper's weight ``a = 1641`` one millimetre of position error weighs as much as one degree of
orientation error (``2a = (180/pi)^2``). Many independent problems (one per cluster) are solved at once
by a batched Levenberg-Marquardt on analytic Jacobians: one vectorised pass per iteration for all of them.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from calibration import so3
from calibration.errors import ModelError


class Kinematics(Protocol):
    """A parameterised arm: what identification and observability need (MinimalParameterisation, ExtendedKinematics)."""

    @property
    def size(self) -> int: ...

    def names(self) -> list[str]: ...

    def scale(self, reach_mm: float = 1000.0) -> np.ndarray: ...

    def pose(self, q: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...

    def jacobian(self, q: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...

DEFAULT_ORIENTATION_WEIGHT = 1641.0


def rotation_residual_scale(a: float) -> float:
    """Factor applied to rotation-vector residuals [rad] so that their square carries weight ``a``."""
    if a < 0:
        raise ModelError(f"orientation weight a must be >= 0, got {a}")
    return float(np.sqrt(2.0 * a))


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
        iterations: iterations run.
        converged: per problem, shape (G,).
        seconds: wall time of the solve.
    """

    x: np.ndarray
    cost: np.ndarray
    rms_mm: np.ndarray
    iterations: int
    converged: np.ndarray
    seconds: float


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
        prior_weight: optional (m,) weights of a Gaussian prior ``|w * (x - x_ref)|^2`` per problem.
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
        self.n_groups = int(groups.max()) + 1
        counts = np.bincount(groups, minlength=self.n_groups)
        if np.any(counts == 0):
            raise ModelError("every group index 0..G-1 must have at least one sample")
        # Samples sorted by group so per-group sums are contiguous reductions.
        order = np.argsort(groups, kind="stable")
        self.q, self.R_meas, self.p_meas, self.groups = self.q[order], R_meas[order], p_meas[order], groups[order]
        self._starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        self._counts = counts
        self.w_rot = rotation_residual_scale(a)
        m = kin.size
        self.basis = np.eye(m) if basis is None else np.asarray(basis, dtype=float)
        if self.basis.shape[0] != m:
            raise ModelError(f"basis must have {m} rows, got {self.basis.shape}")
        self.prior_weight = None if prior_weight is None else np.asarray(prior_weight, dtype=float)
        x_ref = np.zeros(m) if x_ref is None else np.asarray(x_ref, dtype=float)
        self.x_ref = np.broadcast_to(x_ref, (self.n_groups, m)).copy()

    def _evaluate(self, z: np.ndarray, with_jacobian: bool) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
        """Residuals (N, 6), optional Jacobian w.r.t. z (N, 6, k), and per-group cost (G,)."""
        x = self.x_ref + z @ self.basis.T
        xs = x[self.groups]
        if with_jacobian:
            R, p, J = self.kin.jacobian(self.q, xs)
        else:
            R, p = self.kin.pose(self.q, xs)
            J = None
        r, e = weighted_residuals(self.R_meas, self.p_meas, R, p, self.w_rot)
        cost = np.add.reduceat(np.sum(r * r, axis=1), self._starts)
        if self.prior_weight is not None:
            cost = cost + np.sum((self.prior_weight * (x - self.x_ref)) ** 2, axis=1)
        if J is None:
            return r, None, cost
        # d r / dx: position rows -dp; rotation rows -w * Jr^-1(e) dtheta.
        Jr = np.empty_like(J)
        Jr[:, :3] = -J[:, :3]
        Jr[:, 3:] = -self.w_rot * (so3.right_jacobian_inv(e) @ J[:, 3:])
        return r, Jr @ self.basis, cost

    def _normal_equations(self, Jz: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per-group ``J^T J`` (G, k, k) and ``J^T r`` (G, k)."""
        G, k = self.n_groups, Jz.shape[-1]
        if np.all(self._counts == self._counts[0]):  # equal groups: one batched product
            Jg = Jz.reshape(G, -1, k)
            JgT = np.swapaxes(Jg, 1, 2)
            return JgT @ Jg, (JgT @ r.reshape(G, -1, 1))[..., 0]
        JzT = np.swapaxes(Jz, 1, 2)
        return np.add.reduceat(JzT @ Jz, self._starts), np.add.reduceat((JzT @ r[:, :, None])[..., 0], self._starts)

    def solve(self, z0: np.ndarray | None = None, max_iter: int = 50, tol: float = 1e-6) -> NlsResult:
        """Batched Levenberg-Marquardt from ``x_ref`` (or ``x_ref + basis @ z0``)."""
        start = time.perf_counter()
        G, k = self.n_groups, self.basis.shape[1]
        z = np.zeros((G, k)) if z0 is None else np.broadcast_to(z0, (G, k)).copy()
        lam = np.full(G, 1e-3)
        converged = np.zeros(G, dtype=bool)
        r, Jz, cost = self._evaluate(z, True)
        Bw = None if self.prior_weight is None else self.prior_weight[:, None] * self.basis  # (m, k)
        it = 0
        for it in range(1, max_iter + 1):
            A, g = self._normal_equations(Jz, r)
            if Bw is not None:
                A += Bw.T @ Bw
                g += (z @ self.basis.T * self.prior_weight**2) @ self.basis
            diag = np.einsum("gii->gi", A) + 1e-12
            step = np.linalg.solve(A + lam[:, None, None] * (diag[:, :, None] * np.eye(k)), -g[:, :, None])[..., 0]
            step[converged] = 0.0
            r_try, _, cost_try = self._evaluate(z + step, False)
            better = cost_try < cost
            rel = np.abs(cost - cost_try) / np.maximum(cost, 1e-300)
            converged |= (better & (rel < tol)) | (np.linalg.norm(step, axis=1) < 1e-12)
            lam = np.where(better, np.maximum(lam / 3.0, 1e-9), lam * 4.0)
            converged |= lam > 1e8
            if converged.all():
                z = np.where(better[:, None], z + step, z)
                break
            if better.any():
                z = np.where(better[:, None], z + step, z)
                r, Jz, cost = self._evaluate(z, True)
        r, _, cost = self._evaluate(z, False)
        rms = np.sqrt(np.add.reduceat(np.sum(r[:, :3] ** 2, axis=1), self._starts) / self._counts)
        x = self.x_ref + z @ self.basis.T
        return NlsResult(x, cost, rms, it, converged, time.perf_counter() - start)
