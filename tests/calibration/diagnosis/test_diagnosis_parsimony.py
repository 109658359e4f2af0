"""Parsimony when the physics is slightly off: twins whose gravity loading comes from inertias that differ from
the robot YAML's are named with the right kind and no extra kind; the lumped form takes over when the data
show a shape the YAML's inertias cannot give; compliances and backlash never keep an unphysical sign."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.diagnosis import diagnose
from calibration.diagnosis.core import _subset_joints, _wrong_sign
from calibration.diagnosis.synthetic import Design, make_case, perturbed_gravity
from calibration.physics import Backlash, GravityModel, JointCompliance
from cell_config import load_cell

DESIGN = Design()


def arm(robot):
    cr = load_cell().robot(robot)
    nominal = cr.model()
    return cr, nominal, GravityModel.from_spec(cr.robot, nominal)


def run(robot, magnitudes, seed, relative):
    cr, nominal, gravity = arm(robot)
    truth = perturbed_gravity(gravity, nominal, relative, seed)
    twin, fit, ho = make_case(nominal, truth, magnitudes, seed, DESIGN)
    return diagnose(robot, nominal, fit, ho, gravity=gravity, joint_limits=(cr.robot.lower_rad, cr.robot.upper_rad))


def test_perturbed_gravity_is_off_by_the_given_share():
    _, nominal, gravity = arm("R1")
    off = perturbed_gravity(gravity, nominal, 0.3, 0)
    m0, c0 = gravity.masses_coms(nominal)
    m1, _ = off.masses_coms(nominal)
    moving = m0 > 0
    np.testing.assert_allclose(np.abs(m1[moving] / m0[moving] - 1), 0.3)


@pytest.mark.parametrize("robot", ["R1", "R2"])
def test_inertias_30_percent_off_give_joint_compliance_and_nothing_else(robot):
    res = run(robot, {"joint_compliance": 0.3}, 1, 0.3)
    assert [(e.kind, e.joints) for e in res.effects] == [("joint_compliance", (2, 3))]
    assert res.final.rms_mm <= 1.3 * res.noise.floor_mm and res.final.rms_deg <= 1.3 * res.noise.floor_deg


def test_inertias_far_off_take_a_further_form_and_no_extra_kind():
    res = run("R1", {"joint_compliance": 1.0}, 1, 0.9)
    assert [(e.kind, e.joints) for e in res.effects] == [("joint_compliance", (2, 3))]
    assert "c2_rad_per_Nm" not in res.effects[0].parameters  # a further form (mass-free or lumped), not the YAML shape
    assert res.final.rms_mm <= 1.3 * res.noise.floor_mm


def test_compliance_under_own_weight_with_a_varying_payload():
    res = run("R1", {"joint_compliance": 0.3, "payload_compliance": 0.3}, 1, 0.3)
    assert sorted((e.kind, e.joints) for e in res.effects) == [("joint_compliance", (2, 3)),
                                                                ("payload_compliance", (2, 3))]
    assert res.final.rms_mm <= 1.3 * res.noise.floor_mm


def test_unphysical_sign_is_found_per_joint_and_the_joint_removed():
    _, nominal, gravity = arm("R1")
    c = JointCompliance(gravity, (2, 3, 5), np.array([4e-7, 2e-6, -2e-3]))
    assert _wrong_sign(c, np.array([1e-8, 1e-7, 1e-4])) == [5]
    assert _wrong_sign(c, np.array([1e-8, 1e-7, 2e-3])) == []  # within two standard deviations of zero
    assert _wrong_sign(Backlash((1, 2), np.array([-1e-3, 1e-3])), np.array([1e-4, 1e-4])) == [1]
    e, B = _subset_joints(c, np.eye(3), [0, 1])
    assert isinstance(e, JointCompliance) and e.joints == (2, 3) and e.gravity is gravity
    np.testing.assert_array_equal(B, np.eye(2))


def test_unphysical_sign_rule_drops_only_the_wrong_joints_and_keeps_other_kinds():
    """Planted backlash on joints 1-3 plus a gear error: nothing is dropped (each value has the physical sign)."""
    cr, nominal, gravity = arm("R1")
    twin, fit, ho = make_case(nominal, gravity, {"backlash": 0.3, "gear_transmission": 0.3}, 1, DESIGN)
    res = diagnose("R1", nominal, fit, ho, gravity=gravity, joint_limits=(cr.robot.lower_rad, cr.robot.upper_rad))
    assert sorted(e.kind for e in res.effects) == ["backlash", "gear_transmission"]
    assert all(v > 0 for e in res.effects if e.kind == "backlash" for v in e.parameters.values())


def test_the_lumped_form_holds_the_yaml_shape_and_casadi_gives_its_pose():
    import casadi as ca

    from calibration.models.physics import PhysicsModel
    from calibration.physics import LumpedCompliance

    _, nominal, gravity = arm("R2")
    lumped = LumpedCompliance.for_arm(nominal)
    q = np.random.default_rng(2).uniform(-2.0, 2.0, (40, 6))
    yaml = JointCompliance(gravity, (2, 3), np.array([3e-6, 5e-6])).delta_q(nominal, q)
    Y = lumped.regressor(nominal, q)
    b = np.linalg.lstsq(Y[:, 1:3].reshape(-1, lumped.size), yaml[:, 1:3].ravel(), rcond=None)[0]
    np.testing.assert_allclose(lumped.with_values(b).delta_q(nominal, q), yaml, atol=1e-12)
    model = PhysicsModel("R2", "diagnose", nominal, (lumped.with_values(b * 40.0),))
    qs = ca.SX.sym("q", 6)
    pose = model.casadi(qs)
    f = ca.Function("p", [qs], [pose.p])
    _, p = model.fk(q[:5])
    np.testing.assert_allclose(np.array([np.asarray(f(qi)).ravel() for qi in q[:5]]), p, atol=1e-9)


def test_a_constant_payload_is_own_weight_not_a_payload_compliance():
    from calibration.diagnosis.candidates import library

    _, nominal, gravity = arm("R1")
    q = np.zeros((20, 6))
    cands, untested = library(nominal, q, {"payload_kg": np.full(20, 2.0)}, gravity, ("payload_compliance",))
    assert cands == [] and "does not change" in untested[0].reason
    cands, _ = library(nominal, q, {"payload_kg": np.repeat([0.0, 6.0], 10)}, gravity, ("payload_compliance",))
    assert {c.joints for c in cands} >= {(2,), (3,), (2, 3)}
