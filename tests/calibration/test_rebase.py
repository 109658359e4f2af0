"""Rebase (base + tool-marker frames of any fitted model) and the ``rebased`` model kind.

Properties: a planted rigid base and tool change is recovered from noiseless poses; directions the poses
cannot see are held and named; the rebased kind wraps every other kind with matching Jacobians, casadi
expression and a bit-identical file round trip.
"""

from __future__ import annotations

import numpy as np
import pytest

from calibration import so3
from calibration.models import load_model, save_model
from calibration.models.rebased import RebasedModel, make_T
from calibration.rebase import RebaseProblem, rebase
from calibration.recording import Recording
from cell_config.loader import load_cell
from tests.calibration.kinds import T_BASE, T_TOOL, models_of_every_kind
from tests.conftest import cluster_design

KINDS = ("constant", "pi", "cdc", "physics", "diagnosed", "rebased")
@pytest.fixture(scope="module")
def inner_models() -> dict:
    """A model of every kind, with non-trivial parameters."""
    k = models_of_every_kind()
    return {"constant": k.constant, "pi": k.pi, "cdc": k.cdc, "physics": k.physics, "diagnosed": k.diagnosed,
            "rebased": RebasedModel("R1", "nls1", k.constant, T_TOOL, T_BASE, 12)}


@pytest.fixture(scope="module")
def wrapped(inner_models) -> dict:
    return {k: RebasedModel("R1", m.method, m, T_BASE, T_TOOL, 12) for k, m in inner_models.items()}


def _q(n: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-1.2, 1.2, (n, 6))


def _recording(model, q: np.ndarray) -> Recording:
    R, p = model.fk(q)
    return Recording(q, p, so3.R_to_quat(R), {}, "synthetic")


def _three_clusters() -> np.ndarray:
    q, cluster = cluster_design(step_deg=15.0, spread_wrist=False)
    keep = np.isin(cluster, [0, 17, 34])
    return q[keep]


@pytest.mark.parametrize("kind", ["constant", "pi", "cdc"])
def test_planted_base_and_tool_change_is_recovered(inner_models, kind):
    inner = inner_models[kind]
    truth = RebasedModel("R1", inner.method, inner, T_BASE, T_TOOL)
    q = np.concatenate([_three_clusters(), _q(14, seed=5)])  # 21 poses that rotate the tool widely
    model, result = rebase(inner, _recording(truth, q))
    assert result.converged and result.fitted == 12 and result.held == ()
    np.testing.assert_allclose(result.T_base_correction, T_BASE, atol=1e-6)
    np.testing.assert_allclose(result.T_tool_correction, T_TOOL, atol=1e-6)
    assert result.residual_after_mm.max() < 1e-6 < result.residual_before_mm.min()
    q_test = _q(30, seed=9)
    np.testing.assert_allclose(model.fk(q_test)[1], truth.fk(q_test)[1], atol=1e-6)
    assert model.kind == "rebased" and model.inner is inner and model.method == inner.method


def test_a_single_pose_holds_the_directions_it_cannot_see(inner_models):
    """One configuration (repeated) shows 6 of the 12 directions; the other 6 are held and named."""
    inner = inner_models["constant"]
    truth = RebasedModel("R1", "nls1", inner, T_BASE, T_TOOL)
    q = np.repeat(_q(1, seed=2), 7, axis=0)
    _, result = rebase(inner, _recording(truth, q))
    assert result.converged and result.fitted == 6 and len(result.held) == 6
    assert all("together" in h for h in result.held) and all(any(f in h for h in result.held) for f in ("base", "tool"))
    assert "6 of 12 frame directions were held at zero" in result.summary()
    assert result.residual_after_mm.max() < 1e-6  # the pose is still matched exactly
    np.testing.assert_allclose(np.linalg.norm(result.observability.V[:, result.fitted:].T
                                              @ (result.delta / result.observability.scale)), 0.0, atol=1e-12)


def test_a_translation_only_rebase_on_one_cluster_reports_what_it_held(inner_models):
    """One cluster (+1 deg steps) barely rotates the tool: a base and a tool shift look alike; rotations are
    excluded by request; both show in the report and nothing held moves."""
    inner = inner_models["constant"]
    shift = make_T(np.eye(3), np.array([1.0, -2.0, 0.5]))
    truth = RebasedModel("R1", "nls1", inner, shift, np.eye(4))
    q, cluster = cluster_design(step_deg=15.0, spread_wrist=False)
    problem = RebaseProblem.from_recording(inner, _recording(truth, q[cluster == 0]), rotations=False)
    result = problem.solve()
    assert result.converged and result.fitted < 6
    assert sum("(excluded)" in h for h in result.held) == 6
    assert any("shift" in h and "together" in h for h in result.held)
    np.testing.assert_array_equal(result.delta[[3, 4, 5, 9, 10, 11]], 0.0)
    # the held combination splits the shift between base and tool: at these small rotations that costs little
    assert result.residual_after_mm.max() < 0.05 < 2.0 < result.residual_before_mm.min()


