"""The top-up design (:mod:`calibration.methods.topup`): exact rank-6 downdates, nested greedy, and that it spends its poses
where the task goes and the training data did not."""

import numpy as np
import pytest

from app.reports.plots import mask_runs
from calibration.errors import ModelError
from calibration.methods.topup import (
    TopupPrior,
    choose,
    gaussian_share_over,
    held_out_sigma_scales,
    predicted_position_cov,
    predicted_sigma,
)
from tests.calibration.methods.test_standalone_poses import wide_poses
from tests.conftest import cluster_design

SMALL = TopupPrior(n_inducing=40)


@pytest.fixture(scope="module")
def setting():
    q_train, _ = cluster_design(step_deg=30.0, spread_wrist=False)  # still wrist, q1 = 1 deg
    q_cand = wide_poses(40, seed=21)
    q_task = wide_poses(30, seed=22)
    return q_train, q_cand, q_task


def test_the_downdated_variances_equal_a_fresh_posterior(setting, r1_nominal):
    q_train, q_cand, q_task = setting
    res = choose(r1_nominal, q_train, q_cand, q_task, 6, SMALL)
    # the same known configurations, so the same Nystroem centres; the chosen poses now measured
    chosen = list(res.order)
    fresh = choose(r1_nominal, np.concatenate([q_train, q_cand[chosen]]), np.delete(q_cand, chosen, axis=0), q_task,
                   0, SMALL)
    np.testing.assert_allclose(res.sigma_after_mm, fresh.sigma_before_mm, rtol=1e-6, atol=1e-9)


def test_greedy_is_nested_and_each_pose_lowers_the_criterion(setting, r1_nominal):
    q_train, q_cand, q_task = setting
    long = choose(r1_nominal, q_train, q_cand, q_task, 8, SMALL)
    short = choose(r1_nominal, q_train, q_cand, q_task, 3, SMALL)
    assert long.order[:3] == short.order
    assert len(set(long.order)) == 8
    assert np.all(np.diff(long.criterion_mm2) < 0)
    assert np.all(long.sigma_after_mm <= long.sigma_before_mm + 1e-12)


@pytest.mark.parametrize("kind", ["pi", "geometric"])
def test_candidates_near_the_task_are_chosen_over_ones_near_the_training_data(setting, r1_nominal, kind):
    """Half the candidates repeat training configurations (+0.5 deg), half lie next to the task (+0.5 deg): every
    chosen pose is one of the latter, for either parametric part."""
    q_train, _, q_task = setting
    rng = np.random.default_rng(3)
    near_train = q_train[rng.choice(len(q_train), 20, replace=False)] + np.radians(0.5)
    near_task = q_task[rng.choice(len(q_task), 20, replace=False)] + np.radians(0.5)
    res = choose(r1_nominal, q_train, np.concatenate([near_train, near_task]), q_task, 5,
                 TopupPrior(kind=kind, n_inducing=40))
    assert min(res.order) >= 20, res.order


def test_without_training_data_the_prior_alone_is_predicted(setting, r1_nominal):
    _, _, q_task = setting
    far = predicted_sigma(r1_nominal, np.zeros((0, 6)), q_task, SMALL)
    near = predicted_sigma(r1_nominal, q_task, q_task, SMALL)
    assert np.all(near < 0.5 * far)


@pytest.mark.parametrize("bad", [-1, 41, 2.5, True])
def test_a_bad_pose_count_is_refused(setting, r1_nominal, bad):
    q_train, q_cand, q_task = setting
    with pytest.raises(ModelError, match="0..40"):
        choose(r1_nominal, q_train, q_cand, q_task, bad, SMALL)


@pytest.mark.parametrize("field, value", [("kind", "cdc"), ("noise_mm", 0.0), ("length_rad", float("nan")),
                                          ("gp_scale_mm", -1.0), ("tail", 0.0)])
def test_bad_settings_are_refused(field, value):
    with pytest.raises(ModelError, match=field.split("_")[0]):
        TopupPrior(**{field: value})


