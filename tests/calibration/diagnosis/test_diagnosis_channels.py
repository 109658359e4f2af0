"""Per-channel noise: both noise floors estimated from the data, the evidence weighed by them, and effects seen
mainly in the orientation (a wrist gear error, the marker near that joint's axis) found on both robots."""

from __future__ import annotations

import math

import numpy as np
import pytest

from calibration.diagnosis import DiagnoseOptions, Evidence, SelectionOptions, diagnose, noise_floor
from calibration.diagnosis.noise import WEIGHT_RANGE, channel_weight
from calibration.diagnosis.synthetic import Design, make_wrist_case, orientation_rms_deg
from calibration.errors import ModelError
from calibration.identification import DEFAULT_ORIENTATION_WEIGHT, rotation_residual_scale
from calibration.physics import GravityModel
from cell_config import load_cell

DESIGN = Design(n_q2=7, n_q3=5)  # 35 clusters, 245 samples
#: Twice the orientation noise floor (the RMS of the rotation-error norm of the design's noise).
WRIST_DEG = 2 * math.sqrt(3) * DESIGN.noise_deg


def arm(robot):
    cr = load_cell().robot(robot)
    nominal = cr.model()
    return cr, nominal, GravityModel.from_spec(cr.robot, nominal)


def test_noise_floors_of_both_channels_recover_known_noise():
    rng = np.random.default_rng(0)
    groups = np.repeat(np.arange(300), 7)
    w = rotation_residual_scale(DEFAULT_ORIENTATION_WEIGHT)
    r = np.zeros((2100, 6))
    r[:, :3] = rng.normal(0, 0.03, (2100, 3)) + rng.normal(0, 1, (300, 3))[groups]
    r[:, 3:] = w * (rng.normal(0, np.radians(0.02), (2100, 3)) + rng.normal(0, 0.01, (300, 3))[groups])
    nf = noise_floor(r, groups, 0, w)
    np.testing.assert_allclose(nf.within_cluster_mm, 0.03 * np.sqrt(3), rtol=0.05)
    np.testing.assert_allclose(nf.within_cluster_deg, 0.02 * np.sqrt(3), rtol=0.05)
    assert nf.floor_deg == nf.within_cluster_deg and nf.fit_residual_deg > 10 * nf.floor_deg


def test_channel_weight_whitens_both_channels_and_says_when_it_cannot():
    nf = noise_floor(np.zeros((1, 6)), np.zeros(1), 0)  # no orientation floor
    a, note = channel_weight(nf, 1641.0)
    assert a == 1641.0 and "could not be estimated" in note
    nf = type(nf)(0.05, 0.05, 0.06, 0.02, 0.02, 0.03)
    a, note = channel_weight(nf, 1641.0)
    np.testing.assert_allclose(rotation_residual_scale(a), 0.05 / math.radians(0.02))
    assert note == ""
    nf = type(nf)(0.05, 0.05, 0.06, 1e-9, 1e-9, 1e-9)  # noise-free orientation: bounded, and said
    a, note = channel_weight(nf, 1641.0)
    assert a == pytest.approx(1641.0 * WEIGHT_RANGE) and "bounded" in note


def test_rule_reads_the_weighed_loss_of_both_channels_when_given():
    opts = SelectionOptions()
    same_position = Evidence(-50.0, 1e-9, 5.0, 0.1, 0.1, loss_before=2.0, loss_after=1.0)
    assert same_position.accepted(opts)
    assert not Evidence(-50.0, 1e-9, 5.0, 0.1, 0.1).accepted(opts)  # without a loss: the position must improve
    assert not Evidence(-50.0, 1e-9, 5.0, 0.2, 0.1, loss_before=1.0, loss_after=1.1).accepted(opts)


