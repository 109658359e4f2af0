"""The ``physics`` model kind: POE geometry plus identified non-geometric effects (:mod:`calibration.physics`).

Its parameter blocks are its effects' values; its pose (numpy, any context), its casadi expression (the
default context, exact in q) and through it its exact Jacobians all come from the effects' one definition
(:meth:`~calibration.physics.base.Effect.joint_terms`, :meth:`~calibration.physics.base.Effect.grow`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, ClassVar

import numpy as np

from calibration.kinematics.blocks import Block
from calibration.kinematics.casadi_expr import CasadiPose, casadi_ops, chain_pose, poe_chain
from calibration.kinematics.poe import PoeModel, poe_from_dict, poe_to_dict
from calibration.models.base import KinematicModel
from calibration.models.guard import Region
from calibration.physics.base import Effect, apply_effects, effect_from_dict, effects_read
from calibration.physics.context import Context


def effect_blocks(effects: tuple[Effect, ...]) -> tuple[Block, ...]:
    """One parameter block per effect, named by its kind."""
    return tuple(Block(e.kind, tuple(e.names)) for e in effects)


def split_values(effects: tuple[Effect, ...], theta: Any) -> list[Any]:
    """``theta`` (sum of sizes,) cut into each effect's values (numpy slices or casadi sub-expressions)."""
    out, k = [], 0
    for e in effects:
        out.append(theta[k:k + e.size])
        k += e.size
    return out


def casadi_effects(effects: tuple[Effect, ...], values: list[Any], geo: PoeModel, q: Any, H: Any, P: Any,
                   region: Region | None = None) -> tuple[Any, Any]:
    """Effects on the arm ``geo`` with axes/link vectors ``H``, ``P`` (casadi) at joint symbols q, the default
    context: ``(q + delta_q (6,), P changed by the geometry effects (3, n+1))``; with a training ``region`` each
    deflection is evaluated at the angles the extrapolation guard holds its effect at
    (:meth:`~calibration.models.guard.Region.hold_casadi`)."""
    import casadi as ca

    ops = casadi_ops()
    chains: dict[tuple[int, ...], Any] = {}

    dq: Any = ca.SX.zeros(q.shape[0])
    cols = [P[:, c] for c in range(P.shape[1])]
    for e, v in zip(effects, values):
        if e.target == "geometry":
            cols = e.grow(cols, v, 1, None, geo)
            continue
        held = () if region is None else region.held_joints(e)
        q_e = q if region is None else region.hold_casadi(e, q)

        def chain(held: tuple[int, ...] = held, q_e: Any = q_e) -> Any:
            """The effects' arm at this effect's q: built once per set of held joints, when an effect needs it."""
            if held not in chains:
                chains[held] = poe_chain(geo, q_e, H, P)
            return chains[held]

        dq = dq + ca.vertcat(*e.casadi_dq(ops, q_e, chain, v))
    return q + dq, ca.horzcat(*cols)


@dataclass
class PhysicsModel(KinematicModel):
    """Geometry plus fitted effects.

    Attributes:
        robot: robot name (``R1``).
        method: how it was fitted (``diagnose``).
        model: the fitted POE geometry with tool.
        effects: fitted effects.
        geometric_parameters: how many geometric parameters were identified (for ``n_parameters``).
        info: free metadata.
    """

    kind: ClassVar[str] = "physics"
    robot: str
    method: str
    model: PoeModel
    effects: tuple[Effect, ...] = ()
    geometric_parameters: int = 0
    info: dict[str, Any] = field(default_factory=dict)

    def fk(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pose with the default context: static (zero dir, qd), t = 0, no payload, reference temperature."""
        return self.fk_context(q, None)

    def fk_context(self, q: np.ndarray, context: Context | None) -> tuple[np.ndarray, np.ndarray]:
        """Pose ``(R (N, 3, 3), p (N, 3) [mm])`` for joint angles q [rad] (N, 6) and a per-sample context; each
        effect evaluated at the angles and the context the extrapolation guard holds it at
        (:mod:`calibration.models.guard`)."""
        return apply_effects(self.model, self.effects, q, context, self.region())

    @property
    def context_keys(self) -> frozenset[str]:
        """The context entries its effects read (every one, ``qd`` and the directions included, when an effect does
        not say)."""
        return effects_read(self.effects)

    @property
    def n_parameters(self) -> int:
        return int(self.geometric_parameters) + sum(e.size for e in self.effects)

    def blocks(self) -> tuple[Block, ...]:
        return effect_blocks(self.effects)

    def vector(self) -> np.ndarray:
        return np.concatenate([e.values for e in self.effects]) if self.effects else np.zeros(0)

    def with_vector(self, theta: np.ndarray) -> PhysicsModel:
        values = split_values(self.effects, np.asarray(theta, dtype=float))
        return replace(self, effects=tuple(e.with_values(v) for e, v in zip(self.effects, values)))

    def casadi(self, q: Any, theta: Any = None, q_at: Any = None) -> CasadiPose:
        """The pose at the default context on casadi symbols: exact, the joint effects' deflection a function
        of q the caller differentiates through."""
        import casadi as ca

        values = split_values(self.effects, self.vector() if theta is None else theta)
        H, P = ca.DM(self.model.H), ca.DM(self.model.P)
        q_chain, P_eff = casadi_effects(self.effects, values, self.model, q, H, P, self.region())
        return chain_pose(poe_chain(self.model, q_chain, H, P_eff), "physics")

    def urdf_geometry(self) -> Any:
        from calibration.models.urdf import UrdfGeometry  # xml.etree only when a URDF is asked for

        lost = tuple(f"the {e.kind} effect ({e.size} parameters)" for e in self.effects)
        return UrdfGeometry(self.model, f"the fitted geometry of the {self.method} model", lost)

    def _body(self) -> dict[str, Any]:
        return {"geometry": poe_to_dict(self.model), "geometric_parameters": int(self.geometric_parameters),
                "effects": [e.to_dict() for e in self.effects]}

    @classmethod
    def _from_body(cls, robot: str, method: str, info: dict[str, Any], body: dict[str, Any]) -> PhysicsModel:
        return cls(robot, method, poe_from_dict(body["geometry"]),
                   tuple(effect_from_dict(e) for e in body.get("effects", [])),
                   int(body.get("geometric_parameters", 0)), info)
