"""casadi forward kinematics against the numpy models."""

from __future__ import annotations

import numpy as np
import pytest

from app.dual.casadi_kinematics import casadi_fk
from calibration.errors import ModelError
from calibration.kinematics.parameterisation import MinimalParameterisation
from calibration.methods.cdc import geometric_cdc
from calibration.models import ConstantModel
from calibration.models.cdc import CdcModel
from cell_config.loader import load_cell

ca = pytest.importorskip("casadi")


class FourierStub:
    """Test-only stand-in for the fbf13 interpolator: 13 Fourier terms in (q2, q3), numpy ufuncs only."""

    kind = "fbf13-stub"

    def __init__(self, m: int, seed: int = 1, scale: float = 1e-3) -> None:
        self.C = np.random.default_rng(seed).normal(0, scale, (13, m))

    def basis(self, x: np.ndarray) -> np.ndarray:
        a, b = x[:, 0], x[:, 1]
        cols = [np.ones(x.shape[0], dtype=x.dtype) * 1.0]
        for k in (1, 2, 3):
            cols += [np.sin(k * a), np.cos(k * a), np.sin(k * b), np.cos(k * b)]
        return np.stack(cols, axis=1)

    @property
    def coefficients(self) -> np.ndarray:
        return self.C

    def predict(self, x: np.ndarray) -> np.ndarray:
        return self.basis(np.asarray(x, dtype=float)) @ self.C

    def casadi_predict(self, u):
        """The declared casadi form (``Interpolator.casadi_predict``): the same basis on casadi symbols."""
        a, b = u[0], u[1]
        cols = [1.0]
        for k in (1, 2, 3):
            cols += [ca.sin(k * a), ca.cos(k * a), ca.sin(k * b), ca.cos(k * b)]
        return ca.mtimes(ca.DM(self.C.T), ca.vertcat(*cols))

    def out_of_range(self, x: np.ndarray) -> np.ndarray:
        return np.zeros(len(x), dtype=bool)


class OpaqueStub(FourierStub):
    """An interpolator casadi cannot see through (no basis, a casadi_predict that declines like the base class's):
    forces the frozen-parameter fallback."""

    kind = "opaque-stub"
    basis_ = FourierStub.basis

    def __getattribute__(self, name):  # hide basis from hasattr
        if name == "basis":
            raise AttributeError(name)
        return object.__getattribute__(self, name)

    def predict(self, x: np.ndarray) -> np.ndarray:
        return FourierStub.basis(self, np.asarray(x, dtype=float)) @ self.C

    def casadi_predict(self, u):
        raise ModelError(f"{self.kind}: no exact casadi form of this interpolator kind")


def _eval(cfk, q):
    R, p, _, _ = cfk.function(q, cfk.x0(q))
    return np.asarray(R), np.asarray(p).ravel()


def _check(model, cfk, seed=0, n=20):
    rng = np.random.default_rng(seed)
    qs = rng.uniform(-2.0, 2.0, (n, 6))
    R_np, p_np = model.fk(qs)
    for i, q in enumerate(qs):
        R, p = _eval(cfk, q)
        np.testing.assert_allclose(p, p_np[i], atol=1e-9, rtol=0)
        np.testing.assert_allclose(R, R_np[i], atol=1e-12, rtol=0)


@pytest.fixture(scope="module")
def cell():
    return load_cell()


def test_constant_matches_numpy(cell):
    model = ConstantModel("R1", "nominal", cell.robot("R1").model())
    cfk = casadi_fk(model)
    assert cfk.kind == "constant" and not cfk.frozen
    _check(model, cfk)


def test_cdc_fourier_matches_numpy_and_is_exact(cell):
    par = MinimalParameterisation(cell.robot("R2").model())
    model = CdcModel("R2", "fbf13", *geometric_cdc(par), FourierStub(par.size, scale=0.5))  # large deviations: strict test
    cfk = casadi_fk(model)
    assert cfk.kind == "cdc" and not cfk.frozen
    _check(model, cfk, seed=3)


def test_cdc_jacobian_includes_parameter_dependence(cell):
    par = MinimalParameterisation(cell.robot("R1").model())
    model = CdcModel("R1", "fbf13", *geometric_cdc(par), FourierStub(par.size, scale=1e-2))
    cfk = casadi_fk(model)
    q = ca.SX.sym("q", 6)
    _, p, _, _ = cfk.function(q, ca.SX(0, 1))
    J = ca.Function("J", [q], [ca.jacobian(p, q)])
    q0 = np.array([0.1, 0.3, -0.2, 0.4, -0.5, 0.6])
    eps = 1e-6
    fd = np.column_stack([(model.fk(q0 + eps * e)[1][0] - model.fk(q0 - eps * e)[1][0]) / (2 * eps)
                          for e in np.eye(6)])
    np.testing.assert_allclose(np.asarray(J(q0)), fd, atol=1e-5)


def test_cdc_opaque_interpolator_freezes_parameters(cell):
    par = MinimalParameterisation(cell.robot("R1").model())
    model = CdcModel("R1", "opaque", *geometric_cdc(par), OpaqueStub(par.size))
    cfk = casadi_fk(model)
    assert cfk.frozen and cfk.n_frozen == par.size and cfk.kind == "cdc-frozen"
    _check(model, cfk, seed=5)  # exact when frozen at the same q


def test_dq_hook_shifts_joints(cell):
    model = ConstantModel("R1", "nominal", cell.robot("R1").model())
    q = ca.SX.sym("q", 6)
    dq = ca.Function("dq", [q], [1e-3 * ca.sin(q)])
    cfk = casadi_fk(model, dq=dq)
    assert cfk.kind == "constant+dq"
    q0 = np.array([0.2, -0.3, 0.4, 0.5, -0.6, 0.7])
    R, p = _eval(cfk, q0)
    R_np, p_np = model.fk(q0 + 1e-3 * np.sin(q0))
    np.testing.assert_allclose(p, p_np[0], atol=1e-9)


