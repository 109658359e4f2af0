"""Properties of the physics effects, gravity torques, the twin and the physics model file."""

from __future__ import annotations

import json

import numpy as np
import pytest

import calibration.models.physics  # noqa: F401  (fills the KinematicModel registry with "physics")
from calibration.errors import DataError, ModelError
from calibration.kinematics import so3
from calibration.models import load_model, save_model
from calibration.models.physics import PhysicsModel
from calibration.physics import (
    Backlash,
    GearTransmission,
    GravityModel,
    JointCompliance,
    JointOffset,
    LumpedCompliance,
    LumpedPayloadCompliance,
    MocapLatency,
    PayloadCompliance,
    ThermalDrift,
    Twin,
    apply_effects,
    effect_from_dict,
)
from cell_config.loader import load_cell

G = 9.80665


@pytest.fixture(scope="module")
def cell():
    return load_cell()


@pytest.fixture(scope="module")
def r1(cell):
    cr = cell.robot("R1")
    m = cr.model()
    return cr, m, GravityModel.from_spec(cr.robot, m)


def random_q(cr, N, seed=0):
    return np.random.default_rng(seed).uniform(cr.robot.lower_rad, cr.robot.upper_rad, (N, 6))


def all_effects(gravity):
    """Every effect kind with non-trivial parameters (small enough for first-order checks)."""
    return [
        JointCompliance(gravity, (2, 3, 5), np.array([2e-7, 4e-7, 1e-6])),
        PayloadCompliance((2, 3), np.array([3e-7, 5e-7])),
        GearTransmission(((1, (1, 2)), (4, (1,))), np.array([3e-5, -2e-5, 1e-5, 4e-6, -2e-5, 1e-5])),
        Backlash((1, 2, 3), np.array([2e-4, 3e-4, 1e-4])),
        ThermalDrift(("p23", "p34"), np.array([0.08, 0.12]), tau_s=1200.0),
        MocapLatency(values=np.array([0.004])),
        JointOffset((2, 6), np.array([1e-4, -2e-4])),
        LumpedCompliance((2, 3), ((5, 8, 14), (9, 22)), np.array([2e-7, -1e-5, 3e-7, 1e-7, -2e-7])),
        LumpedPayloadCompliance((2, 3), np.array([3e-7, 2e-9, -1e-9, 3e-9, 5e-7, -2e-9, 1e-9, 2e-9])),
    ]


def context(N, seed=1):
    rng = np.random.default_rng(seed)
    ctx = {f"dir{i + 1}": rng.choice([-1.0, 0.0, 1.0], N) for i in range(6)}
    ctx.update(t=rng.uniform(0, 5000, N), payload_kg=rng.uniform(0, 6, N), qd=rng.uniform(-0.3, 0.3, (N, 6)))
    return ctx


# --- gravity -----------------------------------------------------------------------------------------------

def numpy_gravity(gm: GravityModel, model, q: np.ndarray) -> np.ndarray:
    """An independent gravity torque [N m]: ``sum_k J_com,k^T m_k g`` over the links, in numpy."""
    from calibration.physics.gravity import joint_origins

    c = model.chain(q)
    mass, com0 = gm.masses_coms(model)
    o0 = joint_origins(model)
    g_vec = np.array([0.0, 0.0, -gm.g])
    tau = np.zeros((q.shape[0], model.n_joints))
    for k in range(model.n_joints):
        com = c.p_base_origin[k] + c.R_base_link[k + 1] @ (com0[k] - o0[k])  # (N, 3) [mm]
        for i in range(k + 1):
            tau[:, i] += mass[k] * (np.cross(c.axes_base[i], com - c.p_base_origin[i]) / 1000.0) @ g_vec
    return tau


@pytest.mark.parametrize("name", ["R1", "R2"])
def test_pinocchio_gravity_matches_numpy_and_regressor(cell, name):
    cr = cell.robot(name)
    m = cr.model()
    gm = GravityModel.from_spec(cr.robot, m)
    q = random_q(cr, 300, seed=3)
    tau_np = numpy_gravity(gm, m, q)
    np.testing.assert_allclose(gm.torque(m, q), tau_np, atol=1e-6)
    np.testing.assert_allclose(gm.regressor(m, q) @ gm.lumped, tau_np, atol=1e-6)
    assert np.abs(tau_np[:, 1]).max() > 100.0  # joint 2 carries hundreds of N m
    np.testing.assert_allclose(tau_np[:, 0], 0.0, atol=1e-9)  # vertical joint 1 carries none


