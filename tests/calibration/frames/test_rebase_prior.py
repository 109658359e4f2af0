"""The maximum a posteriori rebase (a Gaussian prior on the frame move) and the spread a frame move's uncertainty
predicts at other configurations (issue 31: 3 grid clusters with a still wrist see some frame directions only
together, and a move along them hurts where the wrist turns)."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.data.recording import Recording
from calibration.errors import ModelError
from calibration.frames.rebase import (
    DAY_FRAME_SD,
    RebaseProblem,
    corrections,
    shrink_factor,
    workspace_configurations,
    workspace_spread,
)
from calibration.kinematics import so3
from calibration.kinematics.so3 import make_T
from calibration.models import ConstantModel
from calibration.models.rebased import RebasedModel
from cell_config import load_cell
from tests.conftest import cluster_design

T_BASE = make_T(so3.exp(np.radians([0.01, -0.01, 0.02])), np.array([0.3, -0.2, 0.1]))
T_TOOL = make_T(so3.exp(np.radians([0.05, 0.1, -0.05])), np.array([-0.2, 0.3, 0.2]))


def _grid(n_clusters: int = 3) -> np.ndarray:
    """Joint angles of ``n_clusters`` grid clusters spread over (q2, q3), wrist still."""
    q, cluster = cluster_design(step_deg=30.0, spread_wrist=False)
    ids = np.unique(cluster)
    return q[np.isin(cluster, ids[np.linspace(0, ids.size - 1, n_clusters).astype(int)])]


def _recording(truth, q: np.ndarray, noise_mm: float = 0.0, w_mm_rad: float = 1.0, seed: int = 0) -> Recording:
    """Poses of ``truth`` with position noise ``noise_mm`` per component and rotation noise ``noise_mm / w_mm_rad``
    [rad] per component (so every weighted residual component has the same scale)."""
    R, p = truth.fk(q)
    rng = np.random.default_rng(seed)
    p = p + rng.normal(0.0, noise_mm, p.shape)
    R = so3.exp(rng.normal(0.0, noise_mm / w_mm_rad, (len(q), 3))) @ R
    return Recording(q, p, so3.R_to_quat(R), {}, "synthetic")


@pytest.fixture(scope="module")
def given(r1_nominal):
    return ConstantModel("R1", "nls1", r1_nominal)


def test_a_wide_prior_is_the_least_squares_rebase(given):
    rec = _recording(RebasedModel("R1", "nls1", given, T_BASE, T_TOOL), _grid(), 0.02, seed=1)
    plain = RebaseProblem.from_recording(given, rec).solve()
    wide = RebaseProblem.from_recording(given, rec, prior_sd=np.full(12, 1e9)).solve()
    np.testing.assert_allclose(wide.delta, plain.delta, atol=1e-7)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_the_map_rebase_zeroes_the_gradient_of_the_posterior_and_shrinks_toward_the_model_given(given, seed):
    """At the MAP rebase the data's pull and the prior's balance (gradient of the posterior zero), and the move is
    smaller in the prior's metric than the least-squares move."""
    rng = np.random.default_rng(seed)
    truth = RebasedModel("R1", "nls1", given, T_BASE, T_TOOL)
    rec = _recording(truth, _grid() + rng.normal(0.0, 0.002, _grid().shape), 0.05, seed=seed)
    problem = RebaseProblem.from_recording(given, rec, prior_sd=DAY_FRAME_SD, noise_mm=0.05)
    result = problem.solve()
    z = np.linalg.lstsq(problem.basis, result.delta, rcond=None)[0][None]
    lin = problem.linearise(z, None)
    gradient = np.einsum("nik,ni->k", lin.J, lin.residuals.r) + lin.J_prior.T @ lin.residuals.prior[0]
    assert np.linalg.norm(gradient) < 1e-6 * max(1.0, float(np.sum(lin.residuals.r ** 2)))
    plain = RebaseProblem.from_recording(given, rec).solve()
    assert np.linalg.norm(result.delta / DAY_FRAME_SD) < np.linalg.norm(plain.delta / DAY_FRAME_SD)


@pytest.mark.parametrize("bad", [np.full(11, 0.1), np.r_[np.full(11, 0.1), 0.0], np.r_[np.full(11, 0.1), np.nan]])
def test_a_bad_prior_is_refused_naming_it(given, bad):
    rec = _recording(given, _grid(), 0.0)
    with pytest.raises(ModelError, match="prior_sd: expected 12 positive standard deviations"):
        RebaseProblem.from_recording(given, rec, prior_sd=bad)


