"""The extrapolation guard: the training region, its soft clamp, the count of poses outside it, and physics
effects held at the edge of what the training data identified."""

from __future__ import annotations

import math

import numpy as np
import pytest

from calibration.errors import ModelError
from calibration.models import load_model, save_model
from calibration.models.guard import REGION_KEY, Region, extrapolation
from calibration.models.physics import PhysicsModel
from calibration.physics import GearTransmission
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


def test_a_pose_a_rounding_past_the_edge_is_not_counted_outside(region):
    """A pose 0.03 deg past the range was counted, and the warning said 'by up to 0.0 deg': only an excess beyond
    OUTSIDE_TOLERANCE_DEG counts, and the largest counted excess prints as at least 0.1 deg."""
    from calibration.models.guard import OUTSIDE_TOLERANCE_DEG

    assert OUTSIDE_TOLERANCE_DEG <= 0.05  # half the printed 0.1 deg: a counted excess never prints as 0.0
    model = PhysicsModel("R1", "t", load_cell().robot("R1").model(), (), 0, {REGION_KEY: region.to_dict()})
    q = np.zeros((3, 6))
    q[:, 0] = region.upper_rad[0] + np.radians([0.03, OUTSIDE_TOLERANCE_DEG - 1e-6, OUTSIDE_TOLERANCE_DEG + 0.01])
    ex = extrapolation(model, q)
    assert ex["outside_training_range"] == 1 and ex["outside_tolerance_deg"] == OUTSIDE_TOLERANCE_DEG
    assert f"{ex['rms_excess_deg']:.1f}" == "0.1" and ex["max_excess_deg"] == pytest.approx(0.06)
    assert extrapolation(model, q[:2])["outside_training_range"] == 0


def test_effect_fitted_in_a_narrow_band_is_held_at_its_edge_outside(region, tmp_path):
    """A joint-6 gear error identified within +-1 deg does not swing through its period 40-120 deg away."""
    from calibration.kinematics import so3

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
    gear = GearTransmission(((6, (1, 2)),), np.array([3e-3, 0.0, 2e-3, 0.0]))
    guarded = PhysicsModel("R1", "diagnose", arm, (gear,), 0, {REGION_KEY: region.to_dict()})
    plain = PhysicsModel("R1", "diagnose", arm, (gear,), 0)
    rng = np.random.default_rng(3)
    inside = rng.uniform(region.lower_rad, region.upper_rad, (10, 6))
    far = inside.copy()
    far[:, 5] = np.radians(rng.uniform(30, 120, 10))  # joint 6 (seen within +-1 deg) 29-119 deg beyond its range
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


def _mixed(region: Region) -> tuple:
    """The R1 arm, its YAML gravity, a compliance under that gravity on joints 2 and 3 and a joint-5 gear error, and
    a physics model carrying both with ``region`` as its training region."""
    from calibration.physics import GravityModel, JointCompliance

    spec = load_cell().robot("R1")
    arm = spec.model()
    compliance = JointCompliance(GravityModel.from_spec(spec.robot, arm), (2, 3), np.array([4e-6, 6e-6]))
    gear = GearTransmission(((5, (1, 2)),), np.array([3e-3, 0.0, 2e-3, 0.0]))
    return arm, compliance, gear, PhysicsModel("R1", "diagnose", arm, (compliance, gear), 0,
                                               {REGION_KEY: region.to_dict()})


