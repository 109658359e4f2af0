"""Backend-neutral building blocks: the same formula evaluated on numpy arrays or on casadi symbols.

A model kind or an effect writes its formula once against an :class:`Ops` (``sin``, ``cos``, ``cross``,
``dot``, ``matvec``) and a chain of frames (:class:`calibration.kinematics.poe.Chain` with numpy arrays, or
:class:`SxChain` with casadi expressions); :data:`NUMPY` evaluates it for N samples, :func:`casadi_ops` for one
configuration of casadi symbols. Per-sample numpy values have shape (N,) or (N, 3); casadi ones are SX scalars
or (3, 1) columns.

Also here: the POE chain, the minimal-parameter geometry, a division-free ``exp`` and the interpolator
expression on casadi symbols, and :class:`CasadiPose`, what every model kind's ``casadi`` method returns.
casadi is imported only inside the functions that build expressions.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from calibration.errors import ModelError

log = logging.getLogger("cellcal.calibration")

#: |w| below which :func:`exp_sx` (a truncated Rodrigues series) is exact to machine precision [rad].
MAX_SERIES_ANGLE_RAD = 0.2


@dataclass(frozen=True)
class Ops:
    """Elementwise and 3-vector operations of one backend."""

    name: str
    sin: Callable[[Any], Any]
    cos: Callable[[Any], Any]
    cross: Callable[[Any, Any], Any]
    dot: Callable[[Any, Any], Any]
    matvec: Callable[[Any, np.ndarray], Any]  # rotation (per sample) times a constant 3-vector


NUMPY = Ops("numpy", np.sin, np.cos, lambda a, b: np.cross(a, b),
            lambda a, b: np.einsum("...i,...i->...", a, b), lambda R, v: np.einsum("...ij,j->...i", R, v))


def casadi_ops() -> Ops:
    """The casadi backend (constants given as numpy arrays become DM)."""
    import casadi as ca

    def c(x: Any) -> Any:
        return ca.DM(x) if isinstance(x, np.ndarray) else x

    return Ops("casadi", ca.sin, ca.cos, lambda a, b: ca.cross(c(a), c(b)), lambda a, b: ca.dot(c(a), c(b)),
               lambda R, v: R @ ca.DM(v))


@dataclass(frozen=True)
class SxChain:
    """A POE pass on casadi symbols, indexed like :class:`calibration.kinematics.poe.Chain` (lists instead of stacks)."""

    R_base_link: list[Any]
    p_base_origin: list[Any]
    axes_base: list[Any]
    R_base_tool: Any
    p_base_tool: Any


@dataclass(frozen=True)
class CasadiPose:
    """A model's forward kinematics as casadi expressions of the joint symbols ``q`` (6,).

    Attributes:
        R, p: tool rotation (3, 3) and position (3,) [mm] in the base frame.
        origins: joint-axis points and the flange point (3, n+1) [mm] (the skeleton the capsules follow).
        axes: joint axes (3, n) in the base frame.
        kind: the model kind (``constant``, ``pi``, ``cdc``, ``cdc-frozen``, ``physics``, ``diagnosed``).
        frozen: symbols (k,) the expression also depends on, or None when it depends on q alone.
        frozen_at: ``q (6,) -> values (k,)`` with numpy, for a caller that freezes ``frozen`` at an iterate.
    """

    R: Any
    p: Any
    origins: Any
    axes: Any
    kind: str
    frozen: Any = None
    frozen_at: Callable[[np.ndarray], np.ndarray] | None = None

    def transformed(self, E: Any, shift: Any) -> CasadiPose:
        """Everything rotated by ``E`` (3, 3) then shifted by ``shift`` (3,) (a pose correction)."""
        import casadi as ca

        O = E @ self.origins + ca.repmat(shift, 1, self.origins.shape[1])
        return CasadiPose(E @ self.R, E @ self.p + shift, O, E @ self.axes, self.kind, self.frozen, self.frozen_at)


def rot_sx(h: Any, angle: Any) -> Any:
    """Rotation by ``angle`` about the unit axis h (3,) (Rodrigues)."""
    import casadi as ca

    K = ca.skew(h)
    return ca.SX.eye(3) + ca.sin(angle) * K + (1 - ca.cos(angle)) * (K @ K)


def exp_sx(w: Any) -> Any:
    """Rotation matrix of a small rotation vector w (3,) by the Rodrigues series, exact to machine precision
    for |w| < :data:`MAX_SERIES_ANGLE_RAD` (no division, so derivatives stay finite at w = 0)."""
    import casadi as ca

    t2 = ca.dot(w, w)
    a = 1 - t2 / 6 + t2**2 / 120 - t2**3 / 5040 + t2**4 / 362880
    b = 0.5 - t2 / 24 + t2**2 / 720 - t2**3 / 40320 + t2**4 / 3628800
    K = ca.skew(w)
    return ca.SX.eye(3) + a * K + b * (K @ K)


def poe_chain(model: Any, q: Any, H: Any = None, P: Any = None) -> SxChain:
    """POE forward kinematics of a :class:`~calibration.kinematics.poe.PoeModel` on casadi symbols q (n,), same convention
    as :meth:`PoeModel.chain`; ``H`` (3, n), ``P`` (3, n+1) override the model's (constants or expressions)."""
    import casadi as ca

    n = model.n_joints
    H = ca.DM(model.H) if H is None else H
    P = ca.DM(model.P) if P is None else P
    R = ca.SX.eye(3)
    p = ca.SX(P[:, 0])
    Rs, origins, axes = [R], [p], []
    for i in range(n):
        axes.append(R @ H[:, i])
        R = R @ rot_sx(H[:, i], q[i])
        p = p + R @ P[:, i + 1]
        Rs.append(R)
        origins.append(p)
    return SxChain(Rs, origins, axes, R @ ca.DM(model.R_6_tool), p + R @ ca.DM(model.p_6_tool))


