"""The global fit's predicted task error (:mod:`calibration.methods.topup_risk`): the closed form is what fitting draws
of its own model gives, far poses are declined, near ones kept, and the held-out scales find a planted misfit."""

import numpy as np
import pytest

from calibration.errors import ModelError
from calibration.methods.topup import Features, TopupPrior, farthest_points
from calibration.methods.topup_risk import fit_risk, held_out_risk_scales
from tests.calibration.methods.test_standalone_poses import wide_poses
from tests.conftest import cluster_design

SMALL = TopupPrior(n_inducing=25, param_sd_mm=0.3, gp_scale_mm=0.2, length_rad=0.7)


@pytest.fixture(scope="module")
def still_wrist():
    """A still-wrist grid; a task among its configurations; candidates near the task and far from it (q1, wrist)."""
    q_train, _ = cluster_design(step_deg=30.0, spread_wrist=False)
    rng = np.random.default_rng(4)
    q_task = q_train[rng.choice(len(q_train), 15, replace=False)] + np.radians(rng.uniform(-3, 3, (15, 6)))
    q_near = q_task[:6] + np.radians(1.0)
    q_far = wide_poses(6, seed=9)
    q_far[:, [0, 3, 4, 5]] = np.radians(80.0) + 0.1 * q_far[:, [0, 3, 4, 5]]
    return q_train, q_task, q_near, q_far


def _draw_fit_errors(nominal, q_given, q_added, q_task, prior, weight, draws, seed):
    """Mean squared task position error of a weighted ridge fit of the parametric part to draws of parameters,
    misfit and noise (the model the closed form describes), shape (T,)."""
    known = np.concatenate([q_given, q_added, q_task])
    feats = Features(nominal, prior, known[farthest_points(known, prior.n_inducing)], None)
    F = feats.rows(np.concatenate([q_given, q_added]))
    w = np.r_[np.ones(len(q_given)), np.full(len(q_added), float(weight))]
    J, P = F[:, :, : feats.m], F[:, :, feats.m:]  # P is zero on orientation rows
    Ft = feats.rows(q_task)[:, :3]
    s2 = prior.noise_mm ** 2
    H = np.einsum("n,nim,nik->mk", w, J, J) + s2 * np.eye(feats.m)
    rng = np.random.default_rng(seed)
    delta = rng.standard_normal((feats.m, draws))
    gp = rng.standard_normal((P.shape[2], draws))
    y = J @ delta + P @ gp + prior.noise_mm * rng.standard_normal((*J.shape[:2], draws))
    fit = np.linalg.solve(H, np.einsum("n,nim,nid->md", w, J, y))
    e = Ft[:, :, : feats.m] @ (fit - delta) - Ft[:, :, feats.m:] @ gp  # (T, 3, draws)
    return np.mean(np.sum(e * e, axis=1), axis=1)


def test_the_closed_form_is_what_fitting_draws_of_its_model_gives(still_wrist, r1_nominal):
    q_train, q_task, q_near, q_far = still_wrist
    added = np.concatenate([q_far[:2], q_near[:2]])
    risk = fit_risk(r1_nominal, q_train[::3], added, q_task, SMALL, add_weight=3)
    for k in (0, 2, 4):
        mc = _draw_fit_errors(r1_nominal, q_train[::3], added[:k], q_task, SMALL, 3, 4000, seed=k)
        np.testing.assert_allclose(risk.risk_mm2[k], mc, rtol=0.12)


def test_without_data_the_risk_is_the_prior(still_wrist, r1_nominal):
    _, q_task, _, _ = still_wrist
    risk = fit_risk(r1_nominal, np.zeros((0, 6)), np.zeros((0, 6)), q_task, SMALL)
    known = q_task
    feats = Features(r1_nominal, SMALL, known[farthest_points(known, SMALL.n_inducing)], None)
    F = feats.rows(q_task)[:, :3]
    np.testing.assert_allclose(risk.risk_mm2[0], np.sum(F * F, axis=(1, 2)), rtol=1e-9)


def test_far_poses_are_declined_and_near_ones_kept(still_wrist, r1_nominal):
    """A task the grid already covers in q1 and the wrist: poses 80 deg away in those joints only bend the global
    fit to another region's misfit (declined: none kept). A task beyond the grid in q1 and the wrist: poses at it
    (1 deg away) are kept, every one."""
    q_train, q_task, _, q_far = still_wrist
    prior = TopupPrior(n_inducing=40, param_sd_mm=0.1, gp_scale_mm=0.15, length_rad=0.5)
    far = fit_risk(r1_nominal, q_train, q_far, q_task, prior)
    assert far.useful() == 0 and far.criterion_mm2[-1] > far.criterion_mm2[0]
    q_wide = wide_poses(15, seed=12)
    near = fit_risk(r1_nominal, q_train, q_wide[::2] + np.radians(1.0), q_wide, prior)
    assert near.useful() == len(q_wide[::2]) and near.criterion_mm2[-1] < near.criterion_mm2[0]


def _fold_risk(nominal, q, folds, prior):
    every = TopupPrior(**{**prior.__dict__, "max_task": 10 ** 6})
    return np.concatenate([fit_risk(nominal, q[~m], np.zeros((0, 6)), q[m], every).risk_mm2[0] for m in folds])


def test_the_held_out_scales_predict_the_planted_fold_errors(r1_nominal):
    """Fold errors drawn from the risk model with a planted misfit (none, or 0.2 mm): the scales chosen on them
    predict the folds' mean squared error within 25 %, and more misfit where more was planted."""
    q_train, _ = cluster_design(step_deg=15.0, spread_wrist=True)
    rng = np.random.default_rng(0)
    folds = [rng.random(len(q_train)) < 0.2 for _ in range(3)]
    predicted = []
    for level in (0.0, 0.2):
        planted = _fold_risk(r1_nominal, q_train, folds, TopupPrior(n_inducing=40, param_sd_mm=0.1,
                                                                   gp_scale_mm=level, length_rad=0.5))
        e = np.sqrt((planted + 3 * 0.03 ** 2) / 3) * np.linalg.norm(rng.standard_normal((planted.size, 3)), axis=1)
        cuts = np.cumsum([m.sum() for m in folds])[:-1]
        scales = held_out_risk_scales(r1_nominal, q_train, folds, np.split(e, cuts), TopupPrior(n_inducing=40))
        got = _fold_risk(r1_nominal, q_train, folds, scales.prior) + 3 * scales.residual_mm ** 2
        np.testing.assert_allclose(got.mean(), planted.mean() + 3 * 0.03 ** 2, rtol=0.25)
        predicted.append(got.mean())
    assert predicted[1] > 2 * predicted[0]


def test_bad_input_is_refused(still_wrist, r1_nominal):
    q_train, q_task, q_near, _ = still_wrist
    with pytest.raises(ModelError, match="task has no configuration"):
        fit_risk(r1_nominal, q_train, q_near, np.zeros((0, 6)), SMALL)
    with pytest.raises(ModelError, match="weight must be positive"):
        fit_risk(r1_nominal, q_train, q_near, q_task, SMALL, add_weight=0)
    with pytest.raises(ModelError, match="one error array per fold"):
        held_out_risk_scales(r1_nominal, q_train, [np.ones(len(q_train), bool)], [])