def test_each_effect_is_held_in_the_joints_it_declares(region):
    """Outside the training range a gravity compliance goes on exactly as its formula says (its torque at the true
    q2, q3 and wrist), while a gear error in q5 (seen within +-1 deg) is held at the edge of q5's range and nowhere
    else: the pose is the unguarded formula for the compliance plus the gear's deflection at q5 clamped. Fails on the
    guard that clamped every effect in every joint."""
    arm, compliance, gear, model = _mixed(region)
    assert region.held_joints(compliance) == () and region.held_joints(gear) == (4,)
    rng = np.random.default_rng(5)
    far = rng.uniform(region.lower_rad, region.upper_rad, (30, 6))
    far[:, 1] = np.radians(rng.uniform(60, 110, 30))  # q2 10-60 deg beyond its range
    far[:, 2] = np.radians(rng.uniform(-90, -50, 30))  # q3 10-50 deg below its range
    far[:, 4] = np.radians(rng.uniform(30, 120, 30))  # q5 29-119 deg beyond its range
    q5_held = far.copy()
    q5_held[:, 4] = region.clamp(far)[:, 4]
    dq = compliance.delta_q(arm, far) + gear.delta_q(arm, q5_held)
    R, p = model.fk(far)
    R_want, p_want = arm.fk(far + dq)
    np.testing.assert_allclose(p, p_want, atol=1e-9)
    np.testing.assert_allclose(R, R_want, atol=1e-12)
    # the compliance's deflection far out is what its formula gives there, not its value at the edge
    edge = compliance.delta_q(arm, region.clamp(far))
    assert np.max(np.abs(compliance.delta_q(arm, far) - edge)) > 1e-4
    # the gear stays within what it did inside the range and the clamp band of q5
    band = np.zeros((400, 6))
    band[:, 4] = np.linspace(region.lower_rad[4] - region.margin_rad, region.upper_rad[4] + region.margin_rad, 400)
    assert np.abs(gear.delta_q(arm, q5_held)[:, 4]).max() <= np.abs(gear.delta_q(arm, band)[:, 4]).max() + 1e-12
    assert np.abs(gear.delta_q(arm, far)[:, 4]).max() > 2 * np.abs(gear.delta_q(arm, band)[:, 4]).max()


def test_each_effect_is_held_in_its_own_joints_in_casadi_too(region):
    """The casadi expression holds each effect as the numpy pose does (the compliance's torque at the true q, the
    gear at q5 clamped)."""
    _, _, _, model = _mixed(region)
    qs = ca.SX.sym("q", 6)
    pose = model.casadi(qs)
    f = ca.Function("p", [qs], [pose.p, pose.R])
    far = np.radians(np.random.default_rng(6).uniform(-120, 120, (15, 6)))
    R, p = model.fk(far)
    for i, x in enumerate(far):
        pc, Rc = f(x)
        np.testing.assert_allclose(np.asarray(pc).ravel(), p[i], atol=1e-9)
        np.testing.assert_allclose(np.asarray(Rc), R[i], atol=1e-12)


def test_a_region_saved_before_the_rule_keeps_holding_every_effect_in_every_joint(region, tmp_path):
    """A model file whose training region has no ``rule`` predicts what it predicted before: every effect evaluated at
    q clamped in every joint. A region saved now carries its rule and reads back with it, bit for bit."""
    from calibration.models.guard import RULE_BY_EFFECT, RULE_EVERY_JOINT

    arm, compliance, gear, model = _mixed(region)
    old_dict = {k: v for k, v in region.to_dict().items() if k != "rule"}
    old = Region.from_dict(old_dict)
    assert old.rule == RULE_EVERY_JOINT and Region.from_dict(region.to_dict()).rule == RULE_BY_EFFECT
    assert Region.of(np.zeros((3, 6))).rule == RULE_BY_EFFECT
    far = np.radians(np.random.default_rng(7).uniform(-120, 120, (20, 6)))
    old_model = PhysicsModel("R1", "diagnose", arm, (compliance, gear), 0, {REGION_KEY: old_dict})
    save_model(old_model, tmp_path / "old.json")
    back = load_model(tmp_path / "old.json")
    clamped = region.clamp(far)
    R0, p0 = arm.fk(far + compliance.delta_q(arm, clamped) + gear.delta_q(arm, clamped))  # the guard before the rule
    for a, b in zip(back.fk(far), (R0, p0)):
        np.testing.assert_allclose(a, b, atol=1e-9)
    assert np.max(np.abs(back.fk(far)[1] - model.fk(far)[1])) > 1e-3  # the two rules differ out there
    save_model(model, tmp_path / "new.json")
    new = load_model(tmp_path / "new.json")
    assert new.info[REGION_KEY]["rule"] == RULE_BY_EFFECT
    for a, b in zip(new.fk(far), model.fk(far)):
        np.testing.assert_array_equal(a, b)
    with pytest.raises(ModelError, match="unknown guard rule"):
        Region.from_dict({**region.to_dict(), "rule": "sometimes"})