@pytest.mark.parametrize("kind", KINDS)
def test_rebased_file_round_trip_is_bit_identical(wrapped, kind, tmp_path):
    model = wrapped[kind]
    q = _q(10, seed=6)
    for suffix in (".yaml", ".json"):
        save_model(model, tmp_path / f"m{suffix}")
        loaded = load_model(tmp_path / f"m{suffix}", "R1", load_cell().robot("R1").model())
        assert loaded.kind == "rebased" and loaded.inner.kind == model.inner.kind
        assert [b.names for b in loaded.blocks()] == [b.names for b in model.blocks()]
        for a, b in zip(loaded.fk(q), model.fk(q)):
            np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("kind", KINDS)
def test_rebased_pose_wraps_the_inner_pose(wrapped, kind):
    model = wrapped[kind]
    q = _q(8, seed=3)
    R_i, p_i = model.inner.fk(q)
    R, p = model.fk(q)
    T = np.zeros((8, 4, 4))
    T[:, :3, :3], T[:, :3, 3], T[:, 3, 3] = R_i, p_i, 1.0
    T = model.T_base_correction @ T @ model.T_tool_correction
    np.testing.assert_allclose(R, T[:, :3, :3], atol=1e-14)
    np.testing.assert_allclose(p, T[:, :3, 3], atol=1e-10)


def _pose_difference(Ra, pa, Rb, pb, h):
    return np.concatenate([(pa - pb) / (2 * h), so3.log(Ra @ np.swapaxes(Rb, 1, 2)) / (2 * h)], axis=1)


@pytest.mark.parametrize("kind", ["constant", "pi", "cdc", "physics", "rebased"])
def test_rebased_jacobians_match_finite_differences(wrapped, kind):
    model = wrapped[kind]
    q = _q(4, seed=1)
    theta = model.vector()
    _, _, J = model.jacobian(q)
    assert J.shape == (4, 6, theta.size) and theta.size == sum(b.size for b in model.blocks())
    for k in list(range(min(theta.size - 12, 6))) + list(range(theta.size - 12, theta.size)):
        h = 1e-6 * max(1.0, abs(theta[k]))
        dt = np.zeros_like(theta)
        dt[k] = h
        fd = _pose_difference(*model.with_vector(theta + dt).fk(q), *model.with_vector(theta - dt).fk(q), h)
        np.testing.assert_allclose(J[:, :, k], fd, atol=2e-6 * max(1.0, float(np.abs(fd).max())), rtol=0,
                                   err_msg=f"{kind}: column {k}")
    Jq, h = model.jacobian_q(q), 1e-6
    for j in range(6):
        dq = np.zeros(6)
        dq[j] = h
        fd = _pose_difference(*model.fk(q + dq), *model.fk(q - dq), h)
        np.testing.assert_allclose(Jq[:, :, j], fd, atol=1e-5, rtol=0, err_msg=f"{kind}: joint {j + 1}")


@pytest.mark.parametrize("kind", KINDS)
def test_rebased_casadi_expression_matches_numpy_pose(wrapped, kind):
    ca = pytest.importorskip("casadi")
    model = wrapped[kind]
    qs = ca.SX.sym("q", 6)
    pose = model.casadi(qs)
    assert pose.kind == model.inner.casadi(qs).kind
    f = ca.Function("fk", [qs], [pose.R, pose.p])
    q = _q(10, seed=4)
    R_np, p_np = model.fk(q)
    for i, qi in enumerate(q):
        Rc, pc = f(qi)
        np.testing.assert_allclose(np.asarray(pc).ravel(), p_np[i], atol=1e-9, rtol=0)
        np.testing.assert_allclose(np.asarray(Rc), R_np[i], atol=1e-12, rtol=0)
    theta = ca.SX.sym("t", model.vector().size)  # the symbols at the model's own values give the same pose
    g = ca.Function("fk_theta", [qs, theta], [model.casadi(qs, theta).p])
    np.testing.assert_allclose(np.asarray(g(q[0], model.vector())).ravel(), p_np[0], atol=1e-9)


def test_bad_corrections_are_refused(inner_models):
    from calibration.errors import ModelError

    bad = np.eye(4)
    bad[:3, :3] *= 2.0
    with pytest.raises(ModelError, match="T_base_correction: its rotation block is not a rotation"):
        RebasedModel("R1", "nls1", inner_models["constant"], bad, np.eye(4))
    with pytest.raises(ModelError, match="q must be"):
        RebaseProblem(inner_models["constant"], np.zeros((0, 6)), np.zeros((0, 3, 3)), np.zeros((0, 3)))
