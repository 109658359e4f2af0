"""The refitted model as a model file: the simplest kind that predicts exactly what the refit says.

- no extended terms (constant/physics in use, physics effects only): a ``physics`` model (POE + effects);
  a tool-marker rotation alone is folded into the POE tool rotation;
- extended terms only (a ``pi``/``cdc`` in use, or ``tool_frame``/mass-free ``joint_compliance``/
  ``structural_deflection`` found): a ``pi`` model with the refitted ``theta``, or a ``cdc`` model with its
  interpolator and the refitted ``theta_ref``;
- both: a ``diagnosed`` model (:mod:`calibration.models.diagnosed`), that ``pi``/``cdc`` model plus the physics
  effects acting on it (joint effects perturb q before its kinematics).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from calibration.diagnosis.extended import ToolFrame
from calibration.diagnosis.inuse import InUse
from calibration.kinematics import so3
from calibration.kinematics.poe import PoeModel
from calibration.models import KinematicModel
from calibration.models.cdc import CdcModel
from calibration.models.diagnosed import DiagnosedModel
from calibration.models.physics import PhysicsModel
from calibration.models.pi import PhysicsInformedModel
from calibration.physics.base import Effect
from calibration.physics.extended import ExtendedEffect

__all__ = ["DiagnosedModel", "result_model"]


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
    if inuse.cdc is not None:
        cdc = inuse.cdc
        ref = full.copy()
        ref[:g] = cdc.theta_ref[:g]
        base: CdcModel | PhysicsInformedModel = CdcModel(robot, cdc.method, inuse.kin, ref, cdc.interpolator,
                                                         cdc.inputs, dict(cdc.info), cdc.bounds)
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
