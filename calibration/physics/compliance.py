"""Joint compliance: joints deflect in proportion to the gravity torque they carry.

``joint_compliance``: ``delta_q_i = c_i tau_g,i(q)`` with the arm's own gravity torque (see
:mod:`calibration.physics.gravity` for the sign: positive ``c_i`` sags). ``payload_compliance``: the same
with the torque of the payload ``payload_kg`` (context) as a point mass at the tool point. Both are linear
in the compliances ``c_i`` [rad/(N m)], one per listed joint (1-based).

``joint_compliance`` in the mass-free form (``form: mass_free``, :class:`MassFreeCompliance`), for when the
link masses are unknown: the shape of the shoulder and elbow gravity torques of a planar two-link arm with
unknown lumped masses, ``u = q2 - q3``, ``dq2 = c1 sin q2 + c2 cos u + c3 sin u``, ``dq3 = c4 cos u + c5 sin u``
[rad]. It is also the compliance block of the ``pi`` model (:mod:`calibration.physics.extended`).

``joint_compliance`` in the lumped form (``form: lumped``, :class:`LumpedCompliance`), for when the link masses
and centres of mass are not the robot YAML's: each listed joint deflects by a free combination of the columns of
the gravity regressor it carries (:func:`calibration.physics.gravity.gravity_regressor`: a mass at each link's
joint point and its first moments along the link's axes), ``dq_j = sum_l b_jl Y_jl(q)``. Any rigid distribution of
mass on the links (point masses anywhere along and off each link, a tool load) gives a torque in that span, so the
shape of the own-weight deflection is the data's, not the YAML's; the wrist's position moves it too.

Each writes its regressor once (:meth:`~calibration.physics.base.Effect.joint_terms`) for numpy and casadi;
the torques come from :func:`calibration.physics.gravity.chain_torques`. Each extrapolates by its formula (no
fitted joints for the extrapolation guard, :meth:`~calibration.physics.base.Effect.fitted_joints`): the torque's
shape in q is physics, known at every pose; only the compliances are fitted.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from calibration.errors import ModelError
from calibration.kinematics.arrays import FloatArray
from calibration.kinematics.casadi_expr import Ops
from calibration.kinematics.poe import PoeModel
from calibration.physics.base import Effect, Term
from calibration.physics.context import Context, check_joints, context_array
from calibration.physics.gravity import GravityModel, chain_torque_columns, chain_torques, independent_link_columns


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
    def _from_config(cls, config: dict[str, Any], values: np.ndarray) -> JointCompliance:
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
        payload_kg = context_array(context, "payload_kg", N)  # the default context (casadi): no payload
        mass: FloatArray | float = payload_kg  # per sample (numpy), or one number (casadi)
        if ops.name != "numpy":
            if not np.any(payload_kg):
                return []
            mass = float(payload_kg[0])
        return _select([t * mass for t in chain_torques(ops, chain(), None, self.g)], self.joints)


_LUMPED_PARTS = (("m", "rad_kg_per_Nm"), ("mx", "rad_kg_mm_per_Nm"), ("my", "rad_kg_mm_per_Nm"),
                 ("mz", "rad_kg_mm_per_Nm"))


@dataclass(frozen=True, eq=False)
class LumpedCompliance(Effect):
    """Deflection under the arm's own weight with unknown link masses and centres of mass (the lumped form).

    Attributes:
        joints: 1-based joints that deflect, default (2, 3).
        columns: per joint, the lumped gravity columns it deflects along (0-based indices into the 4n lumped
            parameters, of links it carries; :func:`~calibration.physics.gravity.independent_link_columns`).
        values: ``c{j}_{m|mx|my|mz}{k}_rad_kg[_mm]_per_Nm``: joint j's compliance times link k's lumped parameter,
            one per column.
    """

    kind = "joint_compliance"
    form: ClassVar[str] = "lumped"
    context_keys = frozenset()
    joints: tuple[int, ...] = (2, 3)
    columns: tuple[tuple[int, ...], ...] = ()
    values: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def __post_init__(self) -> None:
        object.__setattr__(self, "joints", check_joints(self.joints))
        columns = tuple(tuple(int(c) for c in cols) for cols in self.columns)
        if len(columns) != len(self.joints) or any(c < 4 * (j - 1) for j, cols in zip(self.joints, columns)
                                                    for c in cols):
            raise ModelError(f"joint_compliance (lumped): one list of columns of carried links per joint "
                             f"{list(self.joints)}, got {[list(c) for c in columns]}")
        object.__setattr__(self, "columns", columns)
        super().__post_init__()

    @classmethod
    def for_arm(cls, model: PoeModel, joints: tuple[int, ...] = (2, 3)) -> LumpedCompliance:
        """The lumped form on ``joints`` of ``model``'s arm with every independent column, values zero."""
        columns = tuple(independent_link_columns(model, j - 1) for j in joints)
        return cls(joints, columns, np.zeros(sum(len(c) for c in columns)))

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(f"c{j}_{_LUMPED_PARTS[c % 4][0]}{c // 4 + 1}_{_LUMPED_PARTS[c % 4][1]}"
                     for j, cols in zip(self.joints, self.columns) for c in cols)

    def fitted_joints(self, n: int) -> tuple[int, ...]:
        return ()  # a gravity torque's shape: it extrapolates by its formula

    def joint_terms(self, ops: Ops, q: list[Any], chain: Any, context: Context | None, N: int) -> list[Term]:
        frames = chain()
        terms: list[Term] = []
        col = 0
        for j, cols in zip(self.joints, self.columns):
            for t in chain_torque_columns(ops, frames, j - 1, cols):
                terms.append((j - 1, col, t))
                col += 1
        return terms

    def _config(self) -> dict[str, Any]:
        return {"joints": list(self.joints), "columns": [list(c) for c in self.columns]}

    @classmethod
    def _from_config(cls, config: dict[str, Any], values: np.ndarray) -> LumpedCompliance:
        return cls(tuple(config["joints"]), tuple(tuple(c) for c in config["columns"]), values)


