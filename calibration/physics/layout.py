"""The parameter layout of the physics-informed (pi) model, at the bottom of ``physics``: the blocks
(:class:`Block`, ``BLOCKS``), the tool, compliance and deflection names, the registration parts and the slices of
the parameter vector they own."""

from __future__ import annotations

from typing import Any

import numpy as np

from calibration.errors import ModelError
from calibration.kinematics.blocks import Block
from calibration.kinematics.casadi_expr import (
    NUMPY,
    Ops,
)

DEFLECTION_TERMS = ("1", "sin_q2", "sin_q3", "cos_q2", "cos_q3", "sin_q2q3", "cos_q2q3")


DEFLECTION_AXES = ("dx_mm", "dy_mm", "dz_mm", "rx_rad", "ry_rad", "rz_rad")


TOOL_NAMES = ("tool_rx_rad", "tool_ry_rad", "tool_rz_rad")


#: The choices of :meth:`ExtendedKinematics.registration_mask` (``FitOptions.pi_registration_free``).
REGISTRATION_PARTS = ("none", "rotation", "shift", "all")


def check_registration_parts(parts: str, what: str = "registration parts") -> str:
    """``parts`` when it is one of :data:`REGISTRATION_PARTS`; raises ModelError naming ``what`` otherwise."""
    if parts not in REGISTRATION_PARTS:
        raise ModelError(f"{what} must be one of {', '.join(REGISTRATION_PARTS)}, got {parts!r}")
    return parts


EZ = np.array([0.0, 0.0, 1.0])


def block_slice(name: str, n_geometric: int) -> slice:
    """Where block ``name`` (``tool``, ``compliance``, ``deflection``) sits in ``theta``."""
    start = n_geometric
    for b in BLOCKS:
        if b.name == name:
            return slice(start, start + b.size)
        start += b.size
    raise KeyError(f"unknown block {name!r}; valid: {', '.join(b.name for b in BLOCKS)}")


def deflection_terms(ops: Ops, q2: Any, q3: Any) -> list[Any]:
    """The F7 terms in (q2, q3), written once for numpy (columns (N,)) and casadi (scalars)."""
    return [q2 * 0.0 + 1.0, ops.sin(q2), ops.sin(q3), ops.cos(q2), ops.cos(q3), ops.sin(q2 + q3), ops.cos(q2 + q3)]


def deflection_basis(q: np.ndarray) -> np.ndarray:
    """F7 basis at joint angles q (N, 6), shape (N, 7)."""
    return np.stack(deflection_terms(NUMPY, q[:, 1], q[:, 2]), axis=1)


COMPLIANCE_NAMES = ("c2_sin_q2_rad", "c2_cos_u_rad", "c2_sin_u_rad", "c3_cos_u_rad", "c3_sin_u_rad")


#: The blocks after the geometric one, in layout order, declared once: everything (sizes, names, offsets, the
#: diagnosis' effect blocks) is derived from this.
BLOCKS = (Block("tool", TOOL_NAMES), Block("compliance", COMPLIANCE_NAMES),
          Block("deflection", tuple(f"deflect_{t}_{a}" for t in DEFLECTION_TERMS for a in DEFLECTION_AXES)))


_TAIL_SIZES = tuple(b.size for b in BLOCKS)