def test_a_harmonic_fitted_over_a_wide_range_goes_on_as_fitted_one_fitted_in_a_narrow_band_is_held(region):
    """The guard holds a fitted shape only in the joints the data saw narrowly: a joint-2 gear error identified over
    100 deg of q2 goes on as fitted 10-60 deg beyond it, the same error on joint 6 (seen within +-1 deg) is held."""
    from calibration.models.guard import NARROW_SPAN_RAD

    arm = load_cell().robot("R1").model()
    assert list(region.narrow()) == [True, False, False, True, True, True]
    assert region.upper_rad[1] - region.lower_rad[1] > NARROW_SPAN_RAD > region.upper_rad[5] - region.lower_rad[5]
    values = np.array([3e-3, 0.0, 2e-3, 0.0])
    rng = np.random.default_rng(8)
    far = rng.uniform(region.lower_rad, region.upper_rad, (20, 6))
    far[:, 1] = np.radians(rng.uniform(60, 110, 20))
    far[:, 5] = np.radians(rng.uniform(30, 120, 20))
    for joint, held in ((2, False), (6, True)):
        gear = GearTransmission(((joint, (1, 2)),), values)
        guarded = PhysicsModel("R1", "diagnose", arm, (gear,), 0, {REGION_KEY: region.to_dict()})
        plain = PhysicsModel("R1", "diagnose", arm, (gear,), 0)
        shift = np.max(np.linalg.norm(guarded.fk(far)[1] - plain.fk(far)[1], axis=1))
        assert region.held_joints(gear) == ((joint - 1,) if held else ())
        assert (shift > 0.1) if held else (shift == 0.0)


# --- time and temperature -------------------------------------------------------------------------------------

def _warm(region_dict, mode="warmup"):
    """A physics model of R1 whose forearm grows by 2 mm with a one-hour warm-up (or 0.1 mm per kelvin)."""
    from calibration.physics import ThermalDrift

    spec = load_cell().robot("R1")
    drift = (ThermalDrift(("p34",), np.array([2.0]), "warmup", tau_s=3600.0) if mode == "warmup" else
             ThermalDrift(("p34",), np.array([0.1]), "temperature", ref_temp_c=20.0))
    return PhysicsModel("R1", "diagnose", spec.model(), (drift,), 0, {REGION_KEY: region_dict})


def _timed_region(region):
    return Region(region.lower_rad, region.upper_rad, region.margin_rad,
                  context_range={"t": (0.0, 600.0), "temp_c": (20.0, 25.0)})


def test_the_context_range_round_trips_and_a_bad_one_is_refused(region, tmp_path):
    timed = _timed_region(region)
    assert Region.from_dict(timed.to_dict()).context_range == {"t": (0.0, 600.0), "temp_c": (20.0, 25.0)}
    assert "context_range" not in region.to_dict() and Region.from_dict(region.to_dict()).context_range == {}
    model = _warm(timed.to_dict())
    save_model(model, tmp_path / "m.yaml")
    assert load_model(tmp_path / "m.yaml").region().context_range == timed.context_range
    with pytest.raises(ModelError, match="context range needs finite lower <= upper.*'t'"):
        Region(region.lower_rad, region.upper_rad, context_range={"t": (600.0, 0.0)})
    with pytest.raises(ModelError, match="entries among t, temp_c, payload_kg, got 'speed'"):
        Region(region.lower_rad, region.upper_rad, context_range={"speed": (0.0, 1.0)})
    rec_context = {"t": np.array([5.0, 300.0, 60.0]), "dir1": np.ones(3), "qd": np.zeros((3, 6))}
    assert Region.of(np.zeros((3, 6)), context=rec_context).context_range == {"t": (5.0, 300.0)}


def test_a_warm_up_fitted_on_ten_minutes_is_held_at_their_edge_hours_later(region):
    timed = _timed_region(region)
    guarded, unguarded = _warm(timed.to_dict()), _warm(region.to_dict())
    q = np.zeros((4, 6))
    inside = {"t": np.array([0.0, 100.0, 300.0, 600.0])}
    for a, b in zip(guarded.fk_context(q, inside), unguarded.fk_context(q, inside)):
        np.testing.assert_array_equal(a, b)  # inside the training time span: the fit as it is
    late = {"t": np.array([600.0, 1800.0, 3600.0, 14400.0])}
    p, p_free = guarded.fk_context(q, late)[1], unguarded.fk_context(q, late)[1]
    p_edge = unguarded.fk_context(q[:1], {"t": np.array([600.0 + 0.1 * 600.0])})[1]
    grown = np.linalg.norm(p - p[0], axis=1)
    assert np.all(grown <= np.linalg.norm(p_edge[0] - p[0]) + 1e-12)  # never past edge + margin (60 s)
    assert np.all(np.diff(grown) >= 0)  # still monotone
    assert np.linalg.norm(p_free[3] - p_free[0]) > 1.0  # unheld, 4 h later the curve promises over a millimetre
    early = Region(region.lower_rad, region.upper_rad, region.margin_rad, context_range={"t": (100.0, 600.0)})
    for a, b in zip(_warm(early.to_dict()).fk(q), unguarded.fk(q)):  # the default context (t = 0) is never held
        np.testing.assert_array_equal(a, b)