def test_gravity_at_zero_matches_hand_computation(r1):
    cr, m, gm = r1
    tau = gm.torque(m, np.zeros((1, 6)))[0]
    # Axis 2 is +y through x = 150 mm: tau2 = g * sum_k m_k (x_k - 150) for links 2..6; axis 3 is -y.
    links = cr.robot.links
    tau2 = G * sum(l.mass_kg * (l.com_mm[0] - 150.0) for l in links[1:]) / 1000.0
    tau3 = -G * sum(l.mass_kg * (l.com_mm[0] - 150.0) for l in links[2:]) / 1000.0
    np.testing.assert_allclose(tau[1:3], [tau2, tau3], atol=1e-9)


def test_identifiable_lumped_columns_reproduce_torque(r1):
    cr, m, gm = r1
    q = random_q(cr, 200, seed=4)
    cols = gm.independent_columns(m, q)
    assert 0 < cols.size < gm.lumped.size
    Y = gm.regressor(m, q)
    pi, *_ = np.linalg.lstsq(Y[:, :, cols].reshape(-1, cols.size), (Y @ gm.lumped).ravel(), rcond=None)
    np.testing.assert_allclose(Y[:, :, cols] @ pi, Y @ gm.lumped, atol=1e-6)


# --- each effect against a hand computation ----------------------------------------------------------------

def test_joint_compliance_hand(r1):
    cr, m, gm = r1
    c = np.array([2e-7, 4e-7, 1e-6])
    e = JointCompliance(gm, (2, 3, 5), c)
    dq = e.delta_q(m, np.zeros((1, 6)))[0]
    tau = gm.torque(m, np.zeros((1, 6)))[0]
    np.testing.assert_allclose(dq, [0, c[0] * tau[1], c[1] * tau[2], 0, c[2] * tau[4], 0], atol=1e-15)
    assert dq[1] > 0  # sag: the arm tips forward (positive rotation about +y)


def test_joint_compliance_lumped_form(r1):
    """delta_q is linear in the products c_j pi: the gravity regressor contracted with c_j lumped."""
    cr, m, gm = r1
    e = JointCompliance(gm, (2, 3, 5), np.array([2e-7, 4e-7, 1e-6]))
    q = random_q(cr, 50)
    theta = e.values[:, None] * gm.lumped[None, :]
    Yg = gm.regressor(m, q)
    L = np.zeros((q.shape[0], 6, len(e.joints), Yg.shape[2]))
    for col, j in enumerate(e.joints):
        L[:, j - 1, col] = Yg[:, j - 1]
    np.testing.assert_allclose(np.einsum("nicp,cp->ni", L, theta), e.delta_q(m, q), atol=1e-15)
    np.testing.assert_allclose(e.delta_q(m, q) / np.r_[1, e.values[:2], 1, e.values[2], 1][None],
                               np.where([0, 1, 1, 0, 1, 0], gm.torque(m, q), 0.0), atol=1e-9)  # pinocchio agrees


def test_payload_compliance_hand(r1):
    cr, m, _ = r1
    e = PayloadCompliance((2, 3), np.array([3e-7, 5e-7]))
    _, p = m.fk(np.zeros((1, 6)))
    dq = e.delta_q(m, np.zeros((1, 6)), {"payload_kg": np.array([5.0])})[0]
    lever = (p[0, 0] - 150.0) / 1000.0
    np.testing.assert_allclose(dq, [0, 3e-7 * 5 * G * lever, -5e-7 * 5 * G * lever, 0, 0, 0], atol=1e-15)


