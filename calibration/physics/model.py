"""A fitted physics model: POE geometry plus identified non-geometric effects, saved as a model file.

``calibration.models.load_model`` finds the kind ``"physics"`` through the :class:`KinematicModel`
registry, which is filled when this module is imported: ``calibration/models.py`` (or whoever calls
``load_model``) must import ``calibration.physics.model`` first.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from calibration.models import KinematicModel, poe_from_dict, poe_to_dict
from calibration.physics.base import Context, Effect, apply_effects, effect_from_dict
from calibration.poe import PoeModel


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
        """Pose ``(R (N, 3, 3), p (N, 3) [mm])`` for joint angles q [rad] (N, 6) and a per-sample context."""
        return apply_effects(self.model, self.effects, q, context)

    @property
    def n_parameters(self) -> int:
        return int(self.geometric_parameters) + sum(e.size for e in self.effects)

    def _body(self) -> dict[str, Any]:
        return {"geometry": poe_to_dict(self.model), "geometric_parameters": int(self.geometric_parameters),
                "effects": [e.to_dict() for e in self.effects]}

    @classmethod
    def _from_body(cls, robot: str, method: str, info: dict[str, Any], body: dict[str, Any]) -> "PhysicsModel":
        return cls(robot, method, poe_from_dict(body["geometry"]),
                   tuple(effect_from_dict(e) for e in body.get("effects", [])),
                   int(body.get("geometric_parameters", 0)), info)
