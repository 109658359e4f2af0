"""The extrapolation guard: the training region, its soft clamp, the count of poses outside it, and physics
effects held at the edge of what the training data identified."""

from __future__ import annotations

import math

import numpy as np
import pytest

from calibration.errors import ModelError
from calibration.models import load_model, save_model
from calibration.models.guard import REGION_KEY, Region, extrapolation
from calibration.physics import GearTransmission, PhysicsModel
from cell_config import load_cell

ca = pytest.importorskip("casadi")


@pytest.fixture(scope="module")
def region():
    return Region(np.radians([-1, -50, -40, -1, -1, -1.0]), np.radians([1, 50, 30, 1, 1, 1.0]), math.radians(2))


def test_clamp_is_the_identity_inside_and_saturates_within_the_margin_outside(region):
    rng = np.random.default_rng(0)
    inside = rng.uniform(region.lower_rad, region.upper_rad, (50, 6))
    np.testing.assert_array_equal(region.clamp(inside), inside)
    far = np.radians(rng.uniform(-170, 170, (200, 6)))
    c = region.clamp(far)
    assert np.all(c >= region.lower_rad - region.margin_rad) and np.all(c <= region.upper_rad + region.margin_rad)
    # continuous with slope 1 at the edge, monotone beyond it
    h = 1e-7
    edge = region.upper_rad[None] + np.array([[-h], [h]])
    np.testing.assert_allclose(np.diff(region.clamp(edge), axis=0), 2 * h, rtol=1e-5)
    ramp = region.upper_rad[None] + np.linspace(0, 1, 50)[:, None]
    assert np.all(np.diff(region.clamp(ramp), axis=0) >= 0)


def test_casadi_clamp_matches_numpy(region):
    qs = ca.SX.sym("q", 6)
    f = ca.Function("c", [qs], [region.clamp_casadi(qs)])
    q = np.radians(np.random.default_rng(1).uniform(-120, 120, (30, 6)))
    np.testing.assert_allclose(np.vstack([np.asarray(f(x)).ravel() for x in q]), region.clamp(q), atol=1e-12)


def test_bad_region_is_refused():
    with pytest.raises(ModelError, match="lower <= upper"):
        Region(np.zeros(6), -np.ones(6))
    with pytest.raises(ModelError, match="bad training_region"):
        Region.from_dict({"lower_rad": [0.0]})


def test_extrapolation_counts_poses_outside_and_by_how_much(region):
    spec = load_cell().robot("R1")
    model = PhysicsModel("R1", "t", spec.model(), (), 0, {REGION_KEY: region.to_dict()})
    q = np.zeros((4, 6))
    q[1, 0] = math.radians(11.0)  # 10 deg beyond q1's range
    q[2, 5] = math.radians(-31.0)  # 30 deg beyond q6's range
    ex = extrapolation(model, q)
    assert ex["poses"] == 4 and ex["outside_training_range"] == 2 and ex["region_known"]
    assert ex["max_excess_deg"] == pytest.approx(30.0)
    assert ex["rms_excess_deg"] == pytest.approx(math.sqrt((10.0**2 + 30.0**2) / 2))
    np.testing.assert_allclose(ex["max_excess_deg_per_joint"], [10, 0, 0, 0, 0, 30], atol=1e-9)
    unknown = extrapolation(PhysicsModel("R1", "t", spec.model()), q)
    assert not unknown["region_known"] and unknown["outside_training_range"] is None


def test_effect_fitted_in_a_narrow_band_is_held_at_its_edge_outside(region, tmp_path):
    """A joint-6 gear error identified within +-1 deg does not swing through its period 40-120 deg away."""
    from calibration import so3

    arm = load_cell().robot("R1").model()
    gear = GearTransmission(((6, (1, 2)),), np.array([3e-3, 0.0, 2e-3, 0.0]))  # sines: small near q6 = 0
    guarded = PhysicsModel("R1", "diagnose", arm, (gear,), 0, {REGION_KEY: region.to_dict()})
    plain = PhysicsModel("R1", "diagnose", arm, (gear,), 0)
    rng = np.random.default_rng(2)
    inside = rng.uniform(region.lower_rad, region.upper_rad, (20, 6))
    for a, b in zip(guarded.fk(inside), plain.fk(inside)):
        np.testing.assert_array_equal(a, b)
    far = inside.copy()
    far[:, 5] = np.radians(rng.uniform(40, 120, 20))

    def deflection(model, q):  # a joint-6 error rotates the tool by |dq6|
        return np.linalg.norm(so3.log(model.fk(q)[0] @ np.swapaxes(arm.fk(q)[0], 1, 2)), axis=1)

    q_band = np.zeros((400, 6))
    q_band[:, 5] = np.linspace(region.lower_rad[5] - region.margin_rad, region.upper_rad[5] + region.margin_rad, 400)
    reach = deflection(plain, q_band).max()  # what the effect does within the training range and the clamp band
    assert deflection(guarded, far).max() <= reach * (1 + 1e-6)
    assert deflection(plain, far).max() > 2 * reach  # unguarded, it swings far beyond
    save_model(guarded, tmp_path / "m.json")
    back = load_model(tmp_path / "m.json")
    for a, b in zip(back.fk(far), guarded.fk(far)):
        np.testing.assert_allclose(a, b, atol=1e-12)


