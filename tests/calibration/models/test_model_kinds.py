"""Every model kind, one set of properties: Jacobians against finite differences, casadi against numpy.

Parameterised over all kinds (constant, pi, cdc on every interpolator with a casadi form, physics, diagnosed on
pi and on cdc), like mink's Lie-group
axiom tests over every group: a kind that declares its blocks wrongly, or whose casadi expression drifts from
its numpy pose, fails here.
"""

from __future__ import annotations

import numpy as np
import pytest

from calibration.interpolation import Interpolator, LinearInterpolator, make_interpolator
from calibration.interpolation.fourier import Fourier13Interpolator
from calibration.kinematics import so3
from calibration.kinematics.parameterisation import MinimalParameterisation
from calibration.models import ConstantModel
from calibration.models.cdc import CdcModel
from calibration.models.diagnosed import DiagnosedModel
from calibration.models.guard import REGION_KEY, Region
from calibration.models.physics import PhysicsModel
from calibration.models.pi import PhysicsInformedModel
from calibration.physics import (
    Backlash,
    GearTransmission,
    GravityModel,
    JointCompliance,
    JointOffset,
    MocapLatency,
    PayloadCompliance,
    ThermalDrift,
)
from calibration.physics.extended import ExtendedKinematics, MassFreeCompliance
from cell_config.loader import load_cell

ca = pytest.importorskip("casadi")
#: cdc on every other interpolator kind (``cdc`` itself is fbf13): each has an exact casadi form.
CDC_INTERPOLATORS = {"nearest": {}, "linear": {}, "cubic": {}, "rbf": {}, "fbf7": {},
                     "nn": {"hidden": (32, 32), "max_iter": 60}, "ae": {"latent": 4, "hidden": (32,), "max_iter": 60}}
KINDS = ("constant", "pi", "cdc", *(f"cdc-{k}" for k in CDC_INTERPOLATORS), "cdc-rbf-bounded", "physics",
         "diagnosed-pi", "diagnosed-cdc", "diagnosed-cdc-nn", "physics-guarded", "diagnosed-pi-guarded",
         "physics-guarded-every-joint")
#: A training region narrower than the test configurations (+-1.5 rad), q1 and the wrist seen narrowly, so the
#: extrapolation guard holds the gear errors on joints 1 and 4 (the compliance goes on by its formula).
_LOWER, _UPPER = np.array([-0.1, -0.6, -0.6, -0.1, -0.1, -0.1]), np.array([0.1, 0.4, 0.4, 0.1, 0.1, 0.1])
GUARD = {REGION_KEY: Region(_LOWER, _UPPER, 0.05).to_dict()}
#: The same region saved before the effects declared their fitted joints: every effect held in every joint.
GUARD_EVERY_JOINT = {REGION_KEY: Region(_LOWER, _UPPER, 0.05, "every_joint").to_dict()}


def _effects(gravity: GravityModel) -> tuple:
    """Joint effects of every kind (context-driven ones are zero at the default context) and thermal growth."""
    return (JointCompliance(gravity, (2, 3, 5), np.array([3e-6, 5e-6, 1e-5])),
            GearTransmission(((1, (1, 2)), (4, (1,))), np.array([2e-4, -1e-4, 5e-5, 3e-5, -2e-4, 1e-4])),
            JointOffset((2, 6), np.array([1e-3, -2e-3])), Backlash((1, 2), np.array([1e-3, 2e-3])),
            MocapLatency(values=np.array([0.01])), PayloadCompliance((2,), np.array([1e-6])),
            ThermalDrift(("p23", "p34"), np.array([0.3, -0.2]), mode="temperature", ref_temp_c=20.0))


