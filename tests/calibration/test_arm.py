"""The Arm value: its nominal model, its gravity model from the link masses, and its refusals."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.arm import Arm
from calibration.errors import ModelError
from calibration.models import ConstantModel
from calibration.physics.gravity import GravityModel

MASS_KG = np.array([90.0, 60.0, 45.0, 12.0, 8.0, 5.0])


def _com_mm(rng_seed: int = 0) -> np.ndarray:
    return np.random.default_rng(rng_seed).uniform(-500.0, 1500.0, (6, 3))


def test_the_nominal_model_is_the_arms_geometry(r1_nominal):
    model = Arm("R1", "MA2010", r1_nominal).nominal_model()
    assert isinstance(model, ConstantModel) and (model.robot, model.method, model.n_parameters) == ("R1", "nominal", 0)
    q = np.random.default_rng(1).uniform(-1.0, 1.0, (20, 6))
    for got, want in zip(model.fk(q), r1_nominal.fk(q)):
        np.testing.assert_array_equal(got, want)


def test_the_gravity_model_is_the_link_masses_on_the_nominal_geometry(r1_nominal):
    com = _com_mm()
    gravity = Arm("R1", "MA2010", r1_nominal, None, MASS_KG, com).gravity()
    np.testing.assert_array_equal(gravity.lumped, GravityModel.from_links(r1_nominal, MASS_KG, com).lumped)
    masses, coms = gravity.masses_coms(r1_nominal)
    np.testing.assert_allclose(masses, MASS_KG, rtol=1e-12)
    np.testing.assert_allclose(coms, com, atol=1e-9)


def test_an_arm_without_link_masses_has_no_gravity_model(r1_nominal):
    with pytest.raises(ModelError, match=r"robot MA2010 has no 'links' \(mass_kg, com_mm\)"):
        Arm("R1", "MA2010", r1_nominal).gravity()
    with pytest.raises(ModelError, match="expected 6 masses"):
        Arm("R1", "MA2010", r1_nominal, None, MASS_KG[:5], _com_mm()[:5]).gravity()


@pytest.mark.parametrize("given", ["masses", "centres"])
def test_link_masses_without_their_centres_are_refused(r1_nominal, given):
    masses, com = (MASS_KG, None) if given == "masses" else (None, _com_mm())
    missing = "the masses" if given == "masses" else "the centres of mass"
    with pytest.raises(ModelError, match=f"arm R1: link masses and centres of mass go together; got only {missing}"):
        Arm("R1", "MA2010", r1_nominal, None, masses, com)
