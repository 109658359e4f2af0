"""Registration of the motion-capture world to a robot base, and of the tool marker to the flange.

Model, for every sample i (poses in millimetres)::

    T_world_marker_i = T_world_base @ T_base_flange(q_i) @ T_flange_marker

with the nominal flange pose ``T_base_flange`` of a :class:`~calibration.kinematics.poe.PoeModel` (its tool dropped). The
12 unknowns are found by a closed-form hand-eye (AX = YB) solution, rotations first, then refined by
Levenberg-Marquardt on perturbations ``delta = [dp_wb, dth_wb, dp_fm, dth_fm]`` (12,): ``p <- p + dp`` and
``R <- exp(dth) R``, each in the transform's parent frame (world for T_world_base, flange for T_flange_marker),
so sigmas are those of the printed translation entries [mm] and of small rotations about the parent axes [deg].
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Protocol

import numpy as np

from calibration.errors import DataError, ModelError, UnsafeTarget
from calibration.identification import DEFAULT_ORIENTATION_WEIGHT, rotation_residual_scale
from calibration.identification.observability import DEFAULT_REACH_MM
from calibration.kinematics import so3
from calibration.kinematics.arrays import FloatArray
from calibration.kinematics.poe import PoeModel
from calibration.kinematics.so3 import make_T

#: Below this RMS rotation [deg] about a principal axis, the poses do not rotate about that axis.
MIN_ROTATION_SPREAD_DEG = 2.0


class DegenerateRegistration(DataError):
    """The poses cannot determine the registration; the message says which motion is missing.

    Attributes:
        n_samples: number of poses.
        spread_deg: RMS rotation of the flange about its three principal axes [deg], descending, shape (3,).
    """

    def __init__(self, reason: str, n_samples: int, spread_deg: np.ndarray) -> None:
        self.n_samples = n_samples
        self.spread_deg = np.asarray(spread_deg, dtype=float)
        super().__init__("registration poses", None, None, reason)


@dataclass(frozen=True)
class RegistrationResult:
    """Outcome of :meth:`RegistrationProblem.solve`.

    Attributes:
        T_world_base, T_flange_marker: the transforms (4, 4) [mm].
        rms_mm, rms_deg, max_mm, max_deg: position / orientation residuals over the samples.
        residual_mm, residual_deg: per sample, shape (N,).
        sigma_world_base, sigma_flange_marker: 1-sigma of ``[p (3) mm, rotation (3) deg]``, parent frame, (6,).
        cond: condition number of the weighted Jacobian (rotation columns scaled to mm at 1 m reach).
        converged: the cost settled before ``max_iterations`` and the damping never blew up.
        iterations: LM iterations over both passes.
        n_samples: N.
    """

    T_world_base: np.ndarray
    T_flange_marker: np.ndarray
    rms_mm: float
    rms_deg: float
    max_mm: float
    max_deg: float
    residual_mm: np.ndarray
    residual_deg: np.ndarray
    sigma_world_base: np.ndarray
    sigma_flange_marker: np.ndarray
    cond: float
    converged: bool
    iterations: int
    n_samples: int


class HasWorldBase(Protocol):
    """A registration: RegistrationResult or cell_config's RobotRegistration."""

    T_world_base: np.ndarray


def _project_rotation(M: np.ndarray) -> np.ndarray:
    """Nearest rotation matrix (Frobenius) to a 3x3 matrix."""
    U, _, Vt = np.linalg.svd(M)
    R: FloatArray = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    return R


def transform_difference(T_a: np.ndarray, T_b: np.ndarray) -> tuple[float, float]:
    """``(|p_a - p_b| [mm], angle of R_a R_b^T [deg])`` of two rigid transforms (4, 4)."""
    dp = float(np.linalg.norm(T_a[:3, 3] - T_b[:3, 3]))
    return dp, float(np.degrees(np.linalg.norm(so3.log(T_a[:3, :3] @ T_b[:3, :3].T))))