@pytest.fixture(scope="module")
def models() -> dict:
    cell = load_cell()
    spec = cell.robot("R1")
    nominal = spec.model()
    par = MinimalParameterisation(nominal, fit_tool=True)
    kin = ExtendedKinematics(par)
    rng = np.random.default_rng(3)
    theta = rng.normal(size=kin.size) * kin.scale() * 0.5
    geometry = par.model(rng.normal(size=par.size) * par.scale() * 0.5)
    gravity = GravityModel.from_spec(spec.robot, geometry)
    pi = PhysicsInformedModel("R1", "pi", kin, theta, kin.size)
    x = rng.uniform(-1.5, 1.5, (40, 2))
    y = rng.normal(size=(40, par.size)) * par.scale() * 0.3
    cdc = CdcModel("R1", "fbf13", kin, theta, Fourier13Interpolator().fit(x, y))
    physics = PhysicsModel("R1", "diagnose", geometry, _effects(gravity), par.size)
    effects = _effects(gravity)[:3] + (_effects(gravity)[-1],)
    cdcs = {f"cdc-{k}": CdcModel("R1", k, kin, theta, make_interpolator(k, **o).fit(x, y))
            for k, o in CDC_INTERPOLATORS.items()}
    # bounds inside the values' range, so the clipping (np.clip / ca.fmin, ca.fmax) is active for many parameters
    bounds = np.stack([np.quantile(y, 0.3, axis=0), np.quantile(y, 0.7, axis=0)])
    cdcs["cdc-rbf-bounded"] = CdcModel("R1", "rbf", kin, theta, make_interpolator("rbf").fit(x, y), bounds=bounds)
    return {"constant": ConstantModel("R1", "nls1", geometry, par.size), "pi": pi, "cdc": cdc, **cdcs,
            "physics": physics, "diagnosed-pi": DiagnosedModel("R1", "diagnose", pi, effects),
            "diagnosed-cdc": DiagnosedModel("R1", "diagnose", cdc, effects),
            "diagnosed-cdc-nn": DiagnosedModel("R1", "diagnose", cdcs["cdc-nn"], effects),
            "physics-guarded": PhysicsModel("R1", "diagnose", geometry, _effects(gravity), par.size, dict(GUARD)),
            "diagnosed-pi-guarded": DiagnosedModel("R1", "diagnose", pi, effects, dict(GUARD)),
            "physics-guarded-every-joint": PhysicsModel("R1", "diagnose", geometry, _effects(gravity), par.size,
                                                        dict(GUARD_EVERY_JOINT))}


def _q(n: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-1.5, 1.5, (n, 6))


def _pose_difference(Ra, pa, Rb, pb, h):
    """Central difference of two poses: ``[dp; vee(log(Ra Rb^T))] / 2h`` (base-frame rotation)."""
    return np.concatenate([(pa - pb) / (2 * h), so3.log(Ra @ np.swapaxes(Rb, 1, 2)) / (2 * h)], axis=1)


@pytest.mark.parametrize("kind", KINDS)
def test_parameter_jacobian_matches_finite_differences(models, kind):
    model = models[kind]
    q = _q(6, seed=1)
    theta = model.vector()
    assert theta.size == sum(b.size for b in model.blocks()) > 0
    R, p, J = model.jacobian(q)
    R_np, p_np = model.fk(q)
    np.testing.assert_allclose(p, p_np, atol=1e-9)
    assert J.shape == (q.shape[0], 6, theta.size)
    for k in range(theta.size):
        h = 1e-6 * max(1.0, abs(theta[k]))
        dt = np.zeros_like(theta)
        dt[k] = h
        Ra, pa = model.with_vector(theta + dt).fk(q)
        Rb, pb = model.with_vector(theta - dt).fk(q)
        fd = _pose_difference(Ra, pa, Rb, pb, h)
        scale = max(1.0, float(np.abs(fd).max()))
        np.testing.assert_allclose(J[:, :, k], fd, atol=2e-6 * scale, rtol=0,
                                   err_msg=f"{kind}: column {k} ({[n for b in model.blocks() for n in b.names][k]})")


@pytest.mark.parametrize("kind", KINDS)
def test_joint_jacobian_matches_finite_differences(models, kind):
    model = models[kind]
    q = _q(5, seed=2)
    Jq = model.jacobian_q(q)
    h = 1e-6
    for j in range(6):
        dq = np.zeros(6)
        dq[j] = h
        fd = _pose_difference(*model.fk(q + dq), *model.fk(q - dq), h)
        np.testing.assert_allclose(Jq[:, :, j], fd, atol=1e-5, rtol=0, err_msg=f"{kind}: joint {j + 1}")


@pytest.mark.parametrize("kind", KINDS)
def test_casadi_expression_matches_numpy_pose(models, kind):
    from app.dual.casadi_kinematics import casadi_fk

    model = models[kind]
    fk = casadi_fk(model)
    assert (fk.kind, fk.n_frozen) == (kind.split("-")[0] if kind != "cdc" else "cdc", 0)
    q = _q(20, seed=4)
    R_np, p_np = model.fk(q)
    for i, qi in enumerate(q):
        Rc, pc, _, _ = fk.function(qi, np.zeros(0))
        np.testing.assert_allclose(np.asarray(pc).ravel(), p_np[i], atol=1e-9, rtol=0)
        np.testing.assert_allclose(np.asarray(Rc), R_np[i], atol=1e-12, rtol=0)


