import numpy as np
import pytest

from calibration.errors import ModelError
from calibration.kinematics import so3
from calibration.kinematics.parameterisation import MinimalParameterisation
from tests.conftest import planted_parameters


@pytest.mark.parametrize("fit_tool", [False, True])
def test_parameter_jacobian_against_finite_differences(r1_nominal, fit_tool):
    par = MinimalParameterisation(r1_nominal, fit_tool)
    x = planted_parameters(par, seed=4, offset_mm=2.0, tilt_rad=1e-2)
    q = np.random.default_rng(5).uniform(-1.5, 1.5, (8, 6))
    _, _, J = par.jacobian(q, x)
    eps = 1e-6
    for i in range(par.size):
        dx = np.zeros(par.size)
        dx[i] = eps
        Rp, pp = par.nominal.fk(q, *par.geometry(x + dx))
        Rm, pm = par.nominal.fk(q, *par.geometry(x - dx))
        np.testing.assert_allclose(J[:, :3, i], (pp - pm) / (2 * eps), atol=2e-6 * max(1, np.abs(J[:, :3, i]).max()))
        np.testing.assert_allclose(J[:, 3:, i], so3.log(Rp @ np.swapaxes(Rm, 1, 2)) / (2 * eps), atol=1e-7)


@pytest.mark.parametrize("fit_tool", [False, True])
def test_geometry_round_trip(r1_nominal, fit_tool):
    par = MinimalParameterisation(r1_nominal, fit_tool)
    x = planted_parameters(par, seed=6)
    H, P = par.geometry(x)
    np.testing.assert_allclose(par.from_geometry(H, P), x, atol=1e-10)
    assert par.size == 24 + 3 * fit_tool
    assert len(par.names()) == par.size


def test_zero_is_nominal_and_origins_stay_in_normal_planes(r1_nominal):
    par = MinimalParameterisation(r1_nominal)
    H, P = par.geometry(np.zeros(par.size))
    np.testing.assert_allclose(H, r1_nominal.H)
    np.testing.assert_allclose(P, r1_nominal.P)
    x = planted_parameters(par, seed=7)
    H, P = par.geometry(x)
    moved = np.cumsum(P, axis=1)[:, :6] - np.cumsum(r1_nominal.P, axis=1)[:, :6]
    np.testing.assert_allclose(np.einsum("ij,ij->j", moved, r1_nominal.H), 0.0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(H, axis=0), 1.0, atol=1e-12)


def test_per_sample_geometry_matches_single(r1_nominal):
    par = MinimalParameterisation(r1_nominal, True)
    xs = np.stack([planted_parameters(par, seed=s) for s in range(3)])
    q = np.random.default_rng(0).uniform(-1, 1, (3, 6))
    R, p = par.nominal.fk(q, *par.geometry(xs))
    for i in range(3):
        Ri, pi = par.model(xs[i]).fk(q[i:i + 1])
        np.testing.assert_allclose(p[i], pi[0], atol=1e-9)
        np.testing.assert_allclose(R[i], Ri[0], atol=1e-12)


def test_flange_shift_without_fit_tool_is_refused(r1_nominal):
    par = MinimalParameterisation(r1_nominal)
    P = r1_nominal.P.copy()
    P[:, -1] += [1.0, 0, 0]
    with pytest.raises(ModelError, match="fit_tool"):
        par.from_geometry(r1_nominal.H, P)
    with pytest.raises(ModelError, match="24 entries"):
        par.geometry(np.zeros(5))
