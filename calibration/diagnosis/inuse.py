"""The model in use, of any kind, as extended kinematics: its pose with effects added, and its Jacobians.

Every model kind maps onto :class:`calibration.physics.extended.ExtendedKinematics` parameters ``theta``
(geometry 27, tool rotation 3, mass-free compliance 5, structural deflection 42):

- ``constant`` / ``physics``: the geometry, every other block zero (a physics model's effects stay effects);
- ``pi``: its ``theta``;
- ``cdc``: per sample, its interpolated geometry with its other blocks at ``theta_ref``; the geometric
  block of ``theta`` is then a shift of the interpolated geometry (held at zero by the diagnosis).

Effects add to that model: joint effects perturb q before its kinematics, geometry effects (thermal
growth) add the pose change they cause on the model's POE geometry, extended effects
(:mod:`.extended`) add to their block of ``theta``. A model with only the geometric block takes the exact
legacy path (:func:`calibration.physics.base.apply_effects` on the POE model), so a constant model is
diagnosed exactly as before.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from calibration.errors import ModelError
from calibration.kinematics.arrays import FloatArray
from calibration.kinematics.parameterisation import MinimalParameterisation
from calibration.kinematics.poe import PoeModel
from calibration.models import ConstantModel, KinematicModel
from calibration.models.cdc import CdcModel
from calibration.models.physics import PhysicsModel
from calibration.models.pi import PhysicsInformedModel
from calibration.physics.base import Effect, apply_effects, geometry_on_top
from calibration.physics.context import Context
from calibration.physics.extended import ExtendedEffect, ExtendedKinematics

if TYPE_CHECKING:
    from calibration.models.cdc import CdcModel


@dataclass(frozen=True)
class InUse:
    """A model in use as extended kinematics.

    Attributes:
        kin: the extended kinematics (its ``par`` is the geometric parameterisation).
        theta: parameters (77,) (cdc: ``theta_ref``, geometric block a shift of the interpolated geometry).
        kind: the model kind (``constant``, ``physics``, ``pi``, ``cdc``).
        cdc: the cdc model in use (its per-sample parameters and its reference geometry), else None.
        effects: the model's own effects (physics models).
    """

    kin: ExtendedKinematics
    theta: np.ndarray
    kind: str = "constant"
    cdc: CdcModel | None = None
    effects: tuple[Effect, ...] = ()

    @classmethod
    def from_model(cls, model: KinematicModel | None, nominal: PoeModel, x: np.ndarray | None = None) -> InUse:
        """The in-use form of a model (None: the nominal geometry moved to ``x``)."""

        if model is None or isinstance(model, (ConstantModel, PhysicsModel)):
            kin = ExtendedKinematics(MinimalParameterisation(nominal, fit_tool=True))
            theta = np.zeros(kin.size)
            if model is not None:
                theta[: kin.par.size] = kin.par.from_geometry(model.model.H, model.model.P)
            elif x is not None:
                theta[: kin.par.size] = x
            effects = tuple(model.effects) if isinstance(model, PhysicsModel) else ()
            return cls(kin, theta, "constant" if model is None else model.kind, None, effects)
        if isinstance(model, PhysicsInformedModel):
            return cls(model.kinematics, np.asarray(model.theta, dtype=float).copy(), "pi")
        if isinstance(model, CdcModel):
            theta = np.asarray(model.theta_ref, dtype=float).copy()
            theta[: model.kinematics.par.size] = 0.0
            return cls(model.kinematics, theta, "cdc", model)
        kind = getattr(model, "kind", type(model).__name__)
        raise ModelError(f"diagnose cannot use a {kind!r} model; valid kinds: constant, physics, pi, cdc")

    @property
    def par(self) -> MinimalParameterisation:
        return self.kin.par

    @property
    def n_geometric(self) -> int:
        return self.kin.par.size

    def with_theta(self, theta: np.ndarray, effects: tuple[Effect, ...] | None = None) -> InUse:
        return InUse(self.kin, np.asarray(theta, dtype=float), self.kind, self.cdc,
                     self.effects if effects is None else tuple(effects))

    def plain(self, theta: np.ndarray) -> bool:
        """True when only the geometric block is in use (the exact POE path applies)."""
        return self.cdc is None and not np.any(theta[self.n_geometric:])

    def thetas(self, q: np.ndarray, theta: np.ndarray) -> np.ndarray:
        """Per-sample parameters (N, 77)."""
        q = np.atleast_2d(q)
        if self.cdc is None:
            return np.array(np.broadcast_to(theta, (q.shape[0], theta.size)))
        g = self.n_geometric
        th = np.array(self.cdc.parameters_at(q), dtype=float)
        th[:, g:] = theta[g:]
        th[:, :g] += theta[:g]
        return th

    def geometry(self, theta: np.ndarray) -> PoeModel:
        """One POE geometry (the drivers' and regressors' arm; cdc: its reference geometry plus the shift)."""
        x = theta[: self.n_geometric]
        if self.cdc is not None:
            x = x + np.asarray(self.cdc.theta_ref)[: self.n_geometric]
        return self.par.model(x)

    @staticmethod
    def split_effects(theta: np.ndarray, effects: tuple[Effect, ...], n_geometric: int
                      ) -> tuple[np.ndarray, tuple[Effect, ...]]:
        """Parameters with the extended effects' values added to their blocks, and the other effects."""
        theta = np.array(theta, dtype=float)
        rest = []
        for e in effects:
            if isinstance(e, ExtendedEffect):
                theta[e.block(n_geometric)] += e.values
            else:
                rest.append(e)
        return theta, tuple(rest)

    def pose(self, q: np.ndarray, effects: tuple[Effect, ...], context: Context | None,
             theta: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Tool pose ``(R (N, 3, 3), p (N, 3) [mm])`` of the model with ``effects`` (extended ones included)."""
        theta, rest = self.split_effects(self.theta if theta is None else theta, tuple(effects), self.n_geometric)
        geo = self.geometry(theta)
        if self.plain(theta):
            return apply_effects(geo, rest, q, context)
        q = np.atleast_2d(np.asarray(q, dtype=float))
        dq = sum((e.delta_q(geo, q, context) for e in rest if e.target != "geometry"), np.zeros_like(q))
        R, p = self.kin.pose(q + dq, self.thetas(q, theta))
        R, p = geometry_on_top(geo, rest, q + dq, context, R, p)
        return R, p

    def jacobian_q(self, q: np.ndarray, theta: np.ndarray) -> np.ndarray:
        """``d[p; rotation] / dq`` (N, 6, 6) at per-sample parameters (compliance and deflection held)."""
        return self.kin.jacobian_q(q, self.thetas(q, theta))

    def jacobian_geometry(self, q: np.ndarray, theta: np.ndarray) -> np.ndarray:
        """``d[p; rotation] / d x`` (N, 6, 27) of the geometric block (a shift of it for cdc)."""
        if self.plain(theta):
            return self.par.jacobian(q, theta[: self.n_geometric])[2]
        return self.kin.jacobian(q, self.thetas(q, theta), geometry_only=True)[2]

    def effect_jacobian(self, effect: Effect, q: np.ndarray, context: Context | None, theta: np.ndarray
                        ) -> np.ndarray:
        """First-order pose change per parameter of an effect, (N, 6, m), on top of this model."""
        if isinstance(effect, ExtendedEffect):
            return self.kin.jacobian(q, self.thetas(q, theta))[2][..., effect.block(self.n_geometric)]
        geo = self.geometry(theta)
        if self.plain(theta):
            return effect.pose_jacobian(geo, q, context)
        if effect.target == "geometry":
            J = effect.pose_jacobian(geo, q, context)
            E = self.kin.deflection_rotation(q, self.thetas(q, theta))
            return np.concatenate([E @ J[:, :3], E @ J[:, 3:]], axis=1)
        J_effect: FloatArray = self.jacobian_q(q, theta) @ effect.regressor(geo, q, context)
        return J_effect

    def signature(self, effect: Effect, q: np.ndarray, context: Context | None, theta: np.ndarray, w_rot: float
                  ) -> np.ndarray:
        """Weighted first-order residual signature of an effect, shape (6N, m)."""
        J = self.effect_jacobian(effect, q, context, theta).copy()
        J[:, 3:] *= w_rot
        return J.reshape(J.shape[0] * 6, J.shape[-1])
