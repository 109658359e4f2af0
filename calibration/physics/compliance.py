"""Joint compliance: joints deflect in proportion to the gravity torque they carry.

``joint_compliance``: ``delta_q_i = c_i tau_g,i(q)`` with the arm's own gravity torque (see
:mod:`calibration.physics.gravity` for the sign: positive ``c_i`` sags). ``payload_compliance``: the same
with the torque of the payload ``payload_kg`` (context) as a point mass at the tool point. Both are linear
in the compliances ``c_i`` [rad/(N m)], one per listed joint (1-based).

``joint_compliance`` in the mass-free form (``form: mass_free``, :class:`MassFreeCompliance`), for when the
link masses are unknown: the shape of the shoulder and elbow gravity torques of a planar two-link arm with
unknown lumped masses, ``u = q2 - q3``, ``dq2 = c1 sin q2 + c2 cos u + c3 sin u``, ``dq3 = c4 cos u + c5 sin u``
[rad]. It is also the compliance block of the ``pi`` model (:mod:`calibration.physics_informed`).

Each writes its regressor once (:meth:`~calibration.physics.base.Effect.joint_terms`) for numpy and casadi;
the torques come from :func:`calibration.physics.gravity.chain_torques`. Each extrapolates by its formula (no
fitted joints for the extrapolation guard, :meth:`~calibration.physics.base.Effect.fitted_joints`): the torque's
shape in q is physics, known at every pose; only the compliances are fitted.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from calibration.casadi_expr import Ops
from calibration.physics.base import Context, Effect, ExtendedEffect, Term, check_joints, context_array
from calibration.physics.gravity import GravityModel, chain_torques

COMPLIANCE_NAMES = ("c2_sin_q2_rad", "c2_cos_u_rad", "c2_sin_u_rad", "c3_cos_u_rad", "c3_sin_u_rad")


def _select(tau: list[Any], joints: tuple[int, ...]) -> list[Term]:
    """Terms placing the torque of joint j in row j-1, column of j."""
    return [(j - 1, col, tau[j - 1]) for col, j in enumerate(joints)]


@dataclass(frozen=True, eq=False)
class JointCompliance(Effect):
    """Deflection under the arm's own weight.

    Attributes:
        gravity: lumped link inertias giving the torque (YAML estimates, or fitted).
        joints: 1-based joints that deflect, default (2, 3, 5).
        values: compliances ``c{j}_rad_per_Nm`` [rad/(N m)], one per joint.
    """

    kind = "joint_compliance"
    context_keys = frozenset()
    gravity: GravityModel
    joints: tuple[int, ...] = (2, 3, 5)
    values: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        object.__setattr__(self, "joints", check_joints(self.joints, self.gravity.n_links))
        super().__post_init__()

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(f"c{j}_rad_per_Nm" for j in self.joints)

    def fitted_joints(self, n: int) -> tuple[int, ...]:
        return ()  # a gravity torque's shape: it extrapolates by its formula

    def joint_terms(self, ops: Ops, q: list[Any], chain: Any, context: Context | None, N: int) -> list[Term]:
        return _select(chain_torques(ops, chain(), self.gravity.lumped, self.gravity.g), self.joints)

    def _config(self) -> dict[str, Any]:
        return {"joints": list(self.joints), "gravity": self.gravity.to_dict()}

    @classmethod
    def _from_config(cls, config: dict[str, Any], values: np.ndarray) -> "JointCompliance":
        return cls(GravityModel.from_dict(config["gravity"]), tuple(config["joints"]), values)


@dataclass(frozen=True, eq=False)
class PayloadCompliance(Effect):
    """Deflection under the payload carried at the tool point (context ``payload_kg``).

    Attributes:
        joints: 1-based joints that deflect, default (2, 3, 5).
        values: compliances ``c{j}_rad_per_Nm`` [rad/(N m)], one per joint.
        g: gravity magnitude [m/s^2].
    """

    kind = "payload_compliance"
    context_keys = frozenset({"payload_kg"})
    joints: tuple[int, ...] = (2, 3, 5)
    values: np.ndarray = field(default_factory=lambda: np.zeros(3))
    g: float = 9.80665

    def __post_init__(self) -> None:
        object.__setattr__(self, "joints", check_joints(self.joints))
        super().__post_init__()

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(f"c{j}_rad_per_Nm" for j in self.joints)

    def fitted_joints(self, n: int) -> tuple[int, ...]:
        return ()  # a gravity torque's shape: it extrapolates by its formula

    def joint_terms(self, ops: Ops, q: list[Any], chain: Any, context: Context | None, N: int) -> list[Term]:
        mass = context_array(context, "payload_kg", N)  # the default context (casadi): no payload
        if ops.name != "numpy":
            if not np.any(mass):
                return []
            mass = float(mass[0])
        return _select([t * mass for t in chain_torques(ops, chain(), None, self.g)], self.joints)


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
