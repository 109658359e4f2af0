"""The refitted model as a model file: the simplest kind that predicts exactly what the refit says.

- no extended terms (constant/physics in use, physics effects only): a ``physics`` model (POE + effects);
  a tool-marker rotation alone is folded into the POE tool rotation;
- extended terms only (a ``pi``/``cdc`` in use, or ``tool_frame``/mass-free ``joint_compliance``/
  ``structural_deflection`` found): a ``pi`` model with the refitted ``theta``, or a ``cdc`` model with its
  interpolator and the refitted ``theta_ref``;
- both: a ``diagnosed`` model, that ``pi``/``cdc`` model plus the physics effects acting on it (joint effects
  perturb q before its kinematics). ``load_model`` knows this kind once :mod:`calibration.diagnosis.model`
  is imported (``calibration/models.py`` imports it at its end for ``evaluate``/``compare``).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, ClassVar

import numpy as np

from calibration import so3
from calibration.casadi_expr import CasadiPose, poe_chain
from calibration.diagnosis.extended import ExtendedEffect, ToolFrame
from calibration.diagnosis.inuse import InUse
from calibration.models import Block, KinematicModel
from calibration.physics.base import Context, Effect, effect_from_dict
from calibration.physics.model import PhysicsModel, casadi_effects, effect_blocks, split_values
from calibration.poe import PoeModel


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

    def _inuse(self) -> InUse:
        return InUse.from_model(self.base, self.base.kinematics.par.nominal)  # type: ignore[attr-defined]

    def fk(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pose with the default context (static, t = 0, no payload, reference temperature)."""
        return self.fk_context(q, None)

    def fk_context(self, q: np.ndarray, context: Context | None) -> tuple[np.ndarray, np.ndarray]:
        """Pose ``(R (N, 3, 3), p (N, 3) [mm])`` for joint angles q [rad] (N, 6) and a per-sample context."""
        return self._inuse().pose(q, self.effects, context)

    def out_of_range(self, q: np.ndarray) -> np.ndarray:
        return self.base.out_of_range(q)

    @property
    def n_parameters(self) -> int:
        return int(self.base.n_parameters) + sum(e.size for e in self.effects)

    def blocks(self) -> tuple[Block, ...]:
        """The base model's blocks, then one per effect."""
        return tuple(self.base.blocks()) + effect_blocks(self.effects)

    def vector(self) -> np.ndarray:
        return np.concatenate([self.base.vector()] + [e.values for e in self.effects])

    def with_vector(self, theta: np.ndarray) -> "DiagnosedModel":
        theta = np.asarray(theta, dtype=float)
        k = self.base.vector().size
        values = split_values(self.effects, theta[k:])
        return replace(self, base=self.base.with_vector(theta[:k]),
                       effects=tuple(e.with_values(v) for e, v in zip(self.effects, values)))

    def casadi(self, q: Any, theta: Any = None, q_at: Any = None) -> CasadiPose:
        """The pose at the default context on casadi symbols, exactly as :meth:`fk`: the effects deflect the
        joints on the base model's arm, then the base model's own expression runs at the deflected joints with
        its configuration-dependent parameters at the reading ``q``. Exact in q (no frozen fixed point)."""
        import casadi as ca

        k = self.base.vector().size
        base_theta = None if theta is None else theta[:k]
        values = split_values(self.effects, self.vector()[k:] if theta is None else theta[k:])
        geo, H, P = self.base.effects_geometry(base_theta)  # type: ignore[attr-defined]
        q_chain, P_eff = casadi_effects(self.effects, values, geo, q, H, P)
        pose = self.base.casadi(q_chain, base_theta, q if q_at is None else q_at)
        if any(e.target == "geometry" for e in self.effects):  # the pose change the grown links cause
            c0, c1 = poe_chain(geo, q_chain, H, P), poe_chain(geo, q_chain, H, P_eff)
            R = c1.R_base_tool @ c0.R_base_tool.T @ pose.R
            pose = replace(pose, R=R, p=pose.p + c1.p_base_tool - c0.p_base_tool)
        return replace(pose, kind="diagnosed")

    def _body(self) -> dict[str, Any]:
        return {"base": self.base.to_dict(), "effects": [e.to_dict() for e in self.effects]}

    @classmethod
    def _from_body(cls, robot: str, method: str, info: dict[str, Any], body: dict[str, Any]) -> "DiagnosedModel":
        return cls(robot, method, KinematicModel.from_dict(body["base"]),
                   tuple(effect_from_dict(e) for e in body.get("effects", [])), info)


def _fold_tool(geo: PoeModel, w: np.ndarray) -> PoeModel:
    return replace(geo, R_flange_tool=geo.R_flange_tool @ so3.exp(np.asarray(w, dtype=float)))


def result_model(robot: str, inuse: InUse, used: KinematicModel | None, theta: np.ndarray,
                 effects: tuple[Effect, ...], n_geometric_free: int, info: dict[str, Any]
                 ) -> tuple[KinematicModel, str]:
    """The refitted model and a note saying what was refitted and how it is saved.

    Args:
        robot: robot name.
        inuse: the model in use.
        used: the model file in use (None: the geometric NLS fit).
        theta: its refitted parameters (77,) without the extended effects' values.
        effects: the model's own and the found effects, refitted (extended ones included).
        n_geometric_free: geometric directions refitted.
        info: metadata for the file.
    """
    from calibration.cdc import CdcModel
    from calibration.physics_informed import PhysicsInformedModel

    g = inuse.n_geometric
    full, rest = InUse.split_effects(theta, effects, g)
    extended = [e for e in effects if isinstance(e, ExtendedEffect)]
    what = "geometric block" if n_geometric_free else "geometric block held (not refitted)"
    if inuse.kind in ("constant", "physics") and all(isinstance(e, ToolFrame) for e in extended):
        geo = inuse.geometry(theta)
        for e in extended:
            geo = _fold_tool(geo, e.values)
        note = f"Refitted: the geometric block ({n_geometric_free} observable directions) and the effects; saved as " \
               "a physics model" + (" (tool-marker rotation folded into the POE tool frame)." if extended else ".")
        folded = sum(e.size for e in extended)  # fitted tool rotations count as identified parameters
        return PhysicsModel(robot, "diagnose", geo, rest, n_geometric_free + folded, info), note
    if inuse.kind == "cdc":
        owner = getattr(inuse.interpolate, "__self__")
        ref = full.copy()
        ref[:g] = owner.theta_ref[:g]
        base: KinematicModel = CdcModel(robot, owner.method, inuse.kin, ref, owner.interpolator, owner.inputs,
                                        dict(owner.info))
        base_kind = "cdc"
    else:
        base = PhysicsInformedModel(robot, "diagnose", inuse.kin, full, n_geometric_free, dict(info))
        base_kind = "pi"
    note = f"Refitted: the {what} ({n_geometric_free} directions) and the effects found"
    if inuse.kind in ("pi", "cdc"):
        note += "; the terms the model in use carries beyond its geometry (tool rotation, compliance, deflection) held"
    if not rest:
        return (replace(base, info={**base.info, **info}), note + f"; saved as a {base_kind} model.")
    return (DiagnosedModel(robot, "diagnose", base, rest, info),
            note + f"; saved as a 'diagnosed' model ({base_kind} plus {', '.join(e.kind for e in rest)}).")