def test_the_workspace_spread_is_the_spread_of_refits_under_noise(given):
    """The predicted spread of the tool position at other configurations matches the spread of rebases refitted on
    noisy copies of the same poses (within the sampling error of 150 refits)."""
    q = _grid(4)
    truth = RebasedModel("R1", "nls1", given, T_BASE, T_TOOL)
    q_ws = np.random.default_rng(7).uniform(-1.5, 1.5, (5, 6))
    problem = RebaseProblem.from_recording(given, _recording(truth, q, 0.0))
    w = float(problem.frames.w_a)
    noise = 0.05
    fitted = RebaseProblem.from_recording(given, _recording(truth, q, noise, w, seed=0))
    predicted = workspace_spread(fitted, fitted.solve(), noise, q_ws)
    positions = np.array([RebaseProblem.from_recording(given, _recording(truth, q, noise, w, seed=s)).solve()
                          .model(given).fk(q_ws)[1] for s in range(1, 151)])
    observed = np.sqrt(np.sum(np.var(positions, axis=0), axis=1))
    np.testing.assert_allclose(predicted, observed, rtol=0.25)


def test_a_move_the_poses_barely_see_spreads_where_the_wrist_turns(given):
    """Fitted along every direction 3 still-wrist clusters see at all, the frame move's uncertainty shows far more
    where the wrist turns than on the clusters' own poses."""
    q = _grid()
    problem = RebaseProblem.from_recording(given, _recording(given, q, 0.02, seed=3), tolerance=1e-5)
    result = problem.solve()
    wrist = q[:1].repeat(20, axis=0)
    wrist[:, 3:] = np.random.default_rng(2).uniform(-1.5, 1.5, (20, 3))
    assert np.mean(workspace_spread(problem, result, 0.05, wrist)) > 3 * np.mean(
        workspace_spread(problem, result, 0.05, q))


def _workspace_error(given, delta_fit, delta_true, q_ws) -> float:
    fit = RebasedModel("R1", "nls1", given, *corrections(delta_fit))
    true = RebasedModel("R1", "nls1", given, *corrections(delta_true))
    return float(np.mean(np.linalg.norm(fit.fk(q_ws)[1] - true.fk(q_ws)[1], axis=1)))


def test_the_shrink_factor_is_one_without_noise_and_falls_to_zero_as_the_noise_swamps_the_move(given):
    truth = RebasedModel("R1", "nls1", given, T_BASE, T_TOOL)
    q_ws = np.random.default_rng(3).uniform(-2.0, 2.0, (50, 6))
    problem = RebaseProblem.from_recording(given, _recording(truth, _grid(), 0.0))
    result = problem.solve()
    factors = [shrink_factor(problem, result, noise, q_ws) for noise in (0.0, 0.01, 0.1, 1.0, 100.0)]
    assert factors[0] == pytest.approx(1.0) and factors[-1] == 0.0
    assert all(a >= b for a, b in zip(factors, factors[1:]))


def test_the_shrunk_move_is_closer_over_the_workspace_than_the_fitted_one():
    """A day's frame change of the data README's size, seen on 3 still-wrist clusters with noise: on average over
    noise draws, the move scaled back by its workspace uncertainty (:func:`shrink_factor`) lands nearer the true
    frames at configurations within the joint limits than the fitted move (issue 31: the fitted move alone, seen only
    on the grid, made the new day worse where the wrist turns)."""
    robot = load_cell().robot("R1")
    given = ConstantModel("R1", "nls1", robot.model())
    q_ws = workspace_configurations(robot.robot.lower_rad, robot.robot.upper_rad, 100)
    rng = np.random.default_rng(11)
    fitted, shrunk = [], []
    for seed in range(20):
        delta_true = rng.normal(0.0, DAY_FRAME_SD)
        truth = RebasedModel("R1", "nls1", given, *corrections(delta_true))
        problem = RebaseProblem.from_recording(given, _recording(truth, _grid(), 0.1, seed=seed))
        result = problem.solve()
        rows = result.n_samples * 6
        noise = result.objective_after * np.sqrt(rows / (rows - result.fitted))
        factor = shrink_factor(problem, result, noise, q_ws)
        fitted.append(_workspace_error(given, result.delta, delta_true, q_ws))
        shrunk.append(_workspace_error(given, factor * result.delta, delta_true, q_ws))
    assert np.mean(shrunk) < 0.9 * np.mean(fitted)