def test_unknown_model_kind_names_supported_kinds():
    with pytest.raises(ModelError, match="supported: constant, cdc"):
        casadi_fk(object())


def test_fitted_fbf13_model_takes_the_exact_path(cell):
    """A real fbf13 model from Fitter is expressed in casadi (no frozen-parameter fallback) and matches numpy."""
    from calibration.methods.fitter import Fitter
    from tests.conftest import cluster_design, measure, planted_parameters

    nominal = cell.robot("R1").model()
    par = MinimalParameterisation(nominal, fit_tool=True)
    truth = par.model(planted_parameters(par))
    q, cluster = cluster_design(step_deg=15.0)
    model, _ = Fitter("R1", nominal, measure(truth.fk, q, 0.02, 0.01, 1, cluster)).fit("fbf13")
    fk = casadi_fk(model)
    assert (fk.kind, fk.n_frozen, fk.params_at) == ("cdc", 0, None)
    qs = np.random.default_rng(5).uniform(-1.0, 1.0, (5, 6))
    R, p = model.fk(qs)
    for i, qi in enumerate(qs):
        Rc, pc, _, _ = fk.function(qi, np.zeros(0))
        np.testing.assert_allclose(np.asarray(pc).ravel(), p[i], atol=1e-9)
        np.testing.assert_allclose(np.asarray(Rc), R[i], atol=1e-12)


def test_physics_informed_and_cdc_over_it_match_numpy(cell):
    """Compliance, tool rotation and deflection terms are written out exactly in casadi."""
    from calibration.models.pi import PhysicsInformedModel
    from calibration.physics.extended import ExtendedKinematics

    par = MinimalParameterisation(cell.robot("R1").model(), fit_tool=True)
    kin = ExtendedKinematics(par)
    theta = np.random.default_rng(7).normal(size=kin.size) * kin.scale() * 0.5
    pi = PhysicsInformedModel("R1", "pi", kin, theta, kin.size)
    fk = casadi_fk(pi)
    assert (fk.kind, fk.n_frozen) == ("pi", 0)
    _check(pi, fk, seed=8)
    cdc = CdcModel("R1", "fbf13", kin, theta, FourierStub(par.size, scale=1e-2))
    fk = casadi_fk(cdc)
    assert (fk.kind, fk.n_frozen) == ("cdc", 0)
    _check(cdc, fk, seed=9)


def test_compile_skips_functions_too_big_for_a_quick_build(tmp_path, monkeypatch):
    """A function over MAX_COMPILE_INSTRUCTIONS comes back interpreted, without running the compiler at all."""
    from app.dual import casadi_kinematics as ck

    q = ca.SX.sym("q", 6)
    F = ca.Function("big", [q], [ca.sum1(ca.sin(q) * ca.cos(q))])
    monkeypatch.setattr(ck, "MAX_COMPILE_INSTRUCTIONS", F.n_instructions() - 1)
    monkeypatch.setattr(ck.subprocess, "run", lambda *a, **k: pytest.fail("the compiler ran"))
    monkeypatch.setattr(ck.subprocess, "Popen", lambda *a, **k: pytest.fail("the compiler ran"))
    assert ck.compile_function(ca, F, cache_dir=tmp_path) is F
    assert list(tmp_path.iterdir()) == []


def _small_function(scale: float):
    q = ca.SX.sym("q", 6)
    return ca.Function("small", [q], [scale * ca.sum1(ca.sin(q))])


def test_compile_cache_is_keyed_by_the_expression_content(tmp_path):
    """A changed model parameter (here a constant in the expression) builds a new library; the same one reuses it."""
    from app.dual import casadi_kinematics as ck

    q = np.linspace(0.1, 0.6, 6)
    a = ck.compile_function(ca, _small_function(2.0), cache_dir=tmp_path)
    libs = sorted(tmp_path.glob("*.so"))
    assert len(libs) == 1 and float(a(q)) == pytest.approx(2.0 * np.sin(q).sum(), abs=1e-12)
    ck.compile_function(ca, _small_function(2.0), cache_dir=tmp_path)
    assert sorted(tmp_path.glob("*.so")) == libs
    b = ck.compile_function(ca, _small_function(3.0), cache_dir=tmp_path)
    assert len(list(tmp_path.glob("*.so"))) == 2 and float(b(q)) == pytest.approx(3.0 * np.sin(q).sum(), abs=1e-12)


@pytest.mark.parametrize("damage", ["truncate", "garbage", "no stamp"])
def test_a_corrupt_cached_library_is_rebuilt_not_loaded(tmp_path, damage):
    from app.dual import casadi_kinematics as ck

    ck.compile_function(ca, _small_function(2.0), cache_dir=tmp_path)
    (lib,) = tmp_path.glob("*.so")
    good = lib.read_bytes()
    if damage == "truncate":  # loading this one would kill the process with a bus error
        lib.write_bytes(good[: len(good) // 2])
    elif damage == "garbage":
        lib.write_bytes(b"not a library")
    else:
        lib.with_name(lib.name + ".sha256").unlink()
    F = ck.compile_function(ca, _small_function(2.0), cache_dir=tmp_path)
    q = np.linspace(0.1, 0.6, 6)
    assert F.name() == "small" and float(F(q)) == pytest.approx(2.0 * np.sin(q).sum(), abs=1e-12)
    assert F.class_name() != "SXFunction"  # the compiled library, not the interpreted fallback
    assert ck._cached(lib) and lib.stat().st_size == len(good)
