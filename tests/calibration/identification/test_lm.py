"""Properties of the one Levenberg-Marquardt solver: planted parameters recovered, ridge optimum reached, and
an honest report (a damping blow-up and the iteration cap are not convergence)."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.errors import ModelError
from calibration.identification import GeometricProblem, lm
from calibration.identification.lm import Groups, Linearisation, LMSettings, Residuals, StopReason
from tests.conftest import cluster_design, measure


class Exponentials:
    """G problems ``y = a exp(b t)`` in z = (a, b), each on its own samples; ``flip`` negates some Jacobians."""

    def __init__(self, t: np.ndarray, y: np.ndarray, group: np.ndarray, flip: np.ndarray | None = None) -> None:
        order, self.groups = Groups.sorted_from_index(group)
        self.t, self.y, self.group = t[order], y[order], group[order]
        self.flip = np.zeros(self.groups.n, dtype=bool) if flip is None else flip

    @property
    def shape(self) -> tuple[int, int]:
        return self.groups.n, 2

    def residuals(self, z: np.ndarray) -> Residuals:
        a, b = z[self.group, 0], z[self.group, 1]
        return Residuals((self.y - a * np.exp(b * self.t))[:, None])

    def linearise(self, z: np.ndarray, at: Residuals | None) -> Linearisation:
        a, b = z[self.group, 0], z[self.group, 1]
        E = np.exp(b * self.t)
        J = -np.stack([E, a * self.t * E], axis=-1)[:, None, :]
        J = np.where(self.flip[self.group][:, None, None], -J, J)  # a wrong sign: every step goes uphill
        return Linearisation(self.residuals(z) if at is None else at, J)


def exponentials(counts: list[int], seed: int = 0, noise: float = 0.0, flip: list[bool] | None = None
                 ) -> tuple[Exponentials, np.ndarray]:
    rng = np.random.default_rng(seed)
    truth = np.column_stack([rng.uniform(1.0, 3.0, len(counts)), rng.uniform(-1.0, 1.0, len(counts))])
    group = np.repeat(np.arange(len(counts)), counts)
    t = rng.uniform(0.0, 2.0, group.size)
    y = truth[group, 0] * np.exp(truth[group, 1] * t) + noise * rng.normal(size=group.size)
    perm = rng.permutation(group.size)  # rows need not arrive grouped
    return Exponentials(t[perm], y[perm], group[perm], None if flip is None else np.array(flip)), truth


@pytest.mark.parametrize("counts", [[20, 20, 20], [12, 30, 7, 19]], ids=["equal groups", "unequal groups"])
@pytest.mark.parametrize("solver", ["lu", "lstsq"])
def test_batched_solve_recovers_planted_parameters(counts, solver):
    problem, truth = exponentials(counts, seed=1)
    res = lm.solve(problem, np.array([1.0, 0.0]), LMSettings(step_atol=1e-10, linear_solver=solver))
    assert res.converged.all() and set(res.reason) <= {StopReason.COST, StopReason.STEP}
    np.testing.assert_allclose(res.z, truth, atol=1e-8)
    assert res.cost.shape == (len(counts),) and np.all(res.cost < 1e-16)
    assert res.iterations.shape == (len(counts),) and np.all(res.iterations >= 1)
    assert 0.0 < res.evaluation_seconds <= res.seconds


class Ridge:
    """Linear least squares ``|y - X z|^2 + |w z|^2`` per problem: the optimum is known in closed form."""

    def __init__(self, X: np.ndarray, y: np.ndarray, counts: list[int], w: np.ndarray) -> None:
        self.X, self.y, self.w = X, y, w
        self.groups = Groups(np.concatenate([[0], np.cumsum(counts)[:-1]]), np.array(counts))
        self.group = np.repeat(np.arange(len(counts)), counts)

    @property
    def shape(self) -> tuple[int, int]:
        return self.groups.n, self.X.shape[1]

    def residuals(self, z: np.ndarray) -> Residuals:
        return Residuals((self.y - np.einsum("nk,nk->n", self.X, z[self.group]))[:, None], self.w * z)

    def linearise(self, z: np.ndarray, at: Residuals | None) -> Linearisation:
        return Linearisation(self.residuals(z), -self.X[:, None, :], np.diag(self.w))


def test_prior_terms_reach_the_ridge_optimum():
    rng = np.random.default_rng(2)
    counts = [15, 9, 25]
    X = rng.normal(size=(sum(counts), 3))
    y = rng.normal(size=sum(counts))
    w = np.array([0.5, 2.0, 0.0])
    res = lm.solve(Ridge(X, y, counts, w), settings=LMSettings(cost_rtol=1e-12))
    assert res.converged.all() and res.reason == (StopReason.COST,) * 3
    start = 0
    for g, n in enumerate(counts):
        Xg, yg = X[start: start + n], y[start: start + n]
        start += n
        np.testing.assert_allclose(res.z[g], np.linalg.solve(Xg.T @ Xg + np.diag(w**2), Xg.T @ yg), atol=1e-8)


def test_damping_blow_up_is_not_convergence():
    """A Jacobian of the wrong sign makes every step go uphill: the damping grows past its cap. That problem
    reports converged=False with reason ``damping`` and keeps its start; its batch neighbours still converge."""
    problem, truth = exponentials([20, 20, 20], seed=3, flip=[False, True, False])
    z0 = np.array([1.0, 0.0])
    res = lm.solve(problem, z0, LMSettings(step_atol=1e-10))
    assert res.reason[1] is StopReason.DAMPING and not res.converged[1]
    assert res.iterations[1] < 50  # stopped by the damping cap, before the iteration cap
    np.testing.assert_array_equal(res.z[1], z0)
    assert res.converged[[0, 2]].all()
    np.testing.assert_allclose(res.z[[0, 2]], truth[[0, 2]], atol=1e-8)


class WrongSign:
    """A parameterised arm whose Jacobian has the wrong sign."""

    def __init__(self, par) -> None:
        self.par, self.size = par, par.size

    def pose(self, q, x):
        return self.par.pose(q, x)

    def jacobian(self, q, x):
        R, p, J = self.par.jacobian(q, x)
        return R, p, -J


def test_damping_blow_up_is_reported_by_the_identification(synthetic_arm):
    par, _, truth = synthetic_arm
    q, cluster = cluster_design(step_deg=45.0)
    rec = measure(truth.fk, q, noise_mm=0.02, noise_deg=0.01, seed=5, cluster=cluster)
    res = GeometricProblem(WrongSign(par), q, rec.R, rec.p).solve()
    assert not res.converged.any() and res.reason == (StopReason.DAMPING,)
    np.testing.assert_array_equal(res.x[0], np.zeros(par.size))


def test_iteration_cap_is_not_convergence(synthetic_arm):
    problem, _ = exponentials([20, 20], seed=4)
    res = lm.solve(problem, np.array([1.0, 0.0]), LMSettings(max_iter=2))
    assert not res.converged.any() and res.reason == (StopReason.ITERATIONS,) * 2
    np.testing.assert_array_equal(res.iterations, [2, 2])
    # The same holds through a real identification problem and its result.
    par, _, truth = synthetic_arm
    q, cluster = cluster_design(step_deg=45.0)
    rec = measure(truth.fk, q, noise_mm=0.02, noise_deg=0.01, seed=4, cluster=cluster)
    capped = GeometricProblem(par, q, rec.R, rec.p).solve(max_iter=1)
    assert not capped.converged.any() and capped.reason == (StopReason.ITERATIONS,) and capped.iterations == 1
    full = GeometricProblem(par, q, rec.R, rec.p).solve()
    assert full.converged.all() and full.reason[0].converged and full.cost[0] < capped.cost[0]


def test_nothing_to_fit_stops_at_once():
    """A problem with no free variable (e.g. a refit with every direction held) is solved as it stands."""
    problem, _ = exponentials([5, 5])
    res = lm.solve(Ridge(np.zeros((10, 0)), problem.y, [5, 5], np.zeros(0)))
    assert res.converged.all() and res.reason == (StopReason.STEP,) * 2 and np.all(res.iterations == 0)
    assert res.z.shape == (2, 0)
    np.testing.assert_allclose(res.cost, [np.sum(problem.y[:5] ** 2), np.sum(problem.y[5:] ** 2)])


@pytest.mark.parametrize("bad, match", [
    (dict(damping0=1e9), "damping_min <= damping0 <= damping_max"),
    (dict(damping_up=1.0), "damping_up"),
    (dict(max_iter=-1), "max_iter"),
    (dict(linear_solver="qr"), "'lu' or 'lstsq'"),
])
def test_bad_settings_rejected(bad, match):
    with pytest.raises(ModelError, match=match):
        LMSettings(**bad)
