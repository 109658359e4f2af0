"""The ``pi`` model kind: a fitted :class:`~calibration.physics.extended.ExtendedKinematics` (77 parameters).

Its blocks are the kinematics' (geometry 27, tool rotation 3, mass-free compliance 5, structural deflection
42, declared once in :mod:`calibration.physics.extended`); its pose, analytic Jacobian and casadi expression
all read that one layout. It has no extrapolation guard (:mod:`calibration.models.guard` says why): its compliance
is the mass-free gravity shape, and its structural deflection's fitted shape is in q2 and q3, which the training
designs see widely.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, ClassVar

import numpy as np

from calibration.errors import ModelFileError
from calibration.kinematics.blocks import Block
from calibration.kinematics.casadi_expr import CasadiPose
from calibration.kinematics.parameterisation import MinimalParameterisation
from calibration.kinematics.poe import PoeModel, poe_from_dict, poe_to_dict
from calibration.models.base import KinematicModel
from calibration.physics.extended import ExtendedKinematics


@dataclass
class PhysicsInformedModel(KinematicModel):
    """A fitted :class:`ExtendedKinematics` (kind ``pi``)."""

    kind: ClassVar[str] = "pi"
    robot: str
    method: str
    kinematics: ExtendedKinematics
    theta: np.ndarray
    rank: int = 0
    info: dict[str, Any] = field(default_factory=dict)

    def fk(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.kinematics.pose(q, self.theta)

    @property
    def n_parameters(self) -> int:
        return self.kinematics.size

    def parameters(self) -> dict[str, float]:
        return dict(zip(self.kinematics.names(), self.theta.tolist()))

    def blocks(self) -> tuple[Block, ...]:
        return self.kinematics.blocks()

    def vector(self) -> np.ndarray:
        return np.asarray(self.theta, dtype=float).copy()

    def with_vector(self, theta: np.ndarray) -> PhysicsInformedModel:
        return replace(self, theta=np.asarray(theta, dtype=float))

    def jacobian(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return self.kinematics.jacobian(q, self.theta)

    def casadi(self, q: Any, theta: Any = None, q_at: Any = None) -> CasadiPose:
        import casadi as ca

        self.kinematics.check_casadi(self.theta)
        return self.kinematics.casadi(q, ca.DM(self.theta) if theta is None else theta)

    def pose_at(self, q: np.ndarray, q_at: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pose at joint angles q (N, 6) [rad] the kinematics see; ``q_at`` is unused (no parameter depends on
        the configuration)."""
        return self.kinematics.pose(q, self.theta)

    def effects_arm(self) -> PoeModel:
        """The POE arm effects acting on this model see: its geometric block with the nominal tool."""
        return self.kinematics.par.model(self.theta[: self.kinematics.par.size])

    def effects_geometry(self, theta: Any = None) -> tuple[PoeModel, Any, Any]:
        """The arm the effects on this model act on, in casadi: ``(nominal with tool, H (3, n), P (3, n+1))``,
        its geometric block (of ``theta``, which may be symbols; of the model's own when None)."""
        import casadi as ca

        par = self.kinematics.par
        if theta is None:
            H, P = par.geometry(self.theta[: par.size])
            return par.nominal, ca.DM(H), ca.DM(P)
        return (par.nominal,) + par.casadi_geometry(theta[: par.size])

    def urdf_geometry(self) -> Any:
        from calibration.models.urdf import UrdfGeometry  # xml.etree only when a URDF is asked for

        return UrdfGeometry(self.kinematics.constant_arm(self.theta),
                            f"the {self.kinematics.par.size}-parameter geometry block and the tool rotation of the "
                            f"{self.method} model", self.kinematics.lost_terms(self.theta))

    def _body(self) -> dict[str, Any]:
        return {"nominal": poe_to_dict(self.kinematics.par.nominal), "fit_tool": self.kinematics.par.fit_tool,
                "rank": self.rank, "theta": self.theta.tolist(), "names": self.kinematics.names()}

    @classmethod
    def _from_body(cls, robot: str, method: str, info: dict[str, Any], body: dict[str, Any]) -> PhysicsInformedModel:
        kin = ExtendedKinematics(MinimalParameterisation(poe_from_dict(body["nominal"]), bool(body["fit_tool"])))
        theta = np.array(body["theta"], dtype=float) if isinstance(body["theta"], list) else None
        if theta is None or theta.shape != (kin.size,):
            got = f"{len(body['theta'])} entries" if isinstance(body["theta"], list) else repr(body["theta"])
            raise ModelFileError("", "theta", f"expected a list of {kin.size} numbers, got {got}")
        return cls(robot, method, kin, theta, int(body["rank"]), info)
