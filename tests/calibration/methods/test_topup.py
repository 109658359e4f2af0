"""The top-up design (:mod:`calibration.methods.topup`): exact rank-6 downdates, nested greedy, and that it spends its poses
where the task goes and the training data did not."""

import numpy as np
import pytest

from calibration.errors import ModelError
from calibration.methods.topup import TopupPrior, choose, predicted_sigma
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
