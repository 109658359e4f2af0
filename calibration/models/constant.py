"""The ``constant`` model kind: one POE geometry for the whole workspace (nominal, base, CPA, NLS fits).

Its parameter block is the minimal POE chart around its own geometry (``x = 0`` is the model, the flange
point included), so its Jacobians are the analytic POE ones and its casadi expression is the POE chain.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from calibration.kinematics.blocks import Block
from calibration.kinematics.poe import PoeModel, poe_from_dict, poe_to_dict
from calibration.models.base import KinematicModel

if TYPE_CHECKING:
    from calibration.kinematics.parameterisation import MinimalParameterisation


@dataclass
class ConstantModel(KinematicModel):
    """One geometry for the whole workspace (nominal, base, CPA, NLS fits)."""

    kind: ClassVar[str] = "constant"
    robot: str
    method: str
    model: PoeModel
    parameters: int = 0
    info: dict[str, Any] = field(default_factory=dict)

    def fk(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.model.fk(q)

    @property
    def n_parameters(self) -> int:
        return self.parameters

    def _chart(self) -> MinimalParameterisation:
        """Minimal parameters around this geometry (``x = 0`` is this model; the flange point included)."""
        # here, not at the top: the CLI loads this kind with every plan check, the fitting maths only when asked for
        from calibration.kinematics.parameterisation import MinimalParameterisation

        return MinimalParameterisation(self.model, fit_tool=True)

    def blocks(self) -> tuple[Block, ...]:
        return (Block("geometry", tuple(self._chart().names())),)

    def vector(self) -> np.ndarray:
        return np.zeros(self._chart().size)

    def with_vector(self, theta: np.ndarray) -> ConstantModel:
        return replace(self, model=self._chart().model(np.asarray(theta, dtype=float)))

    def jacobian(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        par = self._chart()
        return par.jacobian(q, np.zeros(par.size))

    def jacobian_q(self, q: np.ndarray) -> np.ndarray:
        return self.model.jacobian_q(q)

    def casadi(self, q: Any, theta: Any = None, q_at: Any = None) -> Any:
        if theta is None:
            return self.model.casadi(q, kind="constant")
        from calibration.kinematics.casadi_expr import chain_pose, poe_chain

        return chain_pose(poe_chain(self.model, q, *self._chart().casadi_geometry(theta)), "constant")

    def urdf_geometry(self) -> Any:
        from calibration.models.urdf import UrdfGeometry  # xml.etree only when a URDF is asked for

        return UrdfGeometry(self.model, f"the constant {self.method} geometry")

    def _body(self) -> dict[str, Any]:
        return {"geometry": poe_to_dict(self.model)}

    @classmethod
    def _from_body(cls, robot: str, method: str, info: dict[str, Any], body: dict[str, Any]) -> ConstantModel:
        return cls(robot, method, poe_from_dict(body["geometry"]), int(body.get("n_parameters", 0)), info)