def test_gear_backlash_latency_offset_hand(r1):
    _, m, _ = r1
    q = np.array([[0.3, 0.1, -0.2, 0.5, 0.4, -0.7]])
    gear = GearTransmission(((1, (1, 2)),), np.array([1e-4, 2e-4, 3e-4, 4e-4]))
    expected = 1e-4 * np.sin(0.3) + 2e-4 * np.cos(0.3) + 3e-4 * np.sin(0.6) + 4e-4 * np.cos(0.6)
    np.testing.assert_allclose(gear.delta_q(m, q)[0], [expected, 0, 0, 0, 0, 0], atol=1e-18)
    bl = Backlash((1, 2, 3), np.array([2e-4, 4e-4, 6e-4]))
    ctx = {"dir1": np.array([1.0]), "dir2": np.array([-1.0]), "dir3": np.array([0.0])}
    np.testing.assert_allclose(bl.delta_q(m, q, ctx)[0], [1e-4, -2e-4, 0, 0, 0, 0], atol=1e-18)
    qd = np.array([[0.1, -0.2, 0.3, 0, 0, 1.0]])
    np.testing.assert_allclose(MocapLatency(values=np.array([0.01])).delta_q(m, q, {"qd": qd}), -0.01 * qd)
    np.testing.assert_allclose(JointOffset((2, 6), np.array([1e-4, -2e-4])).delta_q(m, q)[0],
                               [0, 1e-4, 0, 0, 0, -2e-4])


def test_thermal_hand(r1):
    _, m, _ = r1
    e = ThermalDrift(("p23", "p34"), np.array([0.1, 0.2]), tau_s=1000.0)
    _, p0 = m.fk(np.zeros((1, 6)))
    _, p = apply_effects(m, [e], np.zeros((1, 6)), {"t": np.array([1000.0])})
    u34 = np.array([1082.0, 0, 200.0]) / np.hypot(1082.0, 200.0)
    np.testing.assert_allclose(p[0] - p0[0], (1 - np.exp(-1)) * (0.1 * np.array([0, 0, 1.0]) + 0.2 * u34),
                               atol=1e-9)
    et = ThermalDrift(("p34",), np.array([0.012]), mode="temperature", ref_temp_c=20.0)
    assert et.names == ("growth_p34_mm_per_K",)
    _, p = apply_effects(m, [et], np.zeros((2, 6)), {"temp_c": np.array([20.0, 30.0])})
    np.testing.assert_allclose(p - p0, [np.zeros(3), 0.12 * u34], atol=1e-9)


# --- generic properties of every effect --------------------------------------------------------------------

def test_zero_parameters_change_nothing(r1):
    cr, m, gm = r1
    q = random_q(cr, 40)
    ctx = context(40)
    R0, p0 = m.fk(q)
    zeroed = [e.with_values(np.zeros(e.size)) for e in all_effects(gm)]
    for e in zeroed:
        np.testing.assert_array_equal(e.delta_q(m, q, ctx), 0.0)
    R, p = apply_effects(m, zeroed, q, ctx)
    np.testing.assert_allclose(p, p0, atol=1e-12)
    np.testing.assert_allclose(R, R0, atol=1e-14)


def test_regressor_is_linear_form_of_forward(r1):
    cr, m, gm = r1
    q = random_q(cr, 40)
    ctx = context(40)
    rng = np.random.default_rng(5)
    for e in all_effects(gm):
        if e.target != "joints":
            continue
        x, y = rng.normal(size=e.size), rng.normal(size=e.size)
        Y = e.regressor(m, q, ctx)
        assert Y.shape == (40, 6, e.size)
        np.testing.assert_allclose(Y @ x, e.with_values(x).delta_q(m, q, ctx), atol=1e-15)
        np.testing.assert_allclose(e.with_values(2 * x - y).delta_q(m, q, ctx),
                                   2 * e.with_values(x).delta_q(m, q, ctx) - e.with_values(y).delta_q(m, q, ctx),
                                   atol=1e-12)


@pytest.mark.parametrize("index", range(7))
def test_pose_signature_is_jacobian_times_delta_q(r1, index):
    cr, m, gm = r1
    e = all_effects(gm)[index]
    q = random_q(cr, 60, seed=7)
    ctx = context(60)
    R0, p0 = m.fk(q)
    R, p = apply_effects(m, [e], q, ctx)
    dpose = np.concatenate([p - p0, so3.log(R @ np.swapaxes(R0, 1, 2))], axis=1)
    first = e.pose_jacobian(m, q, ctx) @ e.values
    if e.target == "joints":
        np.testing.assert_allclose(first, np.einsum("nij,nj->ni", m.jacobian_q(q), e.delta_q(m, q, ctx)),
                                   atol=1e-12)
    scale = np.abs(dpose).max()
    assert scale > 1e-4  # the effect does move the tool
    np.testing.assert_allclose(dpose, first, atol=2e-3 * scale + 1e-9)