def test_extrapolation_says_whether_the_guard_acted_and_by_how_much(region):
    """Outside the range, a configuration-dependent effect makes the guard act (reported with the position change it
    made); a rigid model, or every pose inside, leaves it idle."""
    arm = load_cell().robot("R1").model()
    gear = GearTransmission(((2, (1, 2)),), np.array([3e-3, 0.0, 2e-3, 0.0]))
    guarded = PhysicsModel("R1", "diagnose", arm, (gear,), 0, {REGION_KEY: region.to_dict()})
    plain = PhysicsModel("R1", "diagnose", arm, (gear,), 0)
    rng = np.random.default_rng(3)
    inside = rng.uniform(region.lower_rad, region.upper_rad, (10, 6))
    far = inside.copy()
    far[:, 1] = np.radians(rng.uniform(70, 120, 10))  # joint 2 20-70 deg beyond its range
    ex = extrapolation(guarded, far)
    shift = np.max(np.linalg.norm(guarded.fk(far)[1] - plain.fk(far)[1], axis=1))
    assert ex["guard_acted"] and shift > 0.1
    assert ex["guard_shift_mm_max"] == pytest.approx(shift, rel=1e-12)
    idle = extrapolation(guarded, inside)
    assert not idle["guard_acted"] and idle["guard_shift_mm_max"] == 0.0
    rigid = extrapolation(PhysicsModel("R1", "t", arm, (), 0, {REGION_KEY: region.to_dict()}), far)
    assert rigid["outside_training_range"] == 10 and not rigid["guard_acted"] and rigid["guard_shift_mm_max"] == 0.0


def test_region_of_data_takes_each_joints_margin_from_its_own_spread():
    """The clamp margin is a share of each joint's training span (a joint the data never moved: the floor), so an
    effect seen within +-2 deg of the wrist is not carried 2 deg further, while one seen over 100 deg of joint 2
    keeps the 2 deg cap; a region saved with one margin reads back unchanged."""
    from calibration.models.guard import DEFAULT_MARGIN_RAD, MARGIN_SHARE, MIN_MARGIN_RAD

    rng = np.random.default_rng(4)
    q = np.zeros((200, 6))
    q[:, 1] = np.radians(rng.uniform(-55, 50, 200))
    q[:, 5] = np.radians(rng.uniform(-2, 2, 200))
    r = Region.of(q)
    span = q.max(axis=0) - q.min(axis=0)
    np.testing.assert_allclose(r.margin_rad, np.clip(MARGIN_SHARE * span, MIN_MARGIN_RAD, DEFAULT_MARGIN_RAD))
    assert r.margin_rad[0] == MIN_MARGIN_RAD and r.margin_rad[5] < math.radians(0.5)
    assert r.margin_rad[1] == DEFAULT_MARGIN_RAD
    far = np.zeros((1, 6))
    far[0, 5] = math.radians(60.0)
    assert r.clamp(far)[0, 5] <= r.upper_rad[5] + MARGIN_SHARE * span[5]
    back = Region.from_dict(r.to_dict())
    np.testing.assert_array_equal(back.margin_rad, r.margin_rad)
    qs = ca.SX.sym("q", 6)
    f = ca.Function("c", [qs], [r.clamp_casadi(qs)])
    probe = np.radians(rng.uniform(-120, 120, (20, 6)))
    np.testing.assert_allclose(np.vstack([np.asarray(f(x)).ravel() for x in probe]), r.clamp(probe), atol=1e-12)
    old = Region.from_dict({"lower_rad": [0.0] * 6, "upper_rad": [1.0] * 6, "margin_rad": 0.05})
    assert old.margin_rad == 0.05 and old.to_dict()["margin_rad"] == 0.05
    with pytest.raises(ModelError, match="one per joint"):
        Region(np.zeros(6), np.ones(6), np.ones(5))
