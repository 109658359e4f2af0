import numpy as np
import pytest

from calibration.data.recording import Recording
from calibration.errors import ModelError
from calibration.identification.cpa import fit_circle, identify_cpa, split_sweeps
from calibration.kinematics.parameterisation import MinimalParameterisation
from calibration.kinematics.poe import pose_error
from tests.conftest import measure, planted_parameters


def sweeps_design(n_points: int = 12) -> tuple[np.ndarray, np.ndarray]:
    q, cluster = [], []
    for j in range(6):
        for a in np.linspace(-40, 40, n_points):
            qi = np.zeros(6)
            qi[j] = np.radians(a)
            q.append(qi)
            cluster.append(j)
    return np.array(q), np.array(cluster)


def test_fit_circle_exact():
    t = np.linspace(0, 2, 9)
    pts = np.stack([3 + 5 * np.cos(t), -1 + 5 * np.sin(t), np.full_like(t, 2.0)], axis=1)
    c = fit_circle(pts)
    np.testing.assert_allclose(c.centre, [3, -1, 2], atol=1e-9)
    assert c.radius == pytest.approx(5.0)
    np.testing.assert_allclose(np.abs(c.normal), [0, 0, 1], atol=1e-9)


def test_cpa_recovers_axes_of_planted_arm(r1_nominal):
    par = MinimalParameterisation(r1_nominal, fit_tool=False)
    x_true = planted_parameters(par, seed=11, offset_mm=1.0, tilt_rad=2e-3)
    truth = par.model(x_true)
    q, cluster = sweeps_design()
    rec = measure(truth.fk, q, noise_mm=0.01, noise_deg=0.01, seed=1, cluster=cluster)
    x, circles = identify_cpa(par, split_sweeps(rec))
    assert len(circles) == 6
    # Axis tilts: joints 4 and 6 carry the marker only ~34 mm off their axis, so their circles are small and
    # their tilts noisier; the large-radius joints are checked tightly.
    tilt_error = (x - x_true)[12:].reshape(6, 2)
    np.testing.assert_allclose(tilt_error[[0, 1, 2, 4]], 0.0, atol=2e-4)
    np.testing.assert_allclose(tilt_error[[3, 5]], 0.0, atol=3e-3)
    q_test = np.random.default_rng(0).uniform(-0.7, 0.7, (300, 6))
    err = pose_error(*truth.fk(q_test), *par.model(x).fk(q_test))[0]
    nominal = pose_error(*truth.fk(q_test), *r1_nominal.fk(q_test))[0]
    assert err.mean() < 0.2 * nominal.mean()


def test_cpa_rejects_data_that_is_not_sweeps(r1_nominal):
    q = np.random.default_rng(0).uniform(-0.5, 0.5, (14, 6))
    R, p = r1_nominal.fk(q)
    from calibration.kinematics import so3

    rec = Recording(q, p, so3.R_to_quat(R), {"cluster": np.repeat([0.0, 1.0], 7)}, "x.csv")
    with pytest.raises(ModelError, match="not a single-joint sweep"):
        split_sweeps(rec)
    with pytest.raises(ModelError, match="cluster column"):
        split_sweeps(Recording(q, p, so3.R_to_quat(R), {}, "x.csv"))


def test_cpa_method_is_exact_on_noiseless_sweeps(r1_nominal):
    """Through the Fitter (with the flange shift fitted on the sweeps), CPA recovers the arm exactly."""
    from calibration.methods.fitter import Fitter
    from tests.conftest import cluster_design

    par = MinimalParameterisation(r1_nominal, fit_tool=True)
    truth = par.model(planted_parameters(par, seed=501))
    q, cluster = sweeps_design()
    sweeps = measure(truth.fk, q, 0.0, 0.0, 1, cluster)
    q_train, c_train = cluster_design(step_deg=45.0)
    model, _ = Fitter("R1", r1_nominal, measure(truth.fk, q_train, 0.0, 0.0, 1, c_train), cpa_data=sweeps).fit("cpa")
    q_test = np.random.default_rng(0).uniform(-0.7, 0.7, (200, 6))
    assert pose_error(*truth.fk(q_test), *model.fk(q_test))[0].max() < 1e-8
