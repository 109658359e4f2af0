"""An arm as calibration needs it: its name, nominal geometry with the tool, joint limits and link masses.

The cell loader builds one per arm of the cell (:meth:`cell_config.loader.CellRobot.arm`); the fitter
(:meth:`calibration.methods.fitter.Fitter.for_arm`), the frame check and the multi-day fit
(:mod:`calibration.frames`) take it, so calibration needs no callback into the application to set up a fit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calibration.errors import ModelError
from calibration.kinematics.poe import PoeModel
from calibration.models.constant import ConstantModel
from calibration.physics.gravity import GravityModel


@dataclass(frozen=True)
class Arm:
    """One arm: what a fit reads about it besides its recordings.

    Attributes:
        name: the arm's name in the cell (``R1``, ``R2``); the fitted models' ``robot``.
        model_name: the robot model (``MA2010``), for messages.
        nominal: the vendor's POE model carrying the tool (the marker rigid body in the flange frame) [mm].
        joint_limits_rad: (lower, upper) joint limits [rad], each shape (n,); None when not known (the training
            poses then stand in for the workspace).
        link_mass_kg: lumped mass of each moving link [kg], shape (n,); None when the robot description has none
            (the joint compliance then takes its mass-free form).
        link_com_mm: each moving link's centre of mass in the base frame at q = 0 [mm], shape (n, 3); given
            with ``link_mass_kg`` or not at all.

    Raises:
        ModelError: only one of ``link_mass_kg`` and ``link_com_mm`` given.
    """

    name: str
    model_name: str
    nominal: PoeModel
    joint_limits_rad: tuple[np.ndarray, np.ndarray] | None = None
    link_mass_kg: np.ndarray | None = None
    link_com_mm: np.ndarray | None = None

    def __post_init__(self) -> None:
        if (self.link_mass_kg is None) != (self.link_com_mm is None):
            raise ModelError(f"arm {self.name}: link masses and centres of mass go together; got only "
                             f"{'the masses' if self.link_com_mm is None else 'the centres of mass'}")

    def nominal_model(self) -> ConstantModel:
        """The nominal arm as a model (method ``nominal``, no fitted parameters): what frame checks compare with."""
        return ConstantModel(self.name, "nominal", self.nominal, 0, {})

    def gravity(self) -> GravityModel:
        """The arm's gravity model on its nominal geometry (the joint compliance's torques).

        Raises:
            ModelError: the arm has no link masses, or their count is not the arm's joint count.
        """
        if self.link_mass_kg is None or self.link_com_mm is None:
            raise ModelError(f"robot {self.model_name} has no 'links' (mass_kg, com_mm) in its YAML")
        return GravityModel.from_links(self.nominal, self.link_mass_kg, self.link_com_mm)
