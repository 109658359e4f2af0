"""Non-geometric physics of the arms: effect models, gravity torques, the digital twin and the fitted model.

Pinocchio is imported only when gravity torques are computed (:meth:`GravityModel.torque`).
"""

from calibration.physics.base import (EFFECT_KINDS, Context, Effect, apply_effects, context_array,
                                      effect_from_dict)
from calibration.physics.compliance import JointCompliance, PayloadCompliance
from calibration.physics.gravity import G_STANDARD, GravityModel, gravity_regressor, point_mass_torque
from calibration.physics.joint_effects import Backlash, GearTransmission, JointOffset, MocapLatency
from calibration.physics.model import PhysicsModel
from calibration.physics.thermal import ThermalDrift, link_names
from calibration.physics.twin import Twin, default_effect, plant, reference_context

__all__ = [
    "Backlash", "Context", "EFFECT_KINDS", "Effect", "G_STANDARD", "GearTransmission", "GravityModel",
    "JointCompliance", "JointOffset", "MocapLatency", "PayloadCompliance", "PhysicsModel", "ThermalDrift",
    "Twin", "apply_effects", "context_array", "default_effect", "effect_from_dict", "gravity_regressor",
    "link_names", "plant", "point_mass_torque", "reference_context",
]
