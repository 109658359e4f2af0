"""Where the ``physics`` model kind used to live; it is :mod:`calibration.models.physics` now."""

from calibration.models.physics import PhysicsModel, casadi_effects, effect_blocks, split_values

__all__ = ["PhysicsModel", "casadi_effects", "effect_blocks", "split_values"]
