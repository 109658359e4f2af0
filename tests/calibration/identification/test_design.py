"""Pose design (calibration/identification/design.py): the D criterion beats random designs, the predicted uncertainty is the
least-squares one, the spread term spreads anchors, and Fourier fits on sparse anchors stay bounded."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.errors import ModelError
from calibration.identification import design
from calibration.interpolation import make_interpolator
from calibration.kinematics.parameterisation import MinimalParameterisation
from tests.conftest import cluster_design


@pytest.fixture(scope="module")
def cands(r1_nominal):
    par = MinimalParameterisation(r1_nominal, fit_tool=True)
    q, cluster = cluster_design(step_deg=15.0, spread_wrist=True, seed=3)
    anchors = q[::7, 1:3]
    return design.candidates(par, q, cluster, anchors)


def _logdet(c: design.Candidates, chosen) -> float:
    return float(np.linalg.slogdet(c.info[list(chosen)].sum(axis=0))[1])


def test_d_optimal_selection_beats_random_designs(cands):
    budget = 6
    rng = np.random.default_rng(0)
    random_best = max(_logdet(cands, rng.choice(len(cands), budget, replace=False)) for _ in range(50))
    chosen = design.select(cands, budget, spread_weight=0.0)
    assert len(set(chosen)) == budget
    assert _logdet(cands, chosen) > random_best
    compound = design.select(cands, budget)  # with the space-filling term it still beats the median random design
    median = np.median([_logdet(cands, rng.choice(len(cands), budget, replace=False)) for _ in range(50)])
    assert _logdet(cands, compound) > median


def test_spread_term_spreads_the_anchors(cands):
    def min_gap(chosen):
        a = cands.anchors[chosen]
        d = np.linalg.norm(a[:, None] - a[None], axis=2)
        return d[np.triu_indices(len(a), 1)].min()

    assert min_gap(design.select(cands, 8, spread_weight=5.0)) > min_gap(design.select(cands, 8, spread_weight=0.0))


def test_bad_budget_is_refused(cands):
    for bad in (0, len(cands) + 1, True, 2.5):
        with pytest.raises(ModelError, match="budget must be an integer"):
            design.select(cands, bad)


def test_predicted_sigma_is_the_least_squares_spread(r1_nominal):
    """sigma = noise * sqrt(diag(cov)) matches the spread of linear least-squares estimates under that noise."""
    par = MinimalParameterisation(r1_nominal, fit_tool=True)
    q, cluster = cluster_design(step_deg=30.0, spread_wrist=True, seed=1)
    c = design.candidates(par, q, cluster, q[::7, 1:3])
    noise = 0.05
    fig = design.figures(c, list(range(len(c))), noise)
    J = design.cluster_rows(par, q).reshape(-1, par.size) @ c.basis  # scaled rows in the identifiable directions
    rng = np.random.default_rng(0)
    est = np.array([np.linalg.lstsq(J, rng.normal(0, noise, len(J)), rcond=None)[0] for _ in range(400)])
    empirical = (est @ c.basis.T).std(axis=0) * c.scale
    np.testing.assert_allclose(fig.sigma, empirical, rtol=0.15)
    assert fig.rank == fig.n_identifiable and np.isfinite(fig.condition_number)
    np.testing.assert_allclose(design.figures(c, list(range(len(c))), 2 * noise).sigma, 2 * fig.sigma)


def test_a_design_blind_to_some_directions_says_so(r1_nominal):
    par = MinimalParameterisation(r1_nominal, fit_tool=True)
    q, cluster = cluster_design(step_deg=15.0, spread_wrist=True, seed=3)
    c = design.candidates(par, q, cluster, q[::7, 1:3])
    one = design.figures(c, [0], 0.05)  # one cluster of +1 deg steps: some directions far below the fits' cutoff
    assert one.rank < one.n_identifiable and one.condition_number > 100
    few = design.candidates(par, q[:3], np.zeros(3, int), q[:1, 1:3], reference_q=q)  # 18 rows for 27 directions
    fig = design.figures(few, [0], 0.05)
    assert fig.condition_number == float("inf") and np.all(np.isinf(fig.sigma))


def test_fourier_on_eight_sparse_anchors_stays_bounded():
    """8 anchors: plain least squares over 13 terms is refused; a ridge fit stays within the data's range."""
    rng = np.random.default_rng(4)
    x = np.column_stack([rng.uniform(-0.9, 0.8, 8), rng.uniform(-1.1, 0.8, 8)])
    y = np.column_stack([np.sin(x[:, 0]) + 0.3 * x[:, 1], np.cos(x[:, 1])]) + rng.normal(0, 0.05, (8, 2))
    with pytest.raises(ModelError, match="at least 13 anchors"):
        make_interpolator("fbf13").fit(x, y)
    g = np.stack(np.meshgrid(np.linspace(-0.9, 0.8, 30), np.linspace(-1.1, 0.8, 30)), axis=-1).reshape(-1, 2)
    spread = np.abs(y - y.mean(axis=0)).max(axis=0)
    for kind, opts in (("fbf13", {}), ("fbf7", {"rank": 7})):
        pred = make_interpolator(kind, ridge=0.1, **opts).fit(x, y).predict(g)
        assert np.all(np.abs(pred - y.mean(axis=0)) <= 2.0 * spread), kind


def test_fourier_cdc_fit_on_eight_clusters_chooses_a_ridge_and_stays_near_pi(synthetic_arm):
    """With 8 clusters every held-out fold has fewer than 13 anchors: plain least squares is left out of the ridge
    choice (it raised before), and the chosen fit predicts validation poses about as well as its pi reference."""
    from calibration.evaluation.metrics import errors
    from calibration.methods.fitter import Fitter
    from tests.conftest import measure

    par, _, truth = synthetic_arm
    q, cluster = cluster_design(step_deg=15.0, spread_wrist=False, seed=0)
    keep = np.isin(cluster, np.arange(0, cluster.max() + 1, 4)[:8])
    train = measure(truth.fk, q[keep], 0.02, 0.01, 1, cluster[keep])
    rng = np.random.default_rng(5)
    q_val = np.column_stack([rng.uniform(0, 0.03, 200), rng.uniform(-0.7, 0.7, 200), rng.uniform(-0.6, 0.5, 200),
                             rng.uniform(0, 0.03, (200, 3))])
    val = measure(truth.fk, q_val, 0.0, 0.0, 2)
    fitter = Fitter("R1", par.nominal, train)
    pi = errors(fitter.fit("pi")[0], val).position_mm
    for method in ("fbf13", "fbf7"):
        model, _ = fitter.fit(method)
        strength = model.info["strength"]
        assert strength["ridge"] > 0 and strength["heldout_rms_mm"][0] is None  # ridge 0 cannot fit 6-anchor folds
        e = errors(model, val).position_mm
        assert np.max(e) <= 1.5 * np.max(pi) + 0.05, (method, np.max(e), np.max(pi))
