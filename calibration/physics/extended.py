"""The physics-informed kinematics: geometry plus what the diagnosis of the real R1 data found.

Beyond the minimal POE geometry (27 parameters with the flange shift), the model carries
- the tool-marker rotation (3): ``R_flange_tool <- R_flange_tool exp(w)``;
- joint compliance under gravity in the mass-free form (5): with ``u = q2 - q3`` (the forearm angle),
  ``dq2 = c1 sin q2 + c2 cos u + c3 sin u`` and ``dq3 = c4 cos u + c5 sin u``, the shape of the shoulder and
  elbow gravity torques of a planar two-link arm with unknown lumped masses; added to q before the kinematics;
- a smooth structural deflection (6 x 7): a small pose correction ``xi = F7(q2, q3) C`` (translation mm,
  rotation rad) in the joint-1 frame, ``F7 = [1, sin q2, sin q3, cos q2, cos q3, sin(q2+q3), cos(q2+q3)]``,
  which takes up link bending that joint compliance alone cannot represent.
The blocks after the geometry are declared once (:data:`BLOCKS`); :class:`ExtendedKinematics` derives its
sizes, names, offsets, pose, analytic Jacobian and casadi expression from that declaration, the diagnosis its
effect blocks (:mod:`calibration.diagnosis.extended`), and the compliance block's deflection is the one
:class:`~calibration.physics.extended.MassFreeCompliance` definition. The fitted model kind is
:mod:`calibration.models.pi`.
All terms are fitted jointly by the batched LM (``Fitter.physics_informed``) with a Tikhonov filter on the
joint, mm-scaled Jacobian: directions whose singular value is below 1 % of the largest are damped toward
nominal, so what the data cannot see stays near the vendor arm.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, ClassVar

import numpy as np

from calibration.errors import ModelError
from calibration.kinematics import so3
from calibration.kinematics.blocks import Block
from calibration.kinematics.casadi_expr import (
    NUMPY,
    CasadiPose,
    Ops,
    casadi_ops,
    check_small_rotations,
    exp_sx,
    poe_chain,
    rot_sx,
)
from calibration.kinematics.parameterisation import MinimalParameterisation
from calibration.kinematics.poe import PoeModel
from calibration.physics.base import Effect, Term
from calibration.physics.context import Context, check_q
from calibration.physics.layout import (
    _TAIL_SIZES,
    BLOCKS,
    COMPLIANCE_NAMES,
    DEFLECTION_TERMS,
    EZ,
    TOOL_NAMES,
    block_slice,
    check_registration_parts,
    deflection_basis,
    deflection_terms,
)


@dataclass(frozen=True, eq=False)
class ExtendedEffect(Effect, register=False):
    """An effect whose values add to one block of the ``pi`` parameters (after the geometric block).

    The blocks are declared once, in :data:`calibration.physics.layout.BLOCKS`; ``block_name`` names one.
    """

    block_name: ClassVar[str] = ""

    def block(self, n_geometric: int) -> slice:
        """Where its values sit in ``theta`` of an ``ExtendedKinematics`` with ``n_geometric`` geometry."""

        return block_slice(self.block_name, n_geometric)

    def pose_jacobian(self, model: PoeModel, q: np.ndarray, context: Context | None = None) -> np.ndarray:
        """First-order pose change per parameter on a POE model: its block's columns of the ``pi`` Jacobian
        at ``theta = 0`` around that model."""
        pass

        q = check_q(model, q)
        kin = ExtendedKinematics(MinimalParameterisation(model, fit_tool=True))
        return kin.jacobian(q, np.zeros(kin.size))[2][..., self.block(kin.par.size)]




@dataclass(frozen=True, eq=False)
class MassFreeCompliance(ExtendedEffect):
    """Gravity-shaped deflection of joints 2 and 3 with unknown masses, ``u = q2 - q3``:
    ``dq2 = c1 sin q2 + c2 cos u + c3 sin u``, ``dq3 = c4 cos u + c5 sin u`` [rad] (values ``c1..c5``)."""

    kind = "joint_compliance"
    context_keys = frozenset()
    form: ClassVar[str] = "mass_free"
    block_name: ClassVar[str] = "compliance"
    joints: tuple[int, ...] = (2, 3)
    values: np.ndarray = field(default_factory=lambda: np.zeros(len(COMPLIANCE_NAMES)))

    @property
    def names(self) -> tuple[str, ...]:
        return COMPLIANCE_NAMES

    def fitted_joints(self, n: int) -> tuple[int, ...]:
        return ()  # a gravity torque's shape: it extrapolates by its formula

    def joint_terms(self, ops: Ops, q: list[Any], chain: Any, context: Context | None, N: int) -> list[Term]:
        u = q[1] - q[2]
        return [(1, 0, ops.sin(q[1])), (1, 1, ops.cos(u)), (1, 2, ops.sin(u)), (2, 3, ops.cos(u)),
                (2, 4, ops.sin(u))]

    def pose_jacobian(self, model: Any, q: np.ndarray, context: Context | None = None) -> np.ndarray:
        return Effect.pose_jacobian(self, model, q, context)  # a joint effect: jacobian_q @ regressor




_COMPLIANCE = MassFreeCompliance()  # the one definition of the compliance block's joint deflection


def compliance_regressor(q: np.ndarray) -> np.ndarray:
    """d(dq)/dc, shape (N, 6, 5): gravity-shaped joint deflections of joints 2 and 3 (mass-free form)."""
    Y = np.zeros((q.shape[0], 6, len(COMPLIANCE_NAMES)))
    for j, col, v in _COMPLIANCE.joint_terms(NUMPY, list(q.T), lambda: None, None, q.shape[0]):
        Y[:, j, col] = v
    return Y


@dataclass(frozen=True)
class ExtendedKinematics:
    """Geometry (minimal POE) + tool rotation + gravity compliance + structural deflection.

    Layout of theta: the geometric block then :data:`BLOCKS`, ``[x (27), w_tool (3), c (5), C (7 x 6,
    row-major)]``, 77 parameters. :meth:`pose`, :meth:`jacobian` and :meth:`casadi` all read that layout.
    """

    par: MinimalParameterisation

    def blocks(self) -> tuple[Block, ...]:
        return (Block("geometry", tuple(self.par.names())),) + BLOCKS

    @property
    def sizes(self) -> tuple[int, ...]:
        """Block sizes in layout order (without building the names: called per solver iteration)."""
        return (self.par.size,) + _TAIL_SIZES

    @property
    def size(self) -> int:
        return sum(self.sizes)

    def names(self) -> list[str]:
        return [n for b in self.blocks() for n in b.names]

    def registration_mask(self, parts: str = "all") -> np.ndarray:
        """Which parameters (m,) describe where the tool marker sits on the flange rather than the arm.

        Args:
            parts: ``rotation`` (the tool-marker rotation), ``shift`` (the flange-point shift, with ``fit_tool``),
                ``all`` (both) or ``none``.

        They are a measurement set-up's registration, which the vendor's nominal arm knows nothing about; the pi
        fit leaves those of ``FitOptions.pi_registration_free`` out of its damping toward nominal.
        """
        check_registration_parts(parts)
        mask = np.zeros(self.size, dtype=bool)
        if parts in ("shift", "all") and self.par.fit_tool:
            mask[self.par.size - 3: self.par.size] = True
        if parts in ("rotation", "all"):
            mask[block_slice("tool", self.par.size)] = True
        return mask

    def base_motion(self, q: np.ndarray | None = None) -> np.ndarray:
        """The parameter changes (size, 6) that move the whole arm rigidly in the measurement frame, as a small
        error of the base frame (mocap to robot base) would: column k for the k-th component of ``(w, v)``, a
        rotation w [rad] of the arm about the measurement frame's origin, then a shift v [mm].

        The minimal POE represents such a motion exactly (every joint line moves with it, the flange point and the
        tool rotation follow), in the geometric block and the tool rotation alone; found by least squares of
        ``J B = G`` over the poses q (N, 6) at nominal, G the pose change ``[dp; dtheta] = [v + w x p; w]``. B does
        not depend on the poses, so by default they are 40 generic ones (seeded, within 1 rad of zero), not a
        recording's: a training recording that barely moves some joints would make the least squares ill-posed.

        Raises:
            ModelError: the poses do not determine it (the Jacobian's columns of those blocks have a lower rank:
                too few distinct poses), or those blocks do not represent it (without ``fit_tool`` the flange point
                cannot follow the motion).
        """
        q = np.random.default_rng(0).uniform(-1.0, 1.0, (40, self.par.n_joints)) if q is None else \
            np.atleast_2d(np.asarray(q, dtype=float))
        _, p, J = self.jacobian(q, np.zeros(self.size))
        n = self.par.size + len(TOOL_NAMES)
        G = np.zeros((q.shape[0], 6, 6))
        G[:, :3, :3] = -so3.hat(p)
        G[:, :3, 3:] = np.eye(3)
        G[:, 3:, :3] = np.eye(3)
        A, b = J[:, :, :n].reshape(-1, n), G.reshape(-1, 6)
        sol, _, rank, _ = np.linalg.lstsq(A, b, rcond=None)
        if rank < n:
            raise ModelError(f"{q.shape[0]} poses do not determine the rigid motion of the arm's parameters (rank "
                             f"{rank} of {n}); give more distinct poses")
        misfit = np.linalg.norm(A @ sol - b) / np.linalg.norm(b)
        if misfit > 1e-6:
            raise ModelError(f"the geometric parameters do not represent a rigid motion of the arm on these "
                             f"{q.shape[0]} poses (relative misfit {misfit:.1e})")
        B = np.zeros((self.size, 6))
        B[:n] = sol
        return B

    def scale(self, reach_mm: float = 1000.0) -> np.ndarray:
        """Parameter units per mm of tool motion: angles (tilts, tool and deflection rotations, compliance) / reach."""
        g, t, c, _ = self.sizes
        deflect = np.tile([1.0, 1.0, 1.0, 1.0 / reach_mm, 1.0 / reach_mm, 1.0 / reach_mm], len(DEFLECTION_TERMS))
        return np.concatenate([self.par.scale(reach_mm), np.full(t + c, 1.0 / reach_mm), deflect])

    def split(self, theta: Any) -> tuple[Any, Any, Any, Any]:
        """``(x, w_tool, c, C)``; C is (..., 7, 6) for numpy arrays, the flat block for casadi."""
        g = self.par.size
        t, c, d = (block_slice(b.name, g) for b in BLOCKS)
        if isinstance(theta, np.ndarray):
            return (theta[..., :g], theta[..., t], theta[..., c],
                    theta[..., d].reshape(theta.shape[:-1] + (len(DEFLECTION_TERMS), 6)))
        return theta[:g], theta[t], theta[c], theta[d]

    def casadi(self, q: Any, theta: Any) -> CasadiPose:
        """:meth:`pose` (plus the skeleton) on casadi symbols q (6,) for one parameter vector (77,), which may
        itself be an expression; the deflection moves the skeleton with the tool."""
        import casadi as ca

        x, w_tool, c, C = self.split(theta)
        dq = _COMPLIANCE.casadi_dq(casadi_ops(), q, lambda: None, c)
        H, P = self.par.casadi_geometry(x)
        ch = poe_chain(self.par.nominal, q + ca.vertcat(*dq), H, P)
        R0 = ch.R_base_tool @ exp_sx(w_tool)
        F = deflection_terms(casadi_ops(), q[1], q[2])
        xi = [sum(F[k] * C[6 * k + j] for k in range(len(DEFLECTION_TERMS))) for j in range(6)]
        Rz = rot_sx(ca.DM(EZ), q[0])
        pose = CasadiPose(R0, ch.p_base_tool, ca.horzcat(*ch.p_base_origin), ca.horzcat(*ch.axes_base), "pi")
        return pose.transformed(exp_sx(Rz @ ca.vertcat(*xi[3:])), Rz @ ca.vertcat(*xi[:3]))

    def constant_arm(self, theta: np.ndarray) -> PoeModel:
        """The geometric block and the tool rotation of ``theta`` (size,) as one POE arm: the pose with the
        compliance and the deflection at zero."""
        x, w_tool, _, _ = self.split(np.asarray(theta, dtype=float))
        arm = self.par.model(x)
        return replace(arm, R_flange_tool=arm.R_flange_tool @ so3.exp(w_tool))

    def lost_terms(self, theta: np.ndarray) -> tuple[str, ...]:
        """What :meth:`constant_arm` leaves out of ``theta``: each non-zero block after the tool rotation."""
        _, _, c, C = self.split(np.asarray(theta, dtype=float))
        lost = []
        if np.any(c != 0):
            lost.append(f"the gravity compliance (joint deflection under the arm's weight, {c.size} parameters)")
        if np.any(C != 0):
            lost.append(f"the structural deflection (a twist and shift of the whole arm that depends on q1, q2, q3, "
                        f"{C.size} parameters)")
        return tuple(lost)

    def check_casadi(self, theta: np.ndarray) -> None:
        """ModelError unless the tool and deflection rotations of ``theta`` are in :func:`exp_sx`'s exact range."""
        _, w_tool, _, C = self.split(np.asarray(theta, dtype=float))
        bound = max(np.linalg.norm(w_tool), float(np.abs(C[:, 3:]).sum(axis=0).max()) * np.sqrt(3))
        check_small_rotations(bound, "tool or deflection")

    def _parts(self, q: np.ndarray, theta: np.ndarray, q_compliance: np.ndarray | None = None,
               q_deflection: np.ndarray | None = None) -> tuple[Any, ...]:
        q = np.atleast_2d(np.asarray(q, dtype=float))
        theta = np.broadcast_to(np.asarray(theta, dtype=float), (q.shape[0], self.size))
        x, w_tool, c, C = self.split(theta)
        Y = compliance_regressor(q if q_compliance is None else q_compliance)
        qe = q + (Y @ c[:, :, None])[..., 0]
        xi = np.einsum("nk,nkj->nj", deflection_basis(q if q_deflection is None else q_deflection), C)
        Rz = so3.rot(EZ, q[:, 0])
        w_base = (Rz @ xi[:, 3:, None])[..., 0]
        return q, theta, x, w_tool, Y, qe, xi, Rz, w_base

    def _flange_pose(self, qe: np.ndarray, x: np.ndarray, w_tool: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        R, p = self.par.pose(qe, x)
        return R @ so3.exp(w_tool), p  # the tool position is fixed in the flange frame; only its rotation moves

    def pose(self, q: np.ndarray, theta: np.ndarray, q_compliance: np.ndarray | None = None,
             q_deflection: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Tool pose ``(R (N, 3, 3), p (N, 3) [mm])`` at joint angles q (N, 6) [rad] for parameters theta (size,)
        or (N, size); ``q_compliance`` and ``q_deflection`` (N, 6), when given, are the angles the compliance's and
        the deflection's terms are evaluated at instead of q (how ``scripts/studies/extrapolation_folds.py`` scores either
        term held at the edge of the training range; a ``pi`` model evaluates both at q)."""
        q, theta, x, w_tool, _, qe, xi, Rz, w_base = self._parts(q, theta, q_compliance, q_deflection)
        R0, p0 = self._flange_pose(qe, x, w_tool)
        E = so3.exp(w_base)
        return E @ R0, (E @ p0[:, :, None])[..., 0] + (Rz @ xi[:, :3, None])[..., 0]

    def jacobian_q(self, q: np.ndarray, theta: np.ndarray) -> np.ndarray:
        """``d[p; rotation] / dq`` (N, 6, 6) with the compliance and the deflection held at their values at q."""
        _, _, x, _, _, qe, _, _, w_base = self._parts(q, theta)
        J0 = self.par.nominal.jacobian_q(qe, *self.par.geometry(x))
        E = so3.exp(w_base)
        return np.concatenate([E @ J0[:, :3], E @ J0[:, 3:]], axis=1)

    def deflection_rotation(self, q: np.ndarray, theta: np.ndarray) -> np.ndarray:
        """The rotation (N, 3, 3) the structural deflection applies to the whole arm, in the base frame."""
        return so3.exp(self._parts(q, theta)[8])

    def geometry_view(self, theta_ref: np.ndarray) -> GeometryView:
        """The geometric block alone as kinematics, with every other term fixed at ``theta_ref``."""
        return GeometryView(self, np.asarray(theta_ref, dtype=float))

    def jacobian(self, q: np.ndarray, theta: np.ndarray, geometry_only: bool = False
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pose and ``d[p; theta_rot] / d theta``, shape (N, 6, 77), or (N, 6, 27) with ``geometry_only``."""
        q, theta, x, w_tool, Y, qe, xi, Rz, w_base = self._parts(q, theta)
        N = q.shape[0]
        g, t, c, _ = self.sizes
        E = so3.exp(w_base)
        R_side, p0, Jx, Jq = self.par.jacobians(qe, x)
        R0 = R_side @ so3.exp(w_tool)  # the tool position is fixed in the flange frame; only its rotation moves
        if geometry_only:
            Jg = np.concatenate([E @ Jx[:, :3], E @ Jx[:, 3:]], axis=1)
            return E @ R0, (E @ p0[:, :, None])[..., 0] + (Rz @ xi[:, :3, None])[..., 0], Jg
        J0 = np.zeros((N, 6, g + t + c))
        J0[:, :, :g] = Jx
        # R0 = R_side exp(w_tool): a change dw rotates the tool by R0 J_r(w_tool) dw (base frame), J_r(w) = J_l(-w).
        J0[:, 3:, g:g + t] = R0 @ so3.left_jacobian(-w_tool)
        J0[:, :, g + t:] = Jq @ Y
        # The deflection rotates everything by E = exp(w_base) and shifts it by Rz v.
        J = np.empty((N, 6, self.size))
        J[:, :3, : g + t + c] = E @ J0[:, :3]
        J[:, 3:, : g + t + c] = E @ J0[:, 3:]
        p_rot = (E @ p0[:, :, None])[..., 0]
        Jl = so3.left_jacobian(w_base) @ Rz  # d w_base-equivalent rotation / d w
        F = deflection_basis(q)  # (N, 7)
        dp_dv = Rz
        dp_dw = -so3.hat(p_rot) @ Jl
        blocks = np.concatenate([np.concatenate([dp_dv, dp_dw], axis=2),
                                 np.concatenate([np.zeros((N, 3, 3)), Jl], axis=2)], axis=1)  # (N, 6, 6)
        J[:, :, g + t + c:] = (blocks[:, :, None, :] * F[:, None, :, None]).reshape(N, 6, -1)
        return E @ R0, p_rot + (Rz @ xi[:, :3, None])[..., 0], J


@dataclass(frozen=True)
class GeometryView:
    """Kinematics over the geometric parameters of an :class:`ExtendedKinematics`, other terms held fixed."""

    kin: ExtendedKinematics
    theta_ref: np.ndarray

    @property
    def size(self) -> int:
        return self.kin.par.size

    def names(self) -> list[str]:
        return self.kin.par.names()

    def scale(self, reach_mm: float = 1000.0) -> np.ndarray:
        return self.kin.par.scale(reach_mm)

    def full(self, x: np.ndarray) -> np.ndarray:
        """Extended parameters with geometry ``x`` (m,) or (N, m), shape (..., 77)."""
        x = np.asarray(x, dtype=float)
        theta = np.array(np.broadcast_to(self.theta_ref, x.shape[:-1] + (self.kin.size,)))
        theta[..., : self.size] = x
        return theta

    def pose(self, q: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.kin.pose(q, self.full(x))

    def jacobian(self, q: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return self.kin.jacobian(q, self.full(x), geometry_only=True)