def chain_pose(chain: SxChain, kind: str) -> CasadiPose:
    """The :class:`CasadiPose` of a chain (its tool pose and skeleton)."""
    import casadi as ca

    return CasadiPose(chain.R_base_tool, chain.p_base_tool, ca.horzcat(*chain.p_base_origin),
                      ca.horzcat(*chain.axes_base), kind)


def check_small_rotations(angle_bound_rad: float, what: str) -> None:
    """ModelError when a rotation the casadi form writes with :func:`exp_sx` may exceed its exact range."""
    if angle_bound_rad >= MAX_SERIES_ANGLE_RAD:
        raise ModelError(f"{what} rotation up to {angle_bound_rad:.3f} rad exceeds the {MAX_SERIES_ANGLE_RAD} rad "
                         "the casadi kinematics are exact for")


def interpolator_sx(interp: Any, u: Any, m: int, check_seed: int = 0) -> Any | None:
    """The interpolator's prediction as a casadi expression of its inputs u (d,), or None if not expressible.

    Calls the kind's declared ``interp.casadi_predict(u)`` (:meth:`Interpolator.casadi_predict`; a ModelError
    from it means the kind has no exact form); the result is compared with ``interp.predict`` at 5 random
    inputs (atol 1e-12) before it is accepted.
    """
    import casadi as ca

    d = u.shape[0]
    try:
        expr = ca.reshape(interp.casadi_predict(u), m, 1)
    except ModelError as e:  # the kind declares it has no casadi form: the caller freezes the parameters
        log.info("interpolator %s is not casadi-expressible (%s); using frozen parameters",
                 getattr(interp, "kind", type(interp).__name__), e)
        return None
    f = ca.Function("interp", [u], [expr])
    xs = np.random.default_rng(check_seed).uniform(-1.0, 1.0, (5, d))
    got = np.array([np.asarray(f(xi)).ravel() for xi in xs])
    if not np.allclose(got, interp.predict(xs), rtol=0.0, atol=1e-12):
        log.warning("casadi form of interpolator %s disagrees with predict(); using frozen parameters",
                    getattr(interp, "kind", type(interp).__name__))
        return None
    return expr


def pose_jacobians(build: Callable[[Any, Any], CasadiPose], q: np.ndarray, theta: np.ndarray,
                   wrt_theta: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Exact ``d[p; rotation] / d theta`` (N, 6, m) and ``/ dq`` (N, 6, n) of a casadi pose builder.

    Args:
        build: ``(q_sx (n,), theta_sx (m,)) -> CasadiPose`` (no frozen inputs).
        q: joint angles [rad] (N, n).
        theta: parameters (m,).
        wrt_theta: False when only ``/ dq`` is wanted: the first block is then empty (N, 6, 0) and casadi
            differentiates with respect to the joints only (a cubic CDC model's joint Jacobian of 5 poses:
            10 s of CPU -> 0.6 s).

    Rotation rows are the base-frame angular velocity ``vee(dR R^T)``, as in every numpy Jacobian here.
    """
    import casadi as ca

    q = np.atleast_2d(np.asarray(q, dtype=float))
    N, n = q.shape
    qs, ts = ca.SX.sym("q", n), ca.SX.sym("theta", theta.size)
    e = build(qs, ts)
    if e.frozen is not None:
        raise ModelError(f"a {e.kind} model has frozen casadi inputs; its exact Jacobian is not available")
    m = theta.size if wrt_theta else 0
    z = ca.vertcat(ts, qs) if wrt_theta else qs
    f = ca.Function("pose_jacobians", [qs, ts], [e.R, ca.jacobian(e.p, z), ca.jacobian(ca.vec(e.R), z)])
    F = f.map(N)
    R, Jp, JR = (np.asarray(a) for a in F(q.T, np.repeat(theta[:, None], N, axis=1)))
    R = R.reshape(3, N, 3).transpose(1, 0, 2)
    k = m + n
    Jp = Jp.reshape(3, N, k).transpose(1, 0, 2)
    dR = JR.reshape(3, 3, N, k).transpose(2, 3, 1, 0)  # rows of vec(R) are i + 3 j (column-major): (N, k, i, j)
    W = dR @ np.swapaxes(R, 1, 2)[:, None]
    Jw = np.stack([W[..., 2, 1], W[..., 0, 2], W[..., 1, 0]], axis=1)  # (N, 3, k)
    J = np.concatenate([Jp, Jw], axis=1)
    return J[:, :, :m], J[:, :, m:]
