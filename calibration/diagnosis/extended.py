"""Candidate effects that are blocks of :class:`calibration.physics.extended.ExtendedKinematics`.

What the real R1 data showed beyond the geometry (see :mod:`calibration.physics.extended`):

- ``tool_frame``: the tool-marker rotation in the flange frame (3 parameters, rad);
- ``joint_compliance`` in the mass-free form (5 parameters, rad): the gravity-shaped deflection of joints 2
  and 3 of a planar two-link arm with unknown lumped masses, for when the link masses are unknown;
- ``structural_deflection``: a smooth pose correction in the joint-1 frame, 7 Fourier terms in (q2, q3) per
  pose axis (42 parameters, mm and rad), the link bending joint compliance alone cannot represent.

Each is a :class:`~calibration.physics.extended.ExtendedEffect` (names and values, so the selection and the
report treat it like any other candidate) whose values add to one block of the extended parameters ``theta``;
the blocks and their names are declared once, in :data:`calibration.physics.layout.BLOCKS`.
:class:`calibration.diagnosis.inuse.InUse` applies them and gives their signatures. The mass-free compliance
is a joint effect like any other and is registered (``joint_compliance``, form ``mass_free``; defined in
:mod:`calibration.physics.compliance`); the tool rotation and the deflection act on the pose of a ``pi``
model (``target == "pose"``), so they are declared ``register=False``: the refit writes them into a ``pi``
or ``cdc`` model's parameters, never as physics-model effects.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calibration.physics.extended import ExtendedEffect, MassFreeCompliance
from calibration.physics.layout import BLOCKS

__all__ = ["ExtendedEffect", "MassFreeCompliance", "StructuralDeflection", "ToolFrame"]
_NAMES = {b.name: b.names for b in BLOCKS}


@dataclass(frozen=True, eq=False)
class ToolFrame(ExtendedEffect, register=False):
    """Tool-marker rotation ``R_flange_tool <- R_flange_tool exp(w)``, ``w`` [rad] (3,)."""

    kind = "tool_frame"
    target = "pose"
    block_name = "tool"
    values: np.ndarray = field(default_factory=lambda: np.zeros(len(_NAMES["tool"])))

    @property
    def names(self) -> tuple[str, ...]:
        return _NAMES["tool"]

    def fitted_joints(self, n: int) -> tuple[int, ...]:
        """None: a constant rotation of the marker, the same at every q."""
        return ()


@dataclass(frozen=True, eq=False)
class StructuralDeflection(ExtendedEffect, register=False):
    """Pose correction ``xi = F7(q2, q3) C`` in the joint-1 frame (translation mm, rotation rad), C (7, 6)."""

    kind = "structural_deflection"
    target = "pose"
    block_name = "deflection"
    joints: tuple[int, ...] = (2, 3)
    values: np.ndarray = field(default_factory=lambda: np.zeros(len(_NAMES["deflection"])))

    @property
    def names(self) -> tuple[str, ...]:
        return _NAMES["deflection"]

    def fitted_joints(self, n: int) -> tuple[int, ...]:
        return (1, 2)  # Fourier terms in q2, q3 (q1 only turns the frame it acts in, exactly)
