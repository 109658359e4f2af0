"""Inverse kinematics of one arm under any model kind: Gauss-Newton on the casadi forward kinematics.

Built once per model (:class:`ArmIk`), then solved per target pose. The residual and its exact Jacobian come from
one casadi function built on the public :func:`app.dual.casadi_kinematics.casadi_fk` (the dual planner's kinematics),
so a configuration-dependent model is solved with its parameters' dependence on q; a model whose parameters
casadi cannot see (``frozen``) is solved as a fixed point, its parameters re-evaluated at every iterate, as the
planner does. Joints are kept inside the limits (a step that would cross one stops at it); the result says
honestly whether the pose was reached, with the residual recomputed by the numpy model.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from app.dual.casadi_kinematics import casadi_fk

__all__ = ["ArmIk", "IkResult", "pose_error"]

#: Weight of the rotation-matrix residual against millimetres (1 mrad ~ 1 mm).
ROTATION_WEIGHT_MM = 1000.0
#: :meth:`ArmIk.solve_near` leaves the orientation directions whose singular value (of the orientation task within
#: the position task's null space) is below this fraction of the largest. At the wrist singularity (q5 = 0) of the
#: fbf13 model of 0801 the one it leaves is ~0 (1e-3 leaves it too); at q5 = 0.3 deg reaching it exactly swings
#: joints 4 and 6 by 4.4 deg against each other, at q5 = 0.9 deg by 1.9 deg, and this fraction leaves it at both.
NEAR_RCOND = 1e-2


@dataclass(frozen=True)
class IkResult:
    """Outcome of one solve.

    Attributes:
        q: joint angles [rad], shape (6,).
        residual_mm: position error of the model at q against the target [mm].
        residual_deg: orientation error [deg].
        iterations: Gauss-Newton iterations used.
        converged: the residual is below the requested tolerance.
        at_limit: 1-based joints that ended on a joint limit (the pose may lie beyond it).
    """

    q: np.ndarray
    residual_mm: float
    residual_deg: float
    iterations: int
    converged: bool
    at_limit: tuple[int, ...] = ()
    #: solved by :meth:`ArmIk.solve_near`: the position reached, the orientation as near as the wrist allows
    #: without swinging joints 4 and 6 (``residual_deg`` is what it leaves).
    near: bool = False


def pose_error(model: Any, q: np.ndarray, R_target: np.ndarray, p_target: np.ndarray) -> tuple[float, float]:
    """Position [mm] and orientation [deg] error of ``model.fk(q)`` against a target, by the numpy model."""
    R, p = model.fk(np.asarray(q, dtype=float)[None])
    E = R_target.T @ R[0]
    s = 0.5 * np.linalg.norm([E[2, 1] - E[1, 2], E[0, 2] - E[2, 0], E[1, 0] - E[0, 1]])
    angle = np.arctan2(s, 0.5 * (np.trace(E) - 1.0))  # exact near identity, unlike arccos of the trace
    return float(np.linalg.norm(p[0] - p_target)), float(np.degrees(angle))


class ArmIk:
    """Gauss-Newton inverse kinematics of one model within joint limits.

    Args:
        model: any model :func:`casadi_fk` accepts (``ConstantModel``, ``CdcModel``, ...).
        lower, upper: joint limits [rad], shape (6,).
        tol_mm: position tolerance of a converged solve [mm]; the orientation tolerance is ``tol_mm / 1000`` rad
            (1 mm ~ 1 mrad at a metre).
        max_iter: iterations per solve.
        max_step_rad: largest joint step per iteration [rad].
    """

    def __init__(self, model: Any, lower: np.ndarray, upper: np.ndarray, tol_mm: float = 1e-7,
                 max_iter: int = 100, max_step_rad: float = 0.2) -> None:
        import casadi as ca

        self.model = model
        self.lower, self.upper = np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)
        self.tol_mm, self.max_iter, self.max_step_rad = tol_mm, max_iter, max_step_rad
        self.fk = casadi_fk(model)
        q = ca.SX.sym("q", 6)
        x = ca.SX.sym("x", self.fk.n_frozen)
        T = ca.SX.sym("T", 12)  # target rotation (column-major) then position
        R_t, p_t = ca.reshape(T[:9], 3, 3), T[9:]
        R, p, _, _ = self.fk.function(q, x)
        # all nine rotation entries: zero only at R = R_t (the skew form is zero at 180 deg turns too)
        e = ca.vertcat(p - p_t, ROTATION_WEIGHT_MM * ca.vec(R - R_t))
        self._f = ca.Function("arm_ik", [q, x, T], [e, ca.jacobian(e, q)])

    def _eval(self, q: np.ndarray, T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        e, J = self._f(q, self.fk.x0(q), T)
        return np.asarray(e).ravel(), np.asarray(J)

    def solve(self, R_target: np.ndarray, p_target: np.ndarray, q_start: np.ndarray) -> IkResult:
        """Joint angles that put the model's tool at the target pose, starting from ``q_start``.

        Args:
            R_target: target tool rotation in the base frame, shape (3, 3).
            p_target: target tool position [mm], shape (3,).
            q_start: start [rad], shape (6,) (clipped into the limits).
        """
        T = np.concatenate([np.asarray(R_target, dtype=float).ravel(order="F"), np.asarray(p_target, dtype=float)])
        q = np.clip(np.asarray(q_start, dtype=float), self.lower, self.upper)
        tol_rad = self.tol_mm * 1e-3
        it = 0
        for it in range(1, self.max_iter + 1):
            e, J = self._eval(q, T)
            if np.linalg.norm(e[:3]) < 0.1 * self.tol_mm and np.linalg.norm(e[3:]) < 0.1 * self.tol_mm:
                break
            q_new = self._step(q, np.linalg.lstsq(J, -e, rcond=1e-12)[0])
            if q_new is None:
                break
            q = q_new
        res_mm, res_deg = pose_error(self.model, q, np.asarray(R_target, dtype=float), np.asarray(p_target))
        at = tuple(int(j) + 1 for j in np.flatnonzero((q <= self.lower) | (q >= self.upper)))
        ok = res_mm <= self.tol_mm and np.radians(res_deg) <= tol_rad * 10
        return IkResult(q, res_mm, res_deg, it, bool(ok), at)

    def _step(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray | None:
        """``q + dq`` with the step's largest joint move capped at ``max_step_rad`` and the joints kept within their
        limits; None when the step no longer moves any joint."""
        big = np.abs(dq).max()
        if big > self.max_step_rad:
            dq = dq * (self.max_step_rad / big)
        q_new = np.clip(q + dq, self.lower, self.upper)
        return None if np.abs(q_new - q).max() < 1e-15 else q_new

    def solve_near(self, R_target: np.ndarray, p_target: np.ndarray, q_start: np.ndarray,
                   rcond: float = NEAR_RCOND) -> IkResult:
        """The joints nearest ``q_start`` that reach the target position and as much of its orientation as the arm
        turns to without large joint motion: Gauss-Newton steps of the position task first, the orientation task
        within its null space, that task's directions below ``rcond`` of its largest singular value left out
        (the wrist singularity: at q5 ~ 0 only q4 + q6 is determined, and the orientation about the axis normal to
        joints 4 and 5 would need a swing of both; that part of the orientation is left, and reported).

        ``converged`` says the position was reached (within ``tol_mm``); ``residual_deg`` is the orientation left.
        """
        T = np.concatenate([np.asarray(R_target, dtype=float).ravel(order="F"), np.asarray(p_target, dtype=float)])
        q = np.clip(np.asarray(q_start, dtype=float), self.lower, self.upper)
        it = 0
        for it in range(1, self.max_iter + 1):
            e, J = self._eval(q, T)
            J_p, J_r = J[:3], J[3:]
            P = np.linalg.pinv(J_p)
            dq = P @ -e[:3]
            N = np.eye(6) - P @ J_p
            q_new = self._step(q, dq + N @ (np.linalg.pinv(J_r @ N, rcond=rcond) @ (-e[3:] - J_r @ dq)))
            if q_new is None:
                break
            q = q_new
        res_mm, res_deg = pose_error(self.model, q, np.asarray(R_target, dtype=float), np.asarray(p_target))
        at = tuple(int(j) + 1 for j in np.flatnonzero((q <= self.lower) | (q >= self.upper)))
        return IkResult(q, res_mm, res_deg, it, bool(res_mm <= self.tol_mm), at, near=True)
