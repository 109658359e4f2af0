"""The physics-informed method ``pi``: the global fit of geometry, tool rotation, gravity compliance and smooth
structural deflection (:mod:`calibration.physics.extended`), which the shared fits make once
(:meth:`calibration.methods.shared.SharedFits.physics_informed`: it is also the reference of the ``pi+`` CDC
methods)."""

from __future__ import annotations

from calibration.methods.folds import HeldOutRefits
from calibration.methods.registry import register
from calibration.models.pi import PhysicsInformedModel


@register("pi")
def fit_pi(fitter: HeldOutRefits, method: str) -> PhysicsInformedModel:
    """The global physics-informed fit, shared with the ``pi+`` methods."""
    return fitter.physics_informed()