@dataclass(frozen=True, eq=False)
class LumpedPayloadCompliance(Effect):
    """Deflection under the payload ``payload_kg`` (context) carried at an unknown point of the last link (the lumped
    form of ``payload_compliance``): joint j deflects by ``payload_kg`` times a free combination of the torques of 1 kg
    at the wrist point and of 1 kg mm of first moment along the last link's axes
    (:func:`~calibration.physics.gravity.chain_torque_columns` of the last link). A payload held anywhere on the tool,
    not only at the tool point, gives a deflection in that span.

    Attributes:
        joints: 1-based joints that deflect, default (2, 3).
        values: ``c{j}_{m|mx|my|mz}_rad_per_Nm[_mm]``, four per joint.
    """

    kind = "payload_compliance"
    form: ClassVar[str] = "lumped"
    context_keys = frozenset({"payload_kg"})
    joints: tuple[int, ...] = (2, 3)
    values: np.ndarray = field(default_factory=lambda: np.zeros(8))
    n_joints: int = 6

    def __post_init__(self) -> None:
        object.__setattr__(self, "joints", check_joints(self.joints, self.n_joints))
        super().__post_init__()

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(f"c{j}_{p}_{u}" for j in self.joints
                     for p, u in zip(("m", "mx", "my", "mz"), ("rad_per_Nm", "rad_per_Nm_mm", "rad_per_Nm_mm",
                                                               "rad_per_Nm_mm")))

    def fitted_joints(self, n: int) -> tuple[int, ...]:
        return ()  # a gravity torque's shape: it extrapolates by its formula

    def joint_terms(self, ops: Ops, q: list[Any], chain: Any, context: Context | None, N: int) -> list[Term]:
        payload_kg = context_array(context, "payload_kg", N)
        mass: FloatArray | float = payload_kg  # per sample (numpy), or one number (casadi)
        if ops.name != "numpy":
            if not np.any(payload_kg):
                return []
            mass = float(payload_kg[0])
        frames = chain()
        last = 4 * (self.n_joints - 1)
        terms: list[Term] = []
        for i, j in enumerate(self.joints):
            cols = chain_torque_columns(ops, frames, j - 1, tuple(range(last, last + 4)))
            terms += [(j - 1, 4 * i + c, t * mass) for c, t in enumerate(cols)]
        return terms