def test_bounded_cdc_clips_in_both_forms(models):
    """The bounded model's clipping is active at the test configurations (else the kind above proves nothing)."""
    model = models["cdc-rbf-bounded"]
    q = _q(20, seed=4)
    raw = model.interpolator.predict(q[:, list(model.inputs)])
    assert np.mean((raw < model.bounds[0]) | (raw > model.bounds[1])) > 0.3


class _NoCasadiForm(LinearInterpolator):
    """An interpolator kind that keeps the base class's casadi_predict (declines)."""

    casadi_predict = Interpolator.casadi_predict


def test_cdc_on_a_kind_without_casadi_form_keeps_frozen_parameters_and_matches_numpy_at_them(models):
    """A kind that declines ``casadi_predict``: the planner gets ``cdc-frozen`` with the geometric block as input."""
    from app.dual.casadi_kinematics import casadi_fk

    base = models["cdc-linear"]
    model = CdcModel("R1", "linear", base.kinematics, base.theta_ref,
                     _NoCasadiForm().fit(base.interpolator._anchors, base.interpolator._values))
    fk = casadi_fk(model)
    assert (fk.kind, fk.n_frozen) == ("cdc-frozen", model.kinematics.par.size) and fk.frozen
    q = _q(5, seed=4)
    R_np, p_np = model.fk(q)
    for i, qi in enumerate(q):
        _, pc, _, _ = fk.function(qi, fk.params_at(qi))
        np.testing.assert_allclose(np.asarray(pc).ravel(), p_np[i], atol=1e-9, rtol=0)


def test_pi_analytic_jacobian_has_77_columns(models):
    """pi's analytic Jacobian (the fitter's) covers every block: 27 + 3 + 5 + 42 columns."""
    assert [b.size for b in models["pi"].blocks()] == [27, 3, 5, 42]
    assert models["pi"].jacobian(_q(2, 0))[2].shape == (2, 6, 77)


@pytest.mark.parametrize("kind", KINDS)
def test_model_file_round_trip_is_bit_identical(models, kind, tmp_path):
    from calibration.models import load_model, save_model

    model = models[kind]
    q = _q(10, seed=6)
    for suffix in (".yaml", ".json"):
        save_model(model, tmp_path / f"m{suffix}")
        loaded = load_model(tmp_path / f"m{suffix}")
        assert loaded.kind == model.kind and [b.names for b in loaded.blocks()] == [b.names for b in model.blocks()]
        for a, b in zip(loaded.fk(q), model.fk(q)):
            np.testing.assert_array_equal(a, b)


def test_mass_free_compliance_is_a_registered_joint_effect(models):
    """One definition: the pi model's compliance block is this effect, which loads like every effect."""
    from calibration.physics import EFFECT_KINDS, effect_from_dict
    from calibration.physics.extended import compliance_regressor
    from calibration.physics.layout import block_slice

    e = MassFreeCompliance(values=np.array([1e-3, -5e-4, 2e-4, 3e-4, -1e-4]))
    assert EFFECT_KINDS["joint_compliance:mass_free"] is MassFreeCompliance
    back = effect_from_dict(e.to_dict())
    assert type(back) is MassFreeCompliance and np.array_equal(back.values, e.values)
    geometry = models["constant"].model
    q = _q(20, seed=7)
    np.testing.assert_array_equal(e.regressor(geometry, q), compliance_regressor(q))
    assert e.block(27) == block_slice("compliance", 27) == slice(30, 35)
    physics = PhysicsModel("R1", "diagnose", geometry, (e,))
    np.testing.assert_allclose(physics.fk(q)[1], geometry.fk(q + e.delta_q(geometry, q))[1], atol=1e-12)


@pytest.mark.parametrize("kind", KINDS)
def test_every_kind_answers_for_its_interpolator_bare_and_rebased(models, kind):
    """An analysis asks any model for its interpolator, never its type (issue 31: compare reached for
    CdcModel.interpolator and a frames-first fit's rebased fbf13 has none): configuration-dependent kinds answer
    with theirs, a wrapper with its inner model's, the rest None."""
    from calibration.models.rebased import RebasedModel

    model = models[kind]
    own = model.interpolation()
    assert (own is not None) == kind.startswith(("cdc", "diagnosed-cdc"))
    if isinstance(model, CdcModel):
        assert own is model.interpolator
    assert RebasedModel(model.robot, model.method, model).interpolation() is own