def relative_base(reg_R1: HasWorldBase, reg_R2: HasWorldBase) -> np.ndarray:
    """R2's base in R1's base frame, ``T_R1base_R2base`` (4, 4) [mm], from two registrations in one mocap world."""
    T_w1, T_w2 = np.asarray(reg_R1.T_world_base, dtype=float), np.asarray(reg_R2.T_world_base, dtype=float)
    R1_T = T_w1[:3, :3].T
    return make_T(R1_T @ T_w2[:3, :3], R1_T @ (T_w2[:3, 3] - T_w1[:3, 3]))


class RegistrationProblem:
    """Registration from joint angles and measured marker poses, built once and then solved.

    Args:
        model: the nominal arm; its tool (``R_flange_tool``, ``p_flange_tool``) is ignored for the kinematics.
        q: joint angles [rad], shape (N, 6).
        R_world_marker: measured marker orientations in the mocap world, shape (N, 3, 3).
        p_world_marker: measured marker positions [mm], shape (N, 3).
        T_flange_marker_guess: prior guess of the marker in the flange frame (4, 4) [mm]; None takes the model's
            tool. Only a second starting point: the closed-form solution needs no guess.
        a: orientation weight of the first pass (``a = 1641``: 1 deg weighs as 1 mm, as in identification).

    Raises:
        ModelError: shapes do not match or values are not finite.
        DegenerateRegistration: fewer than 3 poses, or their orientations do not span two rotation axes.
    """

    def __init__(self, model: PoeModel, q: np.ndarray, R_world_marker: np.ndarray, p_world_marker: np.ndarray,
                 T_flange_marker_guess: np.ndarray | None = None, a: float = DEFAULT_ORIENTATION_WEIGHT) -> None:
        q = np.atleast_2d(np.asarray(q, dtype=float))
        if not np.isfinite(q).all():
            raise ModelError("joint angles and marker poses must be finite (no NaN or inf)")
        flange = replace(model, R_flange_tool=np.eye(3), p_flange_tool=np.zeros(3))
        R_bf, p_bf = flange.fk(q)
        guess = make_T(model.R_flange_tool, model.p_flange_tool) if T_flange_marker_guess is None \
            else T_flange_marker_guess
        self._setup(R_bf, p_bf, R_world_marker, p_world_marker, guess, a)
        self.q: np.ndarray | None = q  # None when built from flange poses
        self._check_motion()

    @classmethod
    def from_poses(cls, R_base_flange: np.ndarray, p_base_flange: np.ndarray, R_world_marker: np.ndarray,
                   p_world_marker: np.ndarray, T_flange_marker_guess: np.ndarray | None = None,
                   a: float = DEFAULT_ORIENTATION_WEIGHT, check_motion: bool = True) -> RegistrationProblem:
        """The same problem around any pose function: ``T_world_marker_i = T_world_base @ T_i @ T_flange_marker``.

        Args:
            R_base_flange, p_base_flange: the inner poses ``T_i`` (N, 3, 3), (N, 3) [mm] (a flange, or a whole
                fitted model's tool pose, see :mod:`calibration.frames.rebase`).
            R_world_marker, p_world_marker: measured poses, as in the constructor.
            T_flange_marker_guess: second starting point (4, 4) [mm]; None: identity.
            a: orientation weight.
            check_motion: raise :class:`DegenerateRegistration` when the poses do not rotate about two axes
                (False for callers that hold the unseen directions themselves).
        """
        self = cls.__new__(cls)
        self._setup(R_base_flange, p_base_flange, R_world_marker, p_world_marker,
                    np.eye(4) if T_flange_marker_guess is None else T_flange_marker_guess, a)
        self.q = None
        if check_motion:
            self._check_motion()
        return self

    def _setup(self, R_bf: np.ndarray, p_bf: np.ndarray, R_world_marker: np.ndarray, p_world_marker: np.ndarray,
               guess: np.ndarray, a: float) -> None:
        """Store and check the inner poses, the measured poses and the flange-marker guess."""
        self.R_bf, self.p_bf = np.asarray(R_bf, dtype=float), np.asarray(p_bf, dtype=float)
        self.n_samples = N = self.p_bf.shape[0] if self.p_bf.ndim == 2 else 0
        if self.R_bf.shape != (N, 3, 3) or self.p_bf.shape != (N, 3):
            raise ModelError(f"inner poses must be (N, 3, 3) and (N, 3), got {self.R_bf.shape} and {self.p_bf.shape}")
        self.R_meas = np.asarray(R_world_marker, dtype=float)
        self.p_meas = np.asarray(p_world_marker, dtype=float)
        if self.R_meas.shape != (N, 3, 3) or self.p_meas.shape != (N, 3):
            raise ModelError(f"marker poses must be (N, 3, 3) and (N, 3) for N = {N} joint samples, "
                             f"got {self.R_meas.shape} and {self.p_meas.shape}")
        if not (np.isfinite(self.R_bf).all() and np.isfinite(self.p_bf).all() and np.isfinite(self.R_meas).all()
                and np.isfinite(self.p_meas).all()):
            raise ModelError("joint angles and marker poses must be finite (no NaN or inf)")
        guess = np.asarray(guess, dtype=float)
        if guess.shape != (4, 4):
            raise ModelError(f"T_flange_marker_guess must be (4, 4), got {guess.shape}")
        self.T_flange_marker_guess = make_T(_project_rotation(guess[:3, :3]), guess[:3, 3])
        self.w_a = rotation_residual_scale(a)

    def _check_motion(self) -> None:
        """Raise unless there are 3 poses whose flange orientations rotate about two non-parallel axes.

        Two axes are the minimum of AX = YB (each rotation fixes the lever arms normal to its axis); three
        (the wrist joints 4, 5, 6) condition the translations better.
        """
        N = self.n_samples
        how = ("rotate the tool about at least two non-parallel axes (better three: move each wrist joint 4, 5 "
               f"and 6 by {5 * MIN_ROTATION_SPREAD_DEG:.0f} deg or more, see registration_plan)")
        if N < 3:
            raise DegenerateRegistration(f"got {N} poses, at least 3 are needed; {how}", N, np.zeros(3))
        rel = so3.log(self.R_bf @ self.R_bf[0].T)  # (N, 3) rotation vectors [rad]
        spread = np.degrees(np.linalg.svd(rel, compute_uv=False)) / math.sqrt(N)
        if spread[0] < MIN_ROTATION_SPREAD_DEG:
            reason = f"all {N} poses have the same tool orientation (rotation spread {spread[0]:.3g} deg)"
        elif spread[1] < MIN_ROTATION_SPREAD_DEG:
            reason = (f"the {N} poses rotate the tool about one axis only (spread about the principal axes "
                      f"{np.round(spread, 3).tolist()} deg)")
        else:
            return
        raise DegenerateRegistration(f"{reason}, below {MIN_ROTATION_SPREAD_DEG} deg: the marker offset and base "
                                     f"rotation are not determined; {how}", N, spread)

    def predict(self, T_world_base: np.ndarray, T_flange_marker: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Predicted marker poses in the world: ``(R (N, 3, 3), p (N, 3) [mm])``."""
        R_wb, p_wb = T_world_base[:3, :3], T_world_base[:3, 3]
        R_wf = R_wb @ self.R_bf
        p = (R_wf @ T_flange_marker[:3, 3]) + self.p_bf @ R_wb.T + p_wb
        return R_wf @ T_flange_marker[:3, :3], p

    def residuals(self, T_world_base: np.ndarray, T_flange_marker: np.ndarray, w_rot: float | None = None
                  ) -> np.ndarray:
        """``[p_meas - p; w_rot * log(R_meas R^T)]`` (N, 6) [mm]; ``w_rot`` [mm/rad] defaults to ``sqrt(2a)``."""
        R, p = self.predict(T_world_base, T_flange_marker)
        w = self.w_a if w_rot is None else w_rot
        return np.concatenate([self.p_meas - p, w * so3.log(self.R_meas @ np.swapaxes(R, 1, 2))], axis=1)

    def jacobian(self, T_world_base: np.ndarray, T_flange_marker: np.ndarray, w_rot: float | None = None
                 ) -> np.ndarray:
        """``d residuals / d delta`` (N, 6, 12), ``delta`` as in :func:`retract` (mm, rad)."""
        R, p = self.predict(T_world_base, T_flange_marker)
        w = self.w_a if w_rot is None else w_rot
        e = so3.log(self.R_meas @ np.swapaxes(R, 1, 2))
        Jinv = w * so3.right_jacobian_inv(e)  # (N, 3, 3)
        R_wf = T_world_base[:3, :3] @ self.R_bf
        J = np.zeros((self.n_samples, 6, 12))
        J[:, :3, 0:3] = -np.eye(3)
        J[:, :3, 3:6] = so3.hat(p - T_world_base[:3, 3])
        J[:, :3, 6:9] = -R_wf
        J[:, 3:, 3:6] = -Jinv
        J[:, 3:, 9:12] = -Jinv @ R_wf
        return J

    def initial_guess(self) -> tuple[np.ndarray, np.ndarray]:
        """Closed-form ``(T_world_base, T_flange_marker)``: rotations by SVD, then translations by least squares.

        With ``X = R_flange_marker^T``: ``R_meas X = R_world_base R_bf`` is linear in ``(vec X, vec R_wb)``
        (column-major vec, ``vec(A X B) = (B^T kron A) vec X``); its null vector, rescaled to unit determinant
        and projected on SO(3), gives both rotations. Then ``[R_wb R_bf, I] [p_fm; p_wb] = p_meas - R_wb p_bf``.
        """
        N, I3 = self.n_samples, np.eye(3)
        K_x = np.einsum("ij,nkl->nikjl", I3, self.R_meas).reshape(N, 9, 9)
        K_y = np.einsum("nji,kl->nikjl", self.R_bf, I3).reshape(N, 9, 9)
        v = np.linalg.svd(np.concatenate([K_x, -K_y], axis=2).reshape(9 * N, 18))[2][-1]
        X, Y = v[:9].reshape(3, 3, order="F"), v[9:].reshape(3, 3, order="F")
        scale = np.cbrt(np.linalg.det(X))
        R_fm, R_wb = _project_rotation(X / scale).T, _project_rotation(Y / scale)
        return self._translations(R_wb, R_fm)

    def _translations(self, R_wb: np.ndarray, R_fm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Least-squares translations for given rotations."""
        N = self.n_samples
        M = np.concatenate([R_wb @ self.R_bf, np.broadcast_to(np.eye(3), (N, 3, 3))], axis=2).reshape(3 * N, 6)
        b = (self.p_meas - self.p_bf @ R_wb.T).reshape(-1)
        x = np.linalg.lstsq(M, b, rcond=None)[0]
        return make_T(R_wb, x[3:]), make_T(R_fm, x[:3])

    def _from_guess(self) -> tuple[np.ndarray, np.ndarray]:
        """Start from the flange-marker guess: world rotation by Procrustes, then translations."""
        R_fm = self.T_flange_marker_guess[:3, :3]
        R_wb = _project_rotation(np.einsum("nij,nkj->ik", self.R_meas, self.R_bf @ R_fm))
        return self._translations(R_wb, R_fm)

    def _lm(self, T_wb: np.ndarray, T_fm: np.ndarray, w_rot: float, max_iterations: int, tol: float = 1e-10
            ) -> tuple[np.ndarray, np.ndarray, float, int, bool]:
        """Levenberg-Marquardt on ``delta``: ``(T_wb, T_fm, cost, iterations, converged)``.

        Converged when the Gauss-Newton predicted decrease is below ``tol`` times the cost (or the residual RMS
        is below 1e-9 mm); not converged when the damping exceeds 1e8 or ``max_iterations`` is reached first.
        """
        r = self.residuals(T_wb, T_fm, w_rot).ravel()
        cost, lam, floor = float(r @ r), 1e-3, 1e-18 * r.size
        for it in range(1, max_iterations + 1):
            J = self.jacobian(T_wb, T_fm, w_rot).reshape(-1, 12)
            A, g = J.T @ J, J.T @ r
            diag = np.diag(A) + 1e-12
            if cost <= floor or g @ np.linalg.solve(A + 1e-12 * np.diag(diag), g) <= tol * cost:
                return T_wb, T_fm, cost, it - 1, True
            while True:
                step = np.linalg.solve(A + lam * np.diag(diag), -g)
                T_wb_try, T_fm_try = retract(T_wb, T_fm, step)
                r_try = self.residuals(T_wb_try, T_fm_try, w_rot).ravel()
                if float(r_try @ r_try) < cost:
                    T_wb, T_fm, r, cost, lam = T_wb_try, T_fm_try, r_try, float(r_try @ r_try), max(lam / 3, 1e-9)
                    break
                lam *= 4.0
                if lam > 1e8:
                    return T_wb, T_fm, cost, it, False
        return T_wb, T_fm, cost, max_iterations, False

    def solve(self, max_iterations: int = 100) -> RegistrationResult:
        """Closed form, then two LM passes; the second weights each channel by its own estimated noise.

        Pass 1 weights rotations by ``sqrt(2a)`` from both the closed form and the flange-marker guess, keeping
        the lower cost. Its residuals give the position and orientation noises ``s_p`` [mm] and ``s_r`` [rad]
        (:meth:`_channel_noise`); pass 2 weights rotations by ``s_p / s_r`` (within a factor 100 of ``sqrt(2a)``,
        so noiseless data stay well posed). Sigmas assume white residuals: unmodelled kinematic errors count as
        noise.
        """
        runs = [self._lm(T_wb, T_fm, self.w_a, max_iterations) for T_wb, T_fm in (self.initial_guess(),
                                                                                  self._from_guess())]
        T_wb, T_fm, _, it1, ok1 = min(runs, key=lambda run: run[2])
        s_p, s_r = self._channel_noise(T_wb, T_fm)
        w = float(np.clip(s_p / s_r, self.w_a / 100.0, self.w_a * 100.0))
        T_wb, T_fm, _, it2, ok2 = self._lm(T_wb, T_fm, w, max_iterations)
        sigma = self._sigmas(T_wb, T_fm, w)
        R, p = self.predict(T_wb, T_fm)
        res_mm = np.linalg.norm(self.p_meas - p, axis=1)
        res_deg = np.degrees(np.linalg.norm(so3.log(self.R_meas @ np.swapaxes(R, 1, 2)), axis=1))
        return RegistrationResult(
            T_world_base=T_wb, T_flange_marker=T_fm, rms_mm=float(np.sqrt(np.mean(res_mm**2))),
            rms_deg=float(np.sqrt(np.mean(res_deg**2))), max_mm=float(res_mm.max()), max_deg=float(res_deg.max()),
            residual_mm=res_mm, residual_deg=res_deg, sigma_world_base=sigma[:6], sigma_flange_marker=sigma[6:],
            cond=self.condition_number(T_wb, T_fm), converged=bool(ok1 and ok2), iterations=it1 + it2,
            n_samples=self.n_samples)

    def _channel_noise(self, T_wb: np.ndarray, T_fm: np.ndarray) -> tuple[float, float]:
        """``(s_p [mm], s_r [rad])``: ``s^2 = sum |residual|^2 / (3N - 6)`` per channel, floored at 1e-12.

        The 12 parameters' degrees of freedom are split evenly between the two channels.
        """
        r = self.residuals(T_wb, T_fm, 1.0)
        dof = 3 * self.n_samples - 6
        return (max(math.sqrt(np.sum(r[:, :3] ** 2) / dof), 1e-12),
                max(math.sqrt(np.sum(r[:, 3:] ** 2) / dof), 1e-12))

    def _sigmas(self, T_wb: np.ndarray, T_fm: np.ndarray, w_rot: float) -> np.ndarray:
        """1-sigma of ``delta`` (12,) [mm, deg] by the sandwich ``H^-1 J^T diag(W S) J H^-1``.

        ``J`` is weighted by ``w_rot``, ``S`` holds the per-channel noises re-estimated here; this is the usual
        ``s_p^2 H^-1`` when ``w_rot = s_p / s_r``.
        """
        s_p, s_r = self._channel_noise(T_wb, T_fm)
        J = self.jacobian(T_wb, T_fm, w_rot).reshape(-1, 12)
        H_inv = np.linalg.pinv(J.T @ J)
        noise = np.tile([s_p**2] * 3 + [(w_rot * s_r) ** 2] * 3, self.n_samples)
        sigma = np.sqrt(np.diag(H_inv @ (J.T * noise) @ J @ H_inv))
        sigmas: FloatArray = sigma * np.tile([1.0] * 3 + [math.degrees(1.0)] * 3, 2)
        return sigmas

    def condition_number(self, T_world_base: np.ndarray, T_flange_marker: np.ndarray,
                         reach_mm: float = DEFAULT_REACH_MM) -> float:
        """Condition number of the ``sqrt(2a)``-weighted Jacobian, rotation columns in mm at ``reach_mm``."""
        J = self.jacobian(T_world_base, T_flange_marker).reshape(-1, 12)
        s = np.linalg.svd(J * np.tile([1.0] * 3 + [1.0 / reach_mm] * 3, 2), compute_uv=False)
        return float(s[0] / s[-1]) if s[-1] > 0 else math.inf


def retract(T_world_base: np.ndarray, T_flange_marker: np.ndarray, delta: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray]:
    """Apply ``delta = [dp_wb, dth_wb, dp_fm, dth_fm]`` (12,) [mm, rad]: ``p + dp``, ``exp(dth) R`` in each parent."""
    d = np.asarray(delta, dtype=float)
    return (make_T(so3.exp(d[3:6]) @ T_world_base[:3, :3], T_world_base[:3, 3] + d[0:3]),
            make_T(so3.exp(d[9:12]) @ T_flange_marker[:3, :3], T_flange_marker[:3, 3] + d[6:9]))


def registration_plan(lower_rad: np.ndarray, upper_rad: np.ndarray, q_center: np.ndarray, *, n_spread: int = 8,
                      sweep_deg: float = 20.0, margin_deg: float = 5.0, seed: int = 0) -> np.ndarray:
    """A short registration plan (1 + 2n + n_spread poses) [rad], shape (M, n).

    ``q_center``, then each joint alone to ``-sweep`` and ``+sweep`` about it, then ``n_spread`` random poses with
    every joint uniform within the same band. The band of a joint whose limit is nearer than ``sweep + margin``
    ends at ``limit - margin`` (the plan is generated, no user target is clamped).

    Raises:
        ModelError: shapes differ or ``sweep_deg``/``margin_deg``/``n_spread`` are negative.
        UnsafeTarget: ``q_center`` is outside the limits minus the margin.
    """
    lo, hi, qc = (np.asarray(v, dtype=float).ravel() for v in (lower_rad, upper_rad, q_center))
    if not lo.shape == hi.shape == qc.shape:
        raise ModelError(f"lower_rad, upper_rad and q_center must have one value per joint, got "
                         f"{lo.shape}, {hi.shape}, {qc.shape}")
    if sweep_deg < 0 or margin_deg < 0 or n_spread < 0:
        raise ModelError(f"sweep_deg, margin_deg and n_spread must be >= 0, got {sweep_deg}, {margin_deg}, {n_spread}")
    margin = math.radians(margin_deg)
    lo_m, hi_m = lo + margin, hi - margin
    for j in np.flatnonzero((qc < lo_m) | (qc > hi_m)):
        raise UnsafeTarget("registration plan", int(j) + 1, float(qc[j]), float(np.clip(qc[j], lo_m[j], hi_m[j])),
                           f"q_center must keep {margin_deg} deg from the joint limits")
    band_lo = np.maximum(qc - math.radians(sweep_deg), lo_m)
    band_hi = np.minimum(qc + math.radians(sweep_deg), hi_m)
    n = qc.size
    single = np.repeat(qc[None], 2 * n, axis=0)
    single[2 * np.arange(n), np.arange(n)] = band_lo
    single[2 * np.arange(n) + 1, np.arange(n)] = band_hi
    spread = np.random.default_rng(seed).uniform(band_lo, band_hi, (n_spread, n))
    return np.concatenate([qc[None], single, spread])