# --- twin and model files ----------------------------------------------------------------------------------

def test_twin_round_trip_and_reproducible(r1):
    cr, m, gm = r1
    mags = {"joint_compliance": 0.3, "backlash": 0.1, "thermal_drift": 0.1, "gear_transmission": 0.05}
    tw = Twin.random(m, mags, seed=11, gravity=gm, offset_std_mm=0.2, tilt_std_rad=3e-4)
    again = Twin.random(m, mags, seed=11, gravity=gm, offset_std_mm=0.2, tilt_std_rad=3e-4)
    assert json.dumps(tw.to_dict()) == json.dumps(again.to_dict())
    back = Twin.from_dict(json.loads(json.dumps(tw.to_dict())))
    q = random_q(cr, 30)
    ctx = context(30)
    for a, b in zip(tw.pose(q, ctx), back.pose(q, ctx)):
        np.testing.assert_array_equal(a, b)
    assert set(tw.info["geometric"]) and tw.effect("backlash").parameters().keys() == {"b1_rad", "b2_rad", "b3_rad"}


def test_twin_plants_requested_magnitude(r1):
    cr, m, gm = r1
    q_ref = random_q(cr, 200, seed=9)
    tw = Twin.random(m, {"joint_compliance": 0.3}, seed=2, gravity=gm, q_ref=q_ref)
    _, p0 = tw.geometry.fk(q_ref)
    _, p = tw.pose(q_ref)
    np.testing.assert_allclose(np.sqrt(np.mean(np.sum((p - p0) ** 2, axis=1))), 0.3, rtol=1e-6)


@pytest.mark.parametrize("suffix", [".yaml", ".json"])
def test_physics_model_file_round_trip_bit_identical(r1, tmp_path, suffix):
    cr, m, gm = r1
    pm = PhysicsModel("R1", "diagnose", m, tuple(all_effects(gm)), geometric_parameters=24, info={"note": "x"})
    path = tmp_path / f"model{suffix}"
    save_model(pm, path)
    back = load_model(path)
    assert isinstance(back, PhysicsModel) and back.n_parameters == pm.n_parameters == 24 + 19 + 5 + 8
    q = random_q(cr, 30)
    ctx = context(30)
    for a, b in zip(pm.fk_context(q, ctx), back.fk_context(q, ctx)):
        np.testing.assert_array_equal(a, b)
    for a, b in zip(pm.fk(q), back.fk(q)):
        np.testing.assert_array_equal(a, b)
    assert back.to_dict() == pm.to_dict()


# --- bad input ---------------------------------------------------------------------------------------------

def test_bad_inputs_raise_with_clear_messages(r1, tmp_path):
    cr, m, gm = r1
    with pytest.raises(ModelError, match="expected 3 values"):
        Backlash((1, 2, 3), np.zeros(2))
    with pytest.raises(ModelError, match="joints must be distinct numbers in 1..6"):
        Backlash((0, 2), np.zeros(2))
    with pytest.raises(ModelError, match="links must be distinct names among p01"):
        ThermalDrift(("p99",), np.zeros(1))
    with pytest.raises(ModelError, match="zero length"):
        ThermalDrift(("p45",), np.ones(1)).geometry(m, 1)
    with pytest.raises(ModelError, match="only -1, 0 or 1"):
        Backlash().delta_q(m, np.zeros((1, 6)), {"dir1": np.array([2.0])})
    with pytest.raises(ModelError, match=r"qd'\] must have shape \(2, 6\)"):
        MocapLatency().delta_q(m, np.zeros((2, 6)), {"qd": np.zeros((3, 6))})
    with pytest.raises(ModelError, match=r"q must have shape \(N, 6\)"):
        Backlash().delta_q(m, np.zeros((2, 5)))
    with pytest.raises(ModelError, match="unknown effect kind 'creep'; valid: backlash"):
        effect_from_dict({"kind": "creep", "parameters": {}})
    with pytest.raises(ModelError, match="do not match"):
        effect_from_dict({"kind": "backlash", "joints": [1], "parameters": {"b2_rad": 1.0}})
    with pytest.raises(ModelError, match="each effect kind may appear once"):
        Twin(m, (Backlash(), Backlash()))
    with pytest.raises(ModelError, match="unsupported twin schema"):
        Twin.from_dict({"schema": "other"})
    with pytest.raises(ModelError, match="needs a GravityModel"):
        Twin.random(m, {"joint_compliance": 0.3}, seed=0)
    bad = PhysicsModel("R1", "diagnose", m).to_dict()
    bad["effects"] = [{"kind": "creep", "parameters": {}}]
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(bad))
    with pytest.raises(DataError, match="unknown effect kind"):
        load_model(path)