@pytest.mark.parametrize("eig, exact", [((1, 1, 1), 0.00738), ((1, 0, 0), 0.0455), ((1, 1, 0), np.exp(-4.0))])
def test_the_gaussian_share_beyond_2_sigma_is_the_chi_square_tail_of_the_shape(eig, exact):
    """sigma is the RMS of the error norm: an isotropic 3-D error exceeds 2 sigma with P(chi2_3 > 12), one along
    one axis with P(|z| > 2), one in a plane with P(chi2_2 > 8) = exp(-4), whatever the scale or the rotation."""
    R = np.linalg.qr(np.random.default_rng(1).standard_normal((3, 3)))[0]
    cov = 0.04 * R @ np.diag(np.asarray(eig, dtype=float)) @ R.T
    assert gaussian_share_over(cov[None]) == pytest.approx(exact, abs=0.0015)


def test_the_gaussian_share_is_what_gaussian_errors_of_those_covariances_give():
    rng = np.random.default_rng(2)
    A = rng.standard_normal((400, 3, 3)) * rng.uniform(0.01, 1.0, (400, 3, 1))
    cov = A @ A.transpose(0, 2, 1)
    sigma = np.sqrt(np.trace(cov, axis1=1, axis2=2))
    draws = np.einsum("nij,nkj->nki", np.linalg.cholesky(cov), rng.standard_normal((400, 200, 3)))
    measured = np.mean(np.linalg.norm(draws, axis=2) > 2 * sigma[:, None])
    assert gaussian_share_over(cov) == pytest.approx(measured, abs=0.003)


@pytest.mark.parametrize("param_sd_mm, residual_mm", [(0.1, 0.04), (0.1, 0.25), (1.0, 0.1), (0.03, 0.15)])
def test_the_held_out_scales_recover_the_planted_prior_and_residual(setting, r1_nominal, param_sd_mm, residual_mm):
    """Errors drawn from the predicted covariance of planted scales at poses held out in two folds (wide poses the
    narrow training grid never reached, and grid clusters among the others): the scales chosen are the planted
    ones (the fixed 0.1 / 0.1 mm of old could not follow a residual of 0.04 or 0.25 mm)."""
    q_train, _, _ = setting
    q = np.concatenate([q_train, wide_poses(150, seed=31)])
    rng = np.random.default_rng(4)
    wide = np.arange(len(q)) >= len(q_train)
    grid = np.isin(np.arange(len(q)) // 7, rng.choice(len(q_train) // 7, len(q_train) // 35, replace=False)) & ~wide
    folds, errs = [wide, grid], []
    for m in folds:
        cov = predicted_position_cov(r1_nominal, q[~m], q[m], param_sd_mm=param_sd_mm, residual_mm=residual_mm)
        errs.append(np.linalg.norm(np.einsum("nij,nj->ni", np.linalg.cholesky(cov),
                                             rng.standard_normal((len(cov), 3))), axis=1))
    scales = held_out_sigma_scales(r1_nominal, q, folds, errs, param_grid_mm=(0.03, 0.1, 0.3, 1.0, 3.0))
    assert (scales.param_sd_mm, scales.residual_mm) == (param_sd_mm, residual_mm)
    if param_sd_mm == 0.1:  # the default: the prior fixed, the residual chosen
        assert held_out_sigma_scales(r1_nominal, q, folds, errs).residual_mm == residual_mm
    assert scales.held_out_poses == int(wide.sum() + grid.sum()) and scales.share_over_2_sigma < 0.05


def test_held_out_scales_refuse_errors_that_are_not_one_per_held_out_pose(setting, r1_nominal):
    q_train, _, _ = setting
    held = np.arange(len(q_train)) < 7
    with pytest.raises(ModelError, match="holds out 7"):
        held_out_sigma_scales(r1_nominal, q_train, [held], [np.ones(6)])
    with pytest.raises(ModelError, match="one error array per fold"):
        held_out_sigma_scales(r1_nominal, q_train, [held], [])


@pytest.mark.parametrize("seed", range(5))
def test_mask_runs_cover_exactly_the_true_rows(seed):
    mask = np.random.default_rng(seed).random(int(np.random.default_rng(seed).integers(0, 40))) < 0.5
    runs = mask_runs(mask)
    rebuilt = np.zeros(len(mask), dtype=bool)
    for a, b in runs:
        assert a <= b and mask[a:b + 1].all()
        rebuilt[a:b + 1] = True
    np.testing.assert_array_equal(rebuilt, mask)
    assert all(b1 + 1 < a2 for (_, b1), (a2, _) in zip(runs, runs[1:]))  # maximal: runs never touch
