"""Recovery of planted geometric errors from synthetic measurements with noise."""

import numpy as np
import pytest

from calibration.errors import ModelError
from calibration.identification import GeometricProblem, rotation_residual_scale
from calibration.identification.observability import analyse
from calibration.kinematics.poe import pose_error
from tests.conftest import cluster_design, measure


def test_global_fit_recovers_planted_errors(synthetic_arm):
    par, x_true, truth = synthetic_arm
    q, cluster = cluster_design(step_deg=15.0, spread_wrist=True)
    rec = measure(truth.fk, q, noise_mm=0.02, noise_deg=0.01, seed=3, cluster=cluster)
    obs = analyse(par, q)
    res = GeometricProblem(par, q, rec.R, rec.p, basis=obs.basis).solve()
    assert res.converged.all()
    assert res.rms_mm[0] < 1.1 * 0.02 * np.sqrt(3)  # the noise floor of a 3D position with 0.02 mm per axis
    # Identified geometry predicts the true arm everywhere in the workspace (within noise-level tolerance).
    q_test = np.random.default_rng(9).uniform(-1.0, 1.0, (500, 6))
    dp, dR = pose_error(*truth.fk(q_test), *par.model(res.x[0]).fk(q_test))
    assert dp.max() < 0.05, dp.max()
    assert dR.max() < 0.005
    # Parameters themselves: offsets within 0.05 mm, tilts within 5e-5 rad on observable directions.
    np.testing.assert_allclose(res.x[0][:12], x_true[:12], atol=0.05)
    np.testing.assert_allclose(res.x[0][12:24], x_true[12:24], atol=5e-5)


def test_batched_groups_equal_separate_solves(synthetic_arm):
    par, _, truth = synthetic_arm
    q, cluster = cluster_design(step_deg=45.0)
    rec = measure(truth.fk, q, noise_mm=0.02, noise_deg=0.01, seed=4, cluster=cluster)
    prior = np.full(par.size, 0.1)
    batched = GeometricProblem(par, q, rec.R, rec.p, groups=cluster, prior_weight=prior).solve(tol=1e-14)
    for k in (0, 3, int(cluster.max())):
        sel = cluster == k
        single = GeometricProblem(par, q[sel], rec.R[sel], rec.p[sel], prior_weight=prior).solve(tol=1e-14)
        np.testing.assert_allclose(batched.x[k], single.x[0], atol=1e-6)


def test_orientation_weight_makes_one_degree_weigh_like_one_millimetre():
    assert rotation_residual_scale(1641.0) * np.radians(1.0) == pytest.approx(1.0, abs=2e-4)
    with pytest.raises(ModelError):
        rotation_residual_scale(-1.0)


def test_bad_groups_rejected(synthetic_arm):
    par, _, truth = synthetic_arm
    q = np.zeros((4, 6))
    R, p = truth.fk(q)
    with pytest.raises(ModelError, match="at least one sample"):
        GeometricProblem(par, q, R, p, groups=np.array([0, 0, 2, 2]))
    with pytest.raises(ModelError, match="measurements"):
        GeometricProblem(par, q, R[:2], p, groups=None)


def test_cluster_design_is_anchor_then_one_degree_per_joint():
    from calibration.methods.cdc import expand_anchors

    anchors = np.radians([[1.0, -10.0, 20.0, 1.0, 1.0, 1.0], [1.0, 5.0, -5.0, 1.0, 1.0, 1.0]])
    q, cluster = expand_anchors(anchors)
    assert q.shape == (14, 6) and cluster.tolist() == [0] * 7 + [1] * 7
    np.testing.assert_allclose(q[0], anchors[0])
    np.testing.assert_allclose(np.degrees(q[1:7] - anchors[0]), np.eye(6), atol=1e-12)