def test_a_growth_per_kelvin_goes_on_as_its_formula_says(region):
    timed = _timed_region(region)
    q, hot = np.zeros((2, 6)), {"temp_c": np.array([22.0, 40.0])}
    for a, b in zip(_warm(timed.to_dict(), "temperature").fk_context(q, hot),
                    _warm(region.to_dict(), "temperature").fk_context(q, hot)):
        np.testing.assert_array_equal(a, b)


def test_extrapolation_counts_poses_beyond_the_time_and_temperature_of_the_training_data(region):
    model = _warm(_timed_region(region).to_dict())
    q = np.zeros((5, 6))
    context = {"t": np.array([0.0, 300.0, 900.0, 3600.0, 600.0]), "temp_c": np.full(5, 26.5)}
    ex = extrapolation(model, q, context)
    assert ex["outside_training_range"] == 0
    assert ex["outside_context_range"] == {
        "t": {"poses": 2, "max_excess": 3000.0, "unit": "s", "range": [0.0, 600.0]},
        "temp_c": {"poses": 5, "max_excess": 1.5, "unit": "deg C", "range": [20.0, 25.0]}}
    assert ex["guard_acted"] and ex["guard_shift_mm_max"] > 0.5
    assert extrapolation(model, q)["outside_context_range"] == {}  # no context given: nothing to say
    inside = extrapolation(model, q, {"t": np.full(5, 100.0)})
    assert inside["outside_context_range"]["t"]["poses"] == 0 and not inside["guard_acted"]


def test_a_rebased_model_gives_its_inner_model_the_context(region):
    from calibration.models.rebased import RebasedModel
    from tests.calibration.models.kinds import T_BASE, T_TOOL

    inner = _warm(_timed_region(region).to_dict())
    rebased = RebasedModel("R1", "diagnose", inner, T_BASE, T_TOOL)
    q, late = np.zeros((2, 6)), {"t": np.array([300.0, 620.0])}
    shifted = RebasedModel("R1", "diagnose", inner).fk_context(q, late)
    for a, b in zip(shifted, inner.fk_context(q, late)):
        np.testing.assert_array_equal(a, b)
    assert np.linalg.norm(rebased.fk_context(q, late)[1] - rebased.fk(q)[1], axis=1).min() > 0.01


def test_a_diagnosed_model_holds_its_warm_up_too(region):
    from calibration.models.diagnosed import DiagnosedModel
    from calibration.physics import ThermalDrift
    from tests.calibration.models.kinds import models_of_every_kind

    pi = models_of_every_kind().pi
    drift = (ThermalDrift(("p34",), np.array([2.0]), "warmup", tau_s=3600.0),)
    guarded = DiagnosedModel("R1", "diagnose", pi, drift, {REGION_KEY: _timed_region(region).to_dict()})
    unguarded = DiagnosedModel("R1", "diagnose", pi, drift, {REGION_KEY: region.to_dict()})
    q, late = np.zeros((2, 6)), {"t": np.array([300.0, 14400.0])}
    p, p_free = guarded.fk_context(q, late)[1], unguarded.fk_context(q, late)[1]
    np.testing.assert_array_equal(p[0], p_free[0])
    assert np.linalg.norm(p[1] - p[0]) < 0.5 < np.linalg.norm(p_free[1] - p_free[0])


def test_a_warm_up_recorded_for_longer_than_its_time_constant_goes_on_as_fitted(region):
    long = Region(region.lower_rad, region.upper_rad, region.margin_rad, context_range={"t": (0.0, 4000.0)})
    model = _warm(long.to_dict())  # tau 3600 s, seen over 4000 s: the bend is in the data
    assert long.held_context(model.effects[0]) == {}
    q, late = np.zeros((2, 6)), {"t": np.array([1000.0, 14400.0])}
    for a, b in zip(model.fk_context(q, late), _warm(region.to_dict()).fk_context(q, late)):
        np.testing.assert_array_equal(a, b)
    assert extrapolation(model, q, late)["outside_context_range"]["t"]["poses"] == 1  # still counted and said


