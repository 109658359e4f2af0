"""Joint-angle effects that need no model of the arm: offsets, backlash, gear transmission error, latency.

All are linear in their parameters and act as ``q_true = q + delta_q``; each writes its regressor once
(:meth:`~calibration.physics.base.Effect.joint_terms`) for numpy and casadi:

- ``joint_offset``: ``delta_q_i = offset{i}_rad`` (the simplest geometric error; axis tilts, origin offsets,
  link lengths, base and tool frames are left to :class:`calibration.kinematics.parameterisation.MinimalParameterisation`
  and the geometric fitter).
- ``backlash``: ``delta_q_i = b{i}_rad * dir_i / 2``, the lost motion seen from each approach direction.
- ``gear_transmission``: ``delta_q_i = sum_k a_k sin(k q_i) + b_k cos(k q_i)`` with harmonics ``k`` per joint
  (a shape fitted inside the data: the extrapolation guard holds it where the data saw its joint only narrowly).
- ``mocap_latency``: the measured pose lags the joint reading, ``delta_q = -qd * latency_s``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from calibration.errors import ModelError
from calibration.kinematics.casadi_expr import Ops
from calibration.physics.base import Effect, Term
from calibration.physics.context import Context, check_joints, context_dirs, context_qd


@dataclass(frozen=True, eq=False)
class JointOffset(Effect):
    """Constant joint-angle offsets ``offset{j}_rad`` [rad] on the listed 1-based joints."""

    kind = "joint_offset"
    context_keys = frozenset()
    joints: tuple[int, ...] = (1, 2, 3, 4, 5, 6)
    values: np.ndarray = field(default_factory=lambda: np.zeros(6))

    def __post_init__(self) -> None:
        object.__setattr__(self, "joints", check_joints(self.joints))
        super().__post_init__()

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(f"offset{j}_rad" for j in self.joints)

    def fitted_joints(self, n: int) -> tuple[int, ...]:
        return ()  # constant in q

    def joint_terms(self, ops: Ops, q: list[Any], chain: Any, context: Context | None, N: int) -> list[Term]:
        return [(j - 1, col, 1.0) for col, j in enumerate(self.joints)]


@dataclass(frozen=True, eq=False)
class Backlash(Effect):
    """Lost motion ``b{j}_rad`` [rad] (full width); the joint sits ``dir_j * b_j / 2`` off its reading."""

    kind = "backlash"
    context_keys = frozenset({"dir"})
    joints: tuple[int, ...] = (1, 2, 3)
    values: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        object.__setattr__(self, "joints", check_joints(self.joints))
        super().__post_init__()

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(f"b{j}_rad" for j in self.joints)

    def fitted_joints(self, n: int) -> tuple[int, ...]:
        return ()  # constant in q

    def joint_terms(self, ops: Ops, q: list[Any], chain: Any, context: Context | None, N: int) -> list[Term]:
        d = context_dirs(context, N, len(q))  # the default context (casadi): static, no direction
        return [(j - 1, col, 0.5 * _scalar(d[:, j - 1], ops)) for col, j in enumerate(self.joints)]


@dataclass(frozen=True, eq=False)
class GearTransmission(Effect):
    """Periodic transmission error in harmonics of each joint's own angle.

    Attributes:
        harmonics: ``((joint, (k1, k2, ...)), ...)`` 1-based joints and their positive integer orders.
        values: per joint and order, ``j{j}_sin{k}_rad`` then ``j{j}_cos{k}_rad`` [rad].
    """

    kind = "gear_transmission"
    context_keys = frozenset()
    harmonics: tuple[tuple[int, tuple[int, ...]], ...] = ((1, (1, 2)),)
    values: np.ndarray = field(default_factory=lambda: np.zeros(4))

    def __post_init__(self) -> None:
        try:
            h = tuple((int(j), tuple(int(k) for k in ks)) for j, ks in self.harmonics)
        except (TypeError, ValueError) as e:
            raise ModelError("harmonics must be ((joint, (k, ...)), ...)") from e
        check_joints(tuple(j for j, _ in h))
        if any(not ks or min(ks) < 1 or len(set(ks)) != len(ks) for _, ks in h):
            raise ModelError(f"harmonic orders must be distinct positive integers, got {h}")
        object.__setattr__(self, "harmonics", h)
        super().__post_init__()

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(f"j{j}_{f}{k}_rad" for j, ks in self.harmonics for k in ks for f in ("sin", "cos"))

    def fitted_joints(self, n: int) -> tuple[int, ...]:
        """The joints of its harmonics: their shape was fitted inside the data's range of those joints' angles."""
        return tuple(j - 1 for j, _ in self.harmonics)

    def joint_terms(self, ops: Ops, q: list[Any], chain: Any, context: Context | None, N: int) -> list[Term]:
        terms, col = [], 0
        for j, ks in self.harmonics:
            for k in ks:
                terms += [(j - 1, col, ops.sin(k * q[j - 1])), (j - 1, col + 1, ops.cos(k * q[j - 1]))]
                col += 2
        return terms

    def _config(self) -> dict[str, Any]:
        return {"harmonics": [[j, list(ks)] for j, ks in self.harmonics]}

    @classmethod
    def _from_config(cls, config: dict[str, Any], values: np.ndarray) -> GearTransmission:
        return cls(tuple((int(j), tuple(ks)) for j, ks in config["harmonics"]), values)


@dataclass(frozen=True, eq=False)
class MocapLatency(Effect):
    """The pose is measured ``latency_s`` [s] after the joint reading: ``delta_q = -qd * latency_s``."""

    kind = "mocap_latency"
    context_keys = frozenset({"qd"})
    values: np.ndarray = field(default_factory=lambda: np.zeros(1))

    @property
    def names(self) -> tuple[str, ...]:
        return ("latency_s",)

    def fitted_joints(self, n: int) -> tuple[int, ...]:
        return ()  # constant in q

    def joint_terms(self, ops: Ops, q: list[Any], chain: Any, context: Context | None, N: int) -> list[Term]:
        qd = context_qd(context, N, len(q))  # the default context (casadi): at rest
        return [(j, 0, -_scalar(qd[:, j], ops)) for j in range(len(q))]


def _scalar(column: np.ndarray, ops: Ops) -> Any:
    """A per-sample context column (N,) for numpy; its one value as a float for casadi (N = 1)."""
    return column if ops.name == "numpy" else float(column[0])
