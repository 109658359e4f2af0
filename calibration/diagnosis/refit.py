"""Joint refit of geometry and physics: ``[geometric parameters; effect parameters]`` as a problem of the one
Levenberg-Marquardt solver (:mod:`calibration.identification.lm`).

The geometric parameters move only along ``basis`` (directions outside it stay at their start),
``x = x0 + basis @ z``; every effect keeps its settings and refits its ``values``. An optional Gaussian prior
(the Tikhonov filter of :func:`calibration.identification.observability.filter_weights`) pulls the geometry and
the effect values toward nominal (zero), so what the data barely see stays near nominal. The residual is exact
(POE forward kinematics with the effects applied); the Jacobian uses the analytic geometric Jacobian at the
perturbed joint angles and each effect's analytic pose Jacobian (first order in the small effects). The
parameter covariance is the Gauss-Newton one scaled by the residual variance,
``cov = s^2 (J^T J + J_prior^T J_prior)^-1`` with ``s^2 = RSS / (6N - p)``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from calibration.diagnosis.inuse import InUse
from calibration.errors import ModelError
from calibration.identification import DEFAULT_ORIENTATION_WEIGHT, lm, rotation_residual_scale, weighted_residuals
from calibration.identification.lm import Groups, Linearisation, LMSettings, Residuals, StopReason
from calibration.identification.observability import DEFAULT_RELATIVE_TOLERANCE, analyse_jacobian, filter_weights
from calibration.kinematics import so3
from calibration.kinematics.parameterisation import MinimalParameterisation
from calibration.physics.base import Effect
from calibration.physics.context import Context
from calibration.physics.extended import ExtendedEffect, ExtendedKinematics


@dataclass(frozen=True)
class JointFit:
    """Outcome of a joint geometry + physics fit.

    Attributes:
        x: geometric parameters (m,) of the parameterisation.
        effects: effects with fitted values.
        effect_std: one-sigma uncertainty of each effect's values, same shapes as their values.
        covariance: covariance of ``[z; effect values]`` (k + p_e, k + p_e).
        residual_variance: ``s^2`` per weighted residual component [mm^2].
        rms_mm: position RMS on the fit data [mm].
        n_parameters: k + the free effect directions.
        iterations: LM iterations run.
        converged: whether the solver met its stopping criterion (relative cost change below tolerance).
        seconds: wall time.
        theta: the model in use's extended parameters (77,) with ``x`` and the extended effects' values in.
        reason: why the solver stopped (see :class:`calibration.identification.lm.StopReason`).
    """

    x: np.ndarray
    effects: tuple[Effect, ...]
    effect_std: tuple[np.ndarray, ...]
    covariance: np.ndarray
    residual_variance: float
    rms_mm: float
    n_parameters: int
    iterations: int
    converged: bool
    seconds: float
    theta: np.ndarray
    reason: StopReason | None = None


def filter_prior(inuse: InUse, q: np.ndarray, context: Context | None, effects: tuple[Effect, ...],
                 a: float = DEFAULT_ORIENTATION_WEIGHT, tolerance: float = DEFAULT_RELATIVE_TOLERANCE) -> np.ndarray:
    """Prior weights (27 + p_e,) of the Tikhonov filter over the geometry and ``effects``, around nominal.

    The rule of the ``pi`` fit (:func:`calibration.identification.observability.filter_weights`) applied to the joint
    Jacobian. Each parameter is scaled to millimetres of tool motion: geometry and extended blocks by their
    kinematics' scale, a physics effect by the change that moves the weighted residual (position and
    ``sqrt(2a)`` x rotation) 1 mm RMS over the data.
    """
    theta = np.zeros(inuse.kin.size)
    J = [inuse.jacobian_geometry(q, theta)]
    scale = [inuse.par.scale()]
    names = list(inuse.par.names())
    full_scale = inuse.kin.scale()
    for e in effects:
        Je = inuse.effect_jacobian(e, q, context, theta)
        J.append(Je)
        if isinstance(e, ExtendedEffect):
            scale.append(full_scale[e.block(inuse.n_geometric)])
        else:  # both channels, weighed as in the fit: an effect seen mainly in the orientation is not inflated
            w = rotation_residual_scale(a)
            rms = np.sqrt(np.mean(np.sum(Je[:, :3] ** 2, axis=1) + w**2 * np.sum(Je[:, 3:] ** 2, axis=1), axis=0))
            scale.append(1.0 / np.maximum(rms, 1e-12))
        names += [f"{e.kind}:{n}" for n in e.names]
    obs = analyse_jacobian(np.concatenate(J, axis=-1), np.concatenate(scale), tuple(names), a, tolerance)
    return filter_weights(obs)


def _split(effects: tuple[Effect, ...], theta: np.ndarray) -> tuple[Effect, ...]:
    out, i = [], 0
    for e in effects:
        out.append(e.with_values(theta[i: i + e.size]))
        i += e.size
    return tuple(out)


class JointProblem:
    """Geometry + effects identification from static samples, built once and then solved.

    Args:
        par: geometric parameterisation.
        q: joint angles [rad], shape (N, n).
        R_meas: measured orientations (N, 3, 3).
        p_meas: measured positions [mm] (N, 3).
        context: per-sample context of the effects.
        x0: starting (and hidden-direction) geometric parameters (m,).
        basis: (m, k) observable directions of the geometric parameters.
        effects: the effects to fit (their current values are the start).
        w_rot: rotation residual scale (``sqrt(2a)``).
        effect_basis: optional (p_e, k_e) matrix; effect parameters move only in its column space from their
            start (directions the geometry absorbs stay put).
        inuse: the model in use (pi, cdc, ...) the effects are added to; None: the POE geometry of ``par``
            (``x`` is then its geometric block; for cdc a shift of the interpolated geometry).
        prior_weight: optional (m + p_e,) weights of a prior ``|w * [x; effect values]|^2`` (toward nominal).
    """

    def __init__(self, par: MinimalParameterisation, q: np.ndarray, R_meas: np.ndarray, p_meas: np.ndarray,
                 context: Context | None, x0: np.ndarray, basis: np.ndarray, effects: tuple[Effect, ...],
                 w_rot: float, effect_basis: np.ndarray | None = None, inuse: InUse | None = None,
                 prior_weight: np.ndarray | None = None) -> None:
        self.par, self.q, self.R_meas, self.p_meas, self.context = par, np.atleast_2d(q), R_meas, p_meas, context
        N = self.q.shape[0]
        if R_meas.shape != (N, 3, 3) or p_meas.shape != (N, 3):
            raise ModelError(f"measurements must be (N, 3, 3) and (N, 3) for N = {N}")
        self.x0 = np.asarray(x0, dtype=float)
        self.basis = np.asarray(basis, dtype=float)
        if self.basis.shape[0] != par.size or self.x0.shape != (par.size,):
            raise ModelError(f"x0 must be ({par.size},) and basis ({par.size}, k)")
        self.effects = tuple(effects)
        self.inuse = inuse if inuse is not None else InUse(ExtendedKinematics(par), np.zeros(ExtendedKinematics(par).size))
        if self.inuse.par.size != par.size:
            raise ModelError(f"the model in use has {self.inuse.par.size} geometric parameters, par {par.size}")
        self.w_rot = w_rot
        self.k = self.basis.shape[1]
        self.theta0 = np.concatenate([e.values for e in self.effects]) if self.effects else np.zeros(0)
        self.B = np.eye(self.theta0.size) if effect_basis is None else np.asarray(effect_basis, dtype=float)
        if self.B.shape[0] != self.theta0.size:
            raise ModelError(f"effect_basis must have {self.theta0.size} rows, got {self.B.shape}")
        self.prior_weight = None if prior_weight is None else np.asarray(prior_weight, dtype=float)
        if self.prior_weight is not None and self.prior_weight.shape != (par.size + self.theta0.size,):
            raise ModelError(f"prior_weight must be ({par.size + self.theta0.size},), got {self.prior_weight.shape}")
        J0 = np.zeros((par.size + self.theta0.size, self.k + self.B.shape[1]))
        J0[: par.size, : self.k] = self.basis
        J0[par.size:, self.k:] = self.B
        self._prior_jacobian = J0 if self.prior_weight is None else self.prior_weight[:, None] * J0

    def unpack(self, u: np.ndarray) -> tuple[np.ndarray, tuple[Effect, ...]]:
        """Geometric parameters (m,) and effects for a stacked vector ``[z; theta]``."""
        return self.x0 + self.basis @ u[: self.k], _split(self.effects, self.theta0 + self.B @ u[self.k:])

    def prior(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Prior residual (m + p_e,) and its Jacobian d/du; empty without a prior."""
        if self.prior_weight is None:
            return np.zeros(0), np.zeros((0, u.size))
        x = self.x0 + self.basis @ u[: self.k]
        values = self.theta0 + self.B @ u[self.k:]
        r = self.prior_weight * np.concatenate([x, values])
        return r, self._prior_jacobian

    @property
    def shape(self) -> tuple[int, int]:
        return 1, self.k + self.B.shape[1]

    @property
    def groups(self) -> Groups:
        return Groups.single(self.q.shape[0])

    def residuals(self, u: np.ndarray) -> Residuals:
        """The solver's view at u (1, k + k_e): weighted residual rows, prior, rotation errors as ``extra``."""
        r, e = self.residual(u[0])
        return Residuals(r, None if self.prior_weight is None else self.prior(u[0])[0][None], e)

    def linearise(self, u: np.ndarray, at: Residuals | None) -> Linearisation:
        """Residuals (``at`` when given) and the Jacobian (N, 6, k + k_e) at u (1, k + k_e)."""
        at = self.residuals(u) if at is None else at
        J = self.jacobian(u[0], at.extra)
        J_prior = None if self.prior_weight is None else self._prior_jacobian
        return Linearisation(at, J.reshape(-1, 6, J.shape[-1]), J_prior)

    def theta(self, x: np.ndarray, effects: tuple[Effect, ...]) -> tuple[np.ndarray, tuple[Effect, ...]]:
        """Extended parameters with geometry ``x`` and the extended effects in, and the other effects."""
        theta = self.inuse.theta.copy()
        theta[: self.par.size] = x
        return InUse.split_effects(theta, effects, self.par.size)

    def residual(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Weighted residuals (N, 6) and rotation error vectors (N, 3)."""
        x, effects = self.unpack(u)
        theta = self.inuse.theta.copy()
        theta[: self.par.size] = x
        R, p = self.inuse.pose(self.q, effects, self.context, theta)
        return weighted_residuals(self.R_meas, self.p_meas, R, p, self.w_rot)

    def jacobian(self, u: np.ndarray, e: np.ndarray) -> np.ndarray:
        """d residual / d u, shape (6N, k + p_e)."""
        x, effects = self.unpack(u)
        theta, rest = self.theta(x, effects)
        geo = self.inuse.geometry(theta)
        dq = sum((ef.delta_q(geo, self.q, self.context) for ef in rest if ef.target != "geometry"),
                 np.zeros_like(self.q))
        Jg = self.inuse.jacobian_geometry(self.q + dq, theta)
        blocks = [Jg @ self.basis] + [self.inuse.effect_jacobian(ef, self.q, self.context, theta) for ef in effects]
        J = np.concatenate(blocks, axis=-1)
        J = np.concatenate([J[..., : self.k], J[..., self.k:] @ self.B], axis=-1)
        Jr = np.empty_like(J)
        Jr[:, :3] = -J[:, :3]
        Jr[:, 3:] = -self.w_rot * (so3.right_jacobian_inv(e) @ J[:, 3:])
        return Jr.reshape(Jr.shape[0] * 6, J.shape[-1])

    def settings(self, max_iter: int = 40, tol: float = 1e-10) -> LMSettings:
        """The solver settings of :meth:`solve`: relative cost change ``tol``, minimum-norm (lstsq) steps."""
        return LMSettings(max_iter=max_iter, cost_rtol=tol, step_atol=0.0, damping0=1e-4, damping_min=1e-12,
                          diag_floor=1e-300, linear_solver="lstsq")

    def solve(self, max_iter: int = 40, tol: float = 1e-10, settings: LMSettings | None = None) -> JointFit:
        """Levenberg-Marquardt from ``[0; current effect values]``, then the covariance at the solution."""
        start = time.perf_counter()
        res = lm.solve(self, None, settings or self.settings(max_iter, tol))
        u, r, e = res.z[0], res.residuals.r, res.residuals.extra
        cov, s2 = self.covariance(u, r, e)
        std = np.sqrt(np.clip(np.diag(cov), 0, None))
        x, effects = self.unpack(u)
        stds, i = [], self.k
        for ef in effects:
            stds.append(std[i: i + ef.size])
            i += ef.size
        rms = float(np.sqrt(np.mean(np.sum(r[:, :3] ** 2, axis=1))))
        theta, _ = self.theta(x, effects)
        return JointFit(x, effects, tuple(stds), cov, s2, rms, u.size, int(res.iterations[0]), bool(res.converged[0]),
                        time.perf_counter() - start, theta, res.reason[0])

    def covariance(self, u: np.ndarray, r: np.ndarray, e: np.ndarray) -> tuple[np.ndarray, float]:
        """Covariance of ``[z; effect values]`` (k + p_e, k + p_e) at u and the residual variance ``s^2``."""
        J = self.jacobian(u, e)
        Jp = self.prior(u)[1]
        n_res, p = r.size, u.size
        rss = float(np.sum(r * r))
        s2 = rss / max(n_res - p, 1)
        cov = s2 * np.linalg.pinv(J.T @ J + Jp.T @ Jp)
        T = np.zeros((self.k + self.theta0.size, u.size))
        T[: self.k, : self.k] = np.eye(self.k)
        T[self.k:, self.k:] = self.B
        return T @ cov @ T.T, s2