@pytest.mark.parametrize("end_s, held", [(600.0, True), (800.0, True), (810.0, False), (1200.0, False)])
def test_a_warm_up_is_held_when_its_recording_saw_less_than_a_fifth_of_its_rise(region, end_s, held):
    """tau 3600 s: a cold start sees a fifth of the rise in 3600 ln(5/4) = 803 s. The rule before held any recording
    shorter than tau, which on the synthetic twins also held the fits that had found their time constant."""
    rec = Region(region.lower_rad, region.upper_rad, region.margin_rad, context_range={"t": (0.0, end_s)})
    assert rec.to_dict()["context_rule"] == "rise_share"
    assert rec.held_context(_warm(rec.to_dict()).effects[0]) == ({"t": "above"} if held else {})


def test_a_region_saved_before_the_rise_rule_keeps_its_hold_in_time(region, tmp_path):
    """A model file saved with the first rule (no context_rule) predicts what it predicted: held below tau."""
    d = Region(region.lower_rad, region.upper_rad, region.margin_rad, context_range={"t": (0.0, 1200.0)}).to_dict()
    del d["context_rule"]
    old = Region.from_dict(d)
    assert old.context_rule == "span" and old.held_context(_warm(d).effects[0]) == {"t": "above"}
    model = _warm(d)
    save_model(model, tmp_path / "old.yaml")
    q, late = np.zeros((2, 6)), {"t": np.array([600.0, 14400.0])}
    again = load_model(tmp_path / "old.yaml")
    np.testing.assert_array_equal(again.fk_context(q, late)[1], model.fk_context(q, late)[1])
    new = _warm({**d, "context_rule": "rise_share"})
    assert np.linalg.norm(new.fk_context(q, late)[1][1] - model.fk_context(q, late)[1][1]) > 0.1
    with pytest.raises(ModelError, match="unknown context rule 'fifth'; valid: rise_share, span"):
        Region.from_dict({**d, "context_rule": "fifth"})


def test_a_warm_up_is_not_held_before_its_recording_where_its_formula_pins_it(region):
    later = Region(region.lower_rad, region.upper_rad, region.margin_rad, context_range={"t": (3600.0, 4200.0)})
    assert later.held_context(_warm(later.to_dict()).effects[0]) == {"t": "above"}
    q, cold = np.zeros((3, 6)), {"t": np.array([0.0, 60.0, 600.0])}
    for a, b in zip(_warm(later.to_dict()).fk_context(q, cold), _warm(region.to_dict()).fk_context(q, cold)):
        np.testing.assert_array_equal(a, b)


def test_context_entries_of_one_row_are_every_rows_and_a_wrong_length_is_named(region):
    model = _warm(_timed_region(region).to_dict())
    q = np.zeros((3, 6))
    one = extrapolation(model, q, {"t": np.array([5000.0])})
    assert one["outside_context_range"]["t"]["poses"] == 3 and one["guard_acted"]
    full = extrapolation(model, q, {"t": np.full(3, 5000.0), "qd": np.zeros((3, 6)), "dir1": np.ones(3), "x": None})
    assert full["guard_shift_mm_max"] == one["guard_shift_mm_max"]
    with pytest.raises(ModelError, match=r"context\['t'\] must be a scalar or have shape \(3,\)"):
        model.fk_context(q, {"t": np.zeros(2)})
    with pytest.raises(ModelError, match=r"context\['t'\] must be a scalar or have shape \(3,\)"):
        extrapolation(model, q, {"t": np.zeros(2)})
    assert Region.of(q, context={"t": None, "temp_c": np.array([20.0, np.nan, 24.0])}).context_range == {
        "temp_c": (20.0, 24.0)}


def test_a_rebased_model_says_its_inner_models_guard_acted(region):
    from calibration.models.rebased import RebasedModel
    from tests.calibration.models.kinds import T_BASE, T_TOOL

    timed = _timed_region(region).to_dict()
    inner = _warm(timed)
    rebased = RebasedModel("R1", "diagnose", inner, T_BASE, T_TOOL, info={REGION_KEY: timed})
    late = {"t": np.array([300.0, 14400.0])}
    ex, ex_inner = extrapolation(rebased, np.zeros((2, 6)), late), extrapolation(inner, np.zeros((2, 6)), late)
    assert ex["guard_acted"] and ex["outside_context_range"] == ex_inner["outside_context_range"]
    np.testing.assert_allclose(ex["guard_shift_mm_max"], ex_inner["guard_shift_mm_max"], rtol=1e-9)
