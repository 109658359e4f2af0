"""Candidate effects that are blocks of :class:`calibration.physics_informed.ExtendedKinematics`.

What the real R1 data showed beyond the geometry (see :mod:`calibration.physics_informed`):

- ``tool_frame``: the tool-marker rotation in the flange frame (3 parameters, rad);
- ``joint_compliance`` in the mass-free form (5 parameters, rad): the gravity-shaped deflection of joints 2
  and 3 of a planar two-link arm with unknown lumped masses, for when the link masses are unknown;
- ``structural_deflection``: a smooth pose correction in the joint-1 frame, 7 Fourier terms in (q2, q3) per
  pose axis (42 parameters, mm and rad), the link bending joint compliance alone cannot represent.

Each is a template :class:`~calibration.physics.base.Effect` (names and values, so the selection and the
report treat it like any other candidate) whose values add to one block of the extended parameters ``theta``;
:class:`calibration.diagnosis.inuse.InUse` applies them and gives their signatures. They act on the pose, not
through :func:`calibration.physics.base.apply_effects`, so they are never saved as physics-model effects: the
refit writes them into a ``pi`` or ``cdc`` model's parameters. The kinds are set after the classes are built
so they do not enter the physics effect registry (``joint_compliance`` there is the mass-based form).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calibration.physics.base import Context, Effect
from calibration.physics_informed import COMPLIANCE_NAMES, DEFLECTION_AXES, DEFLECTION_TERMS
from calibration.poe import PoeModel

#: Offsets of the blocks after the geometric block: tool rotation, compliance, deflection.
_OFFSETS = {"tool": (0, 3), "compliance": (3, 3 + len(COMPLIANCE_NAMES)),
            "deflection": (3 + len(COMPLIANCE_NAMES), 3 + len(COMPLIANCE_NAMES) + 6 * len(DEFLECTION_TERMS))}


@dataclass(frozen=True, eq=False)
class ExtendedEffect(Effect):
    """An effect whose values add to one block of the extended parameters (after the geometric block)."""

    block_name = ""

    def block(self, n_geometric: int) -> slice:
        """Where its values sit in ``theta`` of an :class:`ExtendedKinematics` with ``n_geometric`` geometry."""
        a, b = _OFFSETS[self.block_name]
        return slice(n_geometric + a, n_geometric + b)

    def regressor(self, model: PoeModel, q: np.ndarray, context: Context | None = None) -> np.ndarray:
        raise NotImplementedError("extended effects act through calibration.diagnosis.inuse.InUse")

    def pose_jacobian(self, model: PoeModel, q: np.ndarray, context: Context | None = None) -> np.ndarray:
        raise NotImplementedError("extended effects act through calibration.diagnosis.inuse.InUse")


@dataclass(frozen=True, eq=False)
class ToolFrame(ExtendedEffect):
    """Tool-marker rotation ``R_flange_tool <- R_flange_tool exp(w)``, ``w`` [rad] (3,)."""

    block_name = "tool"
    values: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @property
    def names(self) -> tuple[str, ...]:
        return ("tool_rx_rad", "tool_ry_rad", "tool_rz_rad")


@dataclass(frozen=True, eq=False)
class MassFreeCompliance(ExtendedEffect):
    """Gravity-shaped deflection of joints 2 and 3 with unknown masses, ``u = q2 - q3``:
    ``dq2 = c1 sin q2 + c2 cos u + c3 sin u``, ``dq3 = c4 cos u + c5 sin u`` [rad]."""

    block_name = "compliance"
    joints: tuple[int, ...] = (2, 3)
    values: np.ndarray = field(default_factory=lambda: np.zeros(len(COMPLIANCE_NAMES)))

    @property
    def names(self) -> tuple[str, ...]:
        return COMPLIANCE_NAMES


@dataclass(frozen=True, eq=False)
class StructuralDeflection(ExtendedEffect):
    """Pose correction ``xi = F7(q2, q3) C`` in the joint-1 frame (translation mm, rotation rad), C (7, 6)."""

    block_name = "deflection"
    joints: tuple[int, ...] = (2, 3)
    values: np.ndarray = field(default_factory=lambda: np.zeros(6 * len(DEFLECTION_TERMS)))

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(f"deflect_{t}_{a}" for t in DEFLECTION_TERMS for a in DEFLECTION_AXES)


ToolFrame.kind = "tool_frame"
MassFreeCompliance.kind = "joint_compliance"
StructuralDeflection.kind = "structural_deflection"