# --- the context entries each effect reads -------------------------------------------------------------------

#: The context entries a twin can be given, grouped as ``Effect.context_keys`` names them (``dir`` is dir1..dir6).
CONTEXT_GROUPS = {"dir": [f"dir{i + 1}" for i in range(6)], "qd": ["qd"], "t": ["t"], "temp_c": ["temp_c"],
                  "payload_kg": ["payload_kg"]}


def test_the_context_groups_are_every_entry_an_effect_can_read():
    from calibration.physics.base import CONTEXT_KEYS

    assert set(CONTEXT_GROUPS) == CONTEXT_KEYS


#: How many effects :func:`every_kind` gives (checked by the registry test).
N_KINDS = 11


def every_kind(gravity):
    """One effect of every registered kind and form, thermal drift in both its modes."""
    from calibration.physics import MassFreeCompliance

    return all_effects(gravity) + [
        MassFreeCompliance(values=np.array([2e-4, -1e-4, 3e-4, 1e-4, -2e-4])),
        ThermalDrift(("p34",), np.array([0.01]), mode="temperature", ref_temp_c=20.0)]


def test_every_registered_kind_says_which_context_entries_it_reads(r1):
    from calibration.physics import EFFECT_KINDS
    from calibration.physics.base import CONTEXT_KEYS, registry_key

    effects = every_kind(r1[2])
    assert len(effects) == N_KINDS  # the parameterised test below sees every one
    assert {registry_key(e.kind, e.form) for e in effects} == set(EFFECT_KINDS)
    for e in effects:
        assert e.context_keys is not None and e.context_keys <= CONTEXT_KEYS, e.kind


@pytest.mark.parametrize("index", range(N_KINDS))
def test_an_effect_reads_no_context_entry_but_those_it_declares(r1, index):
    # The simulated arm reuses a true pose while it dwells only when its twin reads nothing but the directions
    # (drivers.sim.SimRobotDriver.true_pose): a declaration that leaves out an entry the effect reads would freeze
    # a drift. Every entry left out must leave the pose bit for bit; changing the declared ones must move it.
    cr, m, gm = r1
    e = every_kind(gm)[index]
    q = random_q(cr, 30, seed=11)
    ctx = {**context(30), "temp_c": np.random.default_rng(4).uniform(15, 40, 30)}
    R0, p0 = Twin(m, (e,)).pose(q, ctx)
    rng = np.random.default_rng(9)
    moved = set()
    for group, entries in CONTEXT_GROUPS.items():
        other = dict(ctx)
        for k in entries:  # directions flip (they must stay in {-1, 0, 1}), the rest move by their size or more
            other[k] = -ctx[k] if group == "dir" else ctx[k] + rng.choice([-1.0, 1.0], np.shape(ctx[k])) * np.maximum(
                np.abs(ctx[k]), 1.0)
        R, p = Twin(m, (e,)).pose(q, other)
        if not (np.array_equal(R, R0) and np.array_equal(p, p0)):
            moved.add(group)
    assert moved <= e.context_keys, f"{e.kind} reads {sorted(moved - e.context_keys)} without declaring them"
    assert moved or not e.context_keys, f"{e.kind} declares {sorted(e.context_keys)} but reads none of them"
