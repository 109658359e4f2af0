"""The ``diagnosed`` model kind: a ``pi`` or ``cdc`` model plus the physics effects a diagnosis found.

Its blocks are the base model's, then one per effect; its numpy pose and its casadi expression take the same
steps (joint effects deflect q on the base model's arm, the base model runs at the deflected joints), so a
planner sees its exact derivatives. :func:`calibration.diagnosis.refitted_model.result_model` builds it.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, ClassVar

import numpy as np

from calibration.errors import ModelError
from calibration.kinematics.blocks import Block
from calibration.kinematics.casadi_expr import CasadiPose, poe_chain
from calibration.models.base import KinematicModel
from calibration.models.physics import casadi_effects, effect_blocks, split_values
from calibration.physics.base import NO_GUARD, Effect, effect_from_dict, effects_read, geometry_on_top
from calibration.physics.context import Context


@dataclass
class DiagnosedModel(KinematicModel):
    """A ``pi`` or ``cdc`` model plus physics effects (kind ``diagnosed``).

    Attributes:
        robot, method: as every model.
        base: the pi or cdc model the effects act on.
        effects: physics effects (joint effects perturb q before ``base``'s kinematics).
        info: free metadata.
    """

    kind: ClassVar[str] = "diagnosed"
    robot: str
    method: str
    base: KinematicModel
    effects: tuple[Effect, ...] = ()
    info: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        pose_effects = [e.kind for e in self.effects if e.target not in ("joints", "geometry")]
        if pose_effects:
            raise ModelError(f"{', '.join(pose_effects)} act on the pose: they belong in the base model's "
                             "parameters, not in a diagnosed model's effects")

    def interpolation(self) -> Any:
        return self.base.interpolation()

    def fk(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pose with the default context (static, t = 0, no payload, reference temperature)."""
        return self.fk_context(q, None)

    def fk_context(self, q: np.ndarray, context: Context | None) -> tuple[np.ndarray, np.ndarray]:
        """Pose ``(R (N, 3, 3), p (N, 3) [mm])`` for joint angles q [rad] (N, 6) and a per-sample context.

        The same steps as :meth:`casadi`: the joint effects (each at the angles and the context the extrapolation
        guard holds it at, see :mod:`calibration.models.guard`) deflect the joints on the base model's arm, the
        base model runs at the deflected joints (its configuration-dependent parameters at the reading q),
        and geometry effects add the pose change their grown links cause on that arm.
        """
        q = np.atleast_2d(np.asarray(q, dtype=float))
        geo = self.base.effects_arm()
        guard = self.region() or NO_GUARD  # each effect at what the extrapolation guard holds it at
        dq = sum((e.delta_q(geo, guard.hold(e, q), guard.hold_context(e, context, q.shape[0]))
                  for e in self.effects if e.target == "joints"), np.zeros_like(q))
        R, p = self.base.pose_at(q + dq, q)
        R, p = geometry_on_top(geo, self.effects, q + dq, context, R, p, guard)
        return R, p

    def out_of_range(self, q: np.ndarray) -> np.ndarray:
        return self.base.out_of_range(q)

    @property
    def context_keys(self) -> frozenset[str]:
        """The context entries its effects read (every one, ``qd`` and the directions included, when an effect does
        not say)."""
        return effects_read(self.effects)

    @property
    def n_parameters(self) -> int:
        return int(self.base.n_parameters) + sum(e.size for e in self.effects)

    def blocks(self) -> tuple[Block, ...]:
        """The base model's blocks, then one per effect."""
        return tuple(self.base.blocks()) + effect_blocks(self.effects)

    def vector(self) -> np.ndarray:
        return np.concatenate([self.base.vector()] + [e.values for e in self.effects])

    def with_vector(self, theta: np.ndarray) -> DiagnosedModel:
        theta = np.asarray(theta, dtype=float)
        k = self.base.vector().size
        values = split_values(self.effects, theta[k:])
        return replace(self, base=self.base.with_vector(theta[:k]),
                       effects=tuple(e.with_values(v) for e, v in zip(self.effects, values)))

    def casadi(self, q: Any, theta: Any = None, q_at: Any = None) -> CasadiPose:
        """The pose at the default context on casadi symbols, exactly as :meth:`fk`: the effects deflect the
        joints on the base model's arm, then the base model's own expression runs at the deflected joints with
        its configuration-dependent parameters at the reading ``q``. Exact in q (no frozen fixed point)."""

        k = self.base.vector().size
        base_theta = None if theta is None else theta[:k]
        values = split_values(self.effects, self.vector()[k:] if theta is None else theta[k:])
        geo, H, P = self.base.effects_geometry(base_theta)
        q_chain, P_eff = casadi_effects(self.effects, values, geo, q, H, P, self.region())
        pose = self.base.casadi(q_chain, base_theta, q if q_at is None else q_at)
        if any(e.target == "geometry" for e in self.effects):  # the pose change the grown links cause
            c0, c1 = poe_chain(geo, q_chain, H, P), poe_chain(geo, q_chain, H, P_eff)
            R = c1.R_base_tool @ c0.R_base_tool.T @ pose.R
            pose = replace(pose, R=R, p=pose.p + c1.p_base_tool - c0.p_base_tool)
        return replace(pose, kind="diagnosed")

    def urdf_geometry(self) -> Any:
        geo = self.base.urdf_geometry()
        lost = geo.lost + tuple(f"the {e.kind} effect ({e.size} parameters)" for e in self.effects)
        return replace(geo, exported=f"{geo.exported} (the base of the diagnosed model)", lost=lost)

    def _body(self) -> dict[str, Any]:
        return {"base": self.base.to_dict(), "effects": [e.to_dict() for e in self.effects]}

    @classmethod
    def _from_body(cls, robot: str, method: str, info: dict[str, Any], body: dict[str, Any]) -> DiagnosedModel:
        return cls(robot, method, KinematicModel.from_dict(body["base"]),
                   tuple(effect_from_dict(e) for e in body.get("effects", [])), info)
