"""A model of every kind with non-trivial parameters, shared by the rebase and URDF tests (one construction)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from calibration.interpolation.fourier import Fourier13Interpolator
from calibration.kinematics import so3
from calibration.kinematics.parameterisation import MinimalParameterisation
from calibration.kinematics.so3 import make_T
from calibration.models import ConstantModel
from calibration.models.cdc import CdcModel
from calibration.models.diagnosed import DiagnosedModel
from calibration.models.physics import PhysicsModel
from calibration.models.pi import PhysicsInformedModel
from calibration.physics import GravityModel, JointCompliance, JointOffset
from calibration.physics.extended import ExtendedKinematics
from cell_config.loader import load_cell

T_BASE = make_T(so3.exp(np.radians([0.3, -0.2, 0.5])), np.array([2.0, -1.5, 0.8]))
T_TOOL = make_T(so3.exp(np.radians([-0.4, 0.25, 0.1])), np.array([-0.7, 1.2, 3.0]))


@dataclass(frozen=True)
class Kinds:
    """The models (constant, pi, cdc, physics, diagnosed) of R1 and what they are built from."""

    par: MinimalParameterisation
    kin: ExtendedKinematics
    theta: np.ndarray
    geometry: Any
    effects: tuple
    constant: ConstantModel
    pi: PhysicsInformedModel
    cdc: CdcModel
    physics: PhysicsModel
    diagnosed: DiagnosedModel


def models_of_every_kind(seed: int = 3) -> Kinds:
    spec = load_cell().robot("R1")
    par = MinimalParameterisation(spec.model(), fit_tool=True)
    kin = ExtendedKinematics(par)
    rng = np.random.default_rng(seed)
    theta = rng.normal(size=kin.size) * kin.scale() * 0.5
    geometry = par.model(rng.normal(size=par.size) * par.scale() * 0.5)
    gravity = GravityModel.from_spec(spec.robot, geometry)
    effects = (JointCompliance(gravity, (2, 3), np.array([3e-6, 5e-6])), JointOffset((2, 6), np.array([1e-3, -2e-3])))
    pi = PhysicsInformedModel("R1", "pi", kin, theta, kin.size)
    x = rng.uniform(-1.5, 1.5, (40, 2))
    cdc = CdcModel("R1", "fbf13", kin, theta, Fourier13Interpolator().fit(x, rng.normal(size=(40, par.size))
                                                                           * par.scale() * 0.3))
    return Kinds(par, kin, theta, geometry, effects, ConstantModel("R1", "nls1", geometry, par.size), pi, cdc,
                 PhysicsModel("R1", "diagnose", geometry, effects), DiagnosedModel("R1", "diagnose", pi, effects))
