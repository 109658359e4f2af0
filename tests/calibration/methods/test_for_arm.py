"""Fitter.for_arm: the fitter of one arm, as the app built it by hand before (nominal, link masses, joint limits,
gross rows screened), bit for bit; an arm without masses fits with the mass-free joint compliance and says so."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from calibration.arm import Arm
from calibration.methods.fitter import Fitter
from calibration.methods.options import FitOptions
from calibration.physics.gravity import GravityModel
from cell_config import load_cell
from tests.conftest import cluster_design, measure


@pytest.fixture(scope="module")
def train(synthetic_arm):
    _, _, truth = synthetic_arm
    q, cluster = cluster_design(step_deg=30.0)
    return measure(truth.fk, q, 0.05, 0.02, 1, cluster)


def _by_hand(robot, train, cpa, options):
    """The construction Fitter.for_arm replaced (app.workflows.fit.fitter_for of 2e3c160)."""
    nominal = robot.model()
    fitter = Fitter(robot.name, nominal, train, options, cpa, GravityModel.from_spec(robot.robot, nominal),
                    (robot.robot.lower_rad, robot.robot.upper_rad))
    return fitter.without_gross_rows() if options.reject_gross_rows else fitter


@pytest.mark.parametrize("options", [FitOptions(), FitOptions(a=2.0, reject_gross_rows=False)])
def test_for_arm_is_the_cell_entrys_fitter_bit_for_bit(train, options):
    robot = load_cell().robot("R1")
    cpa = train.subset(np.arange(14))
    got, want = Fitter.for_arm(robot.arm(), train, cpa, options), _by_hand(robot, train, cpa, options)
    assert got.robot == "R1" and got.cpa_data is cpa and got.options == options
    np.testing.assert_array_equal(got.gravity.lumped, want.gravity.lumped)
    np.testing.assert_array_equal(got.joint_limits[0], robot.robot.lower_rad)
    assert (got.gross is None) == (not options.reject_gross_rows) and len(got.train) == len(want.train)
    for method in ("nls1", "pi"):
        a, b = got.fit(method)[0], want.fit(method)[0]
        for x, y in zip(a.fk(train.q), b.fk(train.q)):
            np.testing.assert_array_equal(x, y)


def test_an_arm_without_link_masses_fits_with_the_mass_free_compliance(train, r1_nominal, caplog):
    with caplog.at_level(logging.WARNING, logger="cellcal.calibration"):
        fitter = Fitter.for_arm(Arm("R9", "MA9999", r1_nominal), train)
    assert fitter.gravity is None and fitter.joint_limits is None and fitter.robot == "R9"
    assert "R9: joint compliance takes the mass-free form: robot MA9999 has no 'links'" in caplog.text