@pytest.mark.parametrize("robot,seed", [("R1", 1), ("R2", 0), ("R2", 1)])
def test_orientation_dominated_wrist_effect_is_found(robot, seed):
    cr, nominal, gravity = arm(robot)
    twin, fit, ho = make_wrist_case(nominal, gravity, WRIST_DEG, seed, DESIGN, n_heldout=200)
    planted = twin.effect("gear_transmission")
    _, p0 = twin.geometry.fk(fit.q)
    from calibration.physics import apply_effects
    _, p1 = apply_effects(twin.geometry, [planted], fit.q, fit.context())
    assert np.sqrt(np.mean(np.sum((p1 - p0) ** 2, axis=1))) < DESIGN.noise_mm  # below the position noise
    np.testing.assert_allclose(orientation_rms_deg(twin.geometry, planted, fit.q, fit.context()), WRIST_DEG)
    res = diagnose(robot, nominal, fit, ho, gravity=gravity, joint_limits=(cr.robot.lower_rad, cr.robot.upper_rad))
    assert [(e.kind, e.joints) for e in res.effects] == [("gear_transmission", (6,))]
    assert res.final.rms_deg <= 1.3 * res.noise.floor_deg
    assert res.final.rms_mm <= 1.3 * res.noise.floor_mm
    np.testing.assert_allclose(res.noise.floor_deg, math.sqrt(3) * DESIGN.noise_deg, rtol=0.15)
    np.testing.assert_allclose(res.noise.floor_mm, math.sqrt(3) * DESIGN.noise_mm, rtol=0.15)
    j = res.to_json()
    assert j["noise_floor_deg"] == pytest.approx(res.noise.floor_deg) and j["orientation_weight"]["source"] == "noise"
    assert set(j["noise_estimates_deg"]) == {"within_cluster", "fit_residual"}


def test_nothing_is_found_on_noise_with_per_channel_weights():
    cr, nominal, gravity = arm("R2")
    twin, fit, ho = make_wrist_case(nominal, gravity, 1e-9, 7, DESIGN, n_heldout=200)
    res = diagnose("R2", nominal, fit, ho, gravity=gravity)
    assert res.effects == () and res.weighting == "noise"
    # the estimated weight whitens the design's noise (0.03 mm, 0.01 deg per axis) within 30 %
    np.testing.assert_allclose(rotation_residual_scale(res.orientation_weight_a),
                               DESIGN.noise_mm / math.radians(DESIGN.noise_deg), rtol=0.3)


def test_unknown_weighting_is_refused():
    cr, nominal, gravity = arm("R1")
    _, fit, ho = make_wrist_case(nominal, gravity, 1e-9, 0, DESIGN, n_heldout=20)
    with pytest.raises(ModelError, match="valid: noise, fixed"):
        diagnose("R1", nominal, fit, ho, options=DiagnoseOptions(weighting="equal"))


def test_the_fixed_weight_stays_when_the_noise_weight_costs_held_out_position(monkeypatch):
    """The noise weight is kept only while the model in use's held-out position RMS at it is within
    ``WEIGHT_CHECK`` of that at the fixed weight; past it the diagnosis says so and weighs by the fixed a."""
    from calibration.diagnosis import core

    cr, nominal, gravity = arm("R1")
    _, fit, ho = make_wrist_case(nominal, gravity, 1e-9, 0, Design(n_q2=4, n_q3=3), n_heldout=60)
    monkeypatch.setattr(core, "WEIGHT_CHECK", 0.5)  # any ratio above half: the fallback must act
    res = diagnose("R1", nominal, fit, ho, gravity=gravity)
    assert res.weighting == "fixed" and res.orientation_weight_a == DEFAULT_ORIENTATION_WEIGHT
    assert any("weighed by the fixed a" in n for n in res.notes)
    assert res.to_json()["orientation_weight"] == {"a": DEFAULT_ORIENTATION_WEIGHT, "source": "fixed"}
    monkeypatch.setattr(core, "WEIGHT_CHECK", 1e9)
    assert diagnose("R1", nominal, fit, ho, gravity=gravity).weighting == "noise"
