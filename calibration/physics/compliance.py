"""Joint compliance: joints deflect in proportion to the gravity torque they carry.

``joint_compliance``: ``delta_q_i = c_i tau_g,i(q)`` with the arm's own gravity torque (see
:mod:`calibration.physics.gravity` for the sign: positive ``c_i`` sags). ``payload_compliance``: the same
with the torque of the payload ``payload_kg`` (context) as a point mass at the tool point. Both are linear
in the compliances ``c_i`` [rad/(N m)], one per listed joint (1-based).

When the link inertias are unknown, ``delta_q_i = c_i Y_i(q) pi`` is linear in the products
``c_i pi``; :meth:`JointCompliance.lumped_regressor` gives that form for a mass-free fit.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from calibration.physics.base import Context, Effect, check_joints, check_q, context_array
from calibration.physics.gravity import GravityModel, point_mass_torque
from calibration.poe import PoeModel


def _select(tau: np.ndarray, joints: tuple[int, ...]) -> np.ndarray:
    """Regressor (N, n, len(joints)) placing tau[:, j-1] in row j-1, column of j."""
    Y = np.zeros(tau.shape + (len(joints),))
    for col, j in enumerate(joints):
        Y[:, j - 1, col] = tau[:, j - 1]
    return Y


@dataclass(frozen=True, eq=False)
class JointCompliance(Effect):
    """Deflection under the arm's own weight.

    Attributes:
        gravity: lumped link inertias giving the torque (YAML estimates, or fitted).
        joints: 1-based joints that deflect, default (2, 3, 5).
        values: compliances ``c{j}_rad_per_Nm`` [rad/(N m)], one per joint.
    """

    kind = "joint_compliance"
    gravity: GravityModel
    joints: tuple[int, ...] = (2, 3, 5)
    values: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        object.__setattr__(self, "joints", check_joints(self.joints, self.gravity.n_links))
        super().__post_init__()

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(f"c{j}_rad_per_Nm" for j in self.joints)

    def regressor(self, model: PoeModel, q: np.ndarray, context: Context | None = None) -> np.ndarray:
        q = check_q(model, q)
        return _select(self.gravity.torque(model, q), self.joints)

    def lumped_regressor(self, model: PoeModel, q: np.ndarray) -> np.ndarray:
        """Mass-free form: ``delta_q[:, j-1] = L[:, j-1, col(j)] @ (c_j pi)``.

        Returns:
            ``L`` shape (N, n, len(joints), 4n): row j-1 of the gravity regressor in slot col(j), so with
            ``theta (len(joints), 4n) = c[:, None] * pi`` one has ``delta_q = einsum('nicp,cp->ni', L, theta)``.
        """
        q = check_q(model, q)
        Yg = self.gravity.regressor(model, q)
        L = np.zeros((q.shape[0], model.n_joints, len(self.joints), Yg.shape[2]))
        for col, j in enumerate(self.joints):
            L[:, j - 1, col] = Yg[:, j - 1]
        return L

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
    joints: tuple[int, ...] = (2, 3, 5)
    values: np.ndarray = field(default_factory=lambda: np.zeros(3))
    g: float = 9.80665

    def __post_init__(self) -> None:
        object.__setattr__(self, "joints", check_joints(self.joints))
        super().__post_init__()

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(f"c{j}_rad_per_Nm" for j in self.joints)

    def regressor(self, model: PoeModel, q: np.ndarray, context: Context | None = None) -> np.ndarray:
        q = check_q(model, q)
        mass = context_array(context, "payload_kg", q.shape[0])
        return _select(point_mass_torque(model, q, mass, self.g), self.joints)
