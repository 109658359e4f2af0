"""Non-geometric physics of the arms: effect models, gravity torques and the digital twin.

Each effect writes its formula once for numpy and casadi (:mod:`calibration.physics.base`). The fitted model
of geometry plus effects is the ``physics`` model kind, :mod:`calibration.models.physics`. Pinocchio is imported only for :meth:`GravityModel.torque`.
"""

from calibration.physics.base import EFFECT_KINDS, Effect, apply_effects, effect_from_dict
from calibration.physics.compliance import JointCompliance, LumpedCompliance, LumpedPayloadCompliance, PayloadCompliance
from calibration.physics.context import Context, context_array
from calibration.physics.extended import ExtendedEffect, MassFreeCompliance
from calibration.physics.gravity import G_STANDARD, GravityModel, gravity_regressor, point_mass_torque
from calibration.physics.joint_effects import Backlash, GearTransmission, JointOffset, MocapLatency
from calibration.physics.thermal import ThermalDrift, link_names
from calibration.physics.twin import PlantedErrors, Twin, default_effect, plant, planted_twin, reference_context

__all__ = [
    "Backlash", "Context", "EFFECT_KINDS", "Effect", "ExtendedEffect", "G_STANDARD", "GearTransmission",
    "GravityModel", "JointCompliance", "JointOffset", "LumpedCompliance", "LumpedPayloadCompliance", "MassFreeCompliance",
    "MocapLatency", "PayloadCompliance",
    "PlantedErrors", "ThermalDrift", "Twin", "apply_effects", "context_array", "default_effect",
    "effect_from_dict", "gravity_regressor", "link_names", "plant", "planted_twin", "point_mass_torque",
    "reference_context",
]


