"""Rebase (base + tool-marker frames of any fitted model) and the ``rebased`` model kind.

Properties: a planted rigid base and tool change is recovered from noiseless poses; directions the poses
cannot see are held and named; the rebased kind wraps every other kind with matching Jacobians, casadi
expression and a bit-identical file round trip.
"""

from __future__ import annotations

import numpy as np
import pytest

from calibration.data.recording import Recording
from calibration.frames.rebase import RebaseProblem, rebase
from calibration.kinematics import so3
from calibration.kinematics.so3 import make_T
from calibration.models import load_model, save_model
from calibration.models.rebased import RebasedModel
from cell_config.loader import load_cell
from tests.calibration.models.kinds import T_BASE, T_TOOL, models_of_every_kind
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
    # the objective: the position RMS at least (orientation adds to it), zero once the planted frames are found
    assert result.objective_after < 1e-6 and result.objective_before >= np.sqrt(
        np.mean(result.residual_before_mm ** 2) / 6)
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


DQ = np.radians([0.0, 0.03, -0.02, 0.05, -0.04, 0.0])  # joints 2..5 (1 and 6 are frame rotations)


@pytest.mark.parametrize("kind, offsets", [("constant", (1, 2, 3, 4, 5, 6)), ("pi", (2, 3, 4, 5))])
def test_planted_frames_and_joint_offsets_are_recovered_where_the_wrist_moves(inner_models, kind, offsets):
    """On a POE arm joint 1's and 6's offsets are exactly frame rotations (held); on pi (its compliance and
    deflection depend on q) nearly so, hence joints 2-5 only there."""
    inner = inner_models[kind]
    truth = RebasedModel("R1", inner.method, inner, T_BASE, T_TOOL, joint_offsets=DQ)
    q = _q(21, seed=7)  # every joint moves widely
    model, result = rebase(inner, _recording(truth, q), offsets=offsets)
    assert result.converged and result.fitted == 16 and len(result.held) == len(offsets) - 4
    assert all("joint 1 offset" in h or "joint 6 offset" in h for h in result.held)
    assert result.residual_after_mm.max() < 1e-6 < result.residual_before_mm.min()
    np.testing.assert_allclose(result.joint_offsets[1:5], DQ[1:5], atol=1e-8)
    q_test = _q(30, seed=9)
    np.testing.assert_allclose(model.fk(q_test)[1], truth.fk(q_test)[1], atol=1e-6)
    assert "Joint offsets: " in result.summary()
    assert ("of 18 directions (frames and joint offsets)" in result.summary()) == (len(offsets) == 6)


def test_a_still_wrist_cannot_see_the_wrist_offsets(inner_models):
    """The paper's clusters hold the wrist within 2 deg: a joint 4/5 offset looks like a tool rotation there, so
    the rebase holds (a combination of) them and the rebased model is wrong where the wrist moves."""
    inner = inner_models["constant"]
    truth = RebasedModel("R1", inner.method, inner, T_BASE, T_TOOL, joint_offsets=DQ)
    _, wide = rebase(inner, _recording(truth, _q(21, seed=7)), offsets=(2, 3, 4, 5))
    model, still = rebase(inner, _recording(truth, _three_clusters()), offsets=(2, 3, 4, 5))
    assert wide.fitted == 16 and still.fitted < 16
    assert any("joint 4 offset" in h or "joint 5 offset" in h for h in still.held)
    q_test = _q(30, seed=9)
    assert np.abs(model.fk(q_test)[1] - truth.fk(q_test)[1]).max() > 0.1


@pytest.mark.parametrize("kind", ["constant", "pi"])
def test_rebased_with_offsets_jacobians_casadi_and_file(inner_models, kind, tmp_path):
    model = RebasedModel("R1", inner_models[kind].method, inner_models[kind], T_BASE, T_TOOL, 12, {}, DQ)
    q = _q(4, seed=1)
    R, p = model.fk(q)
    R_i, p_i = model.inner.fk(q + DQ)
    np.testing.assert_allclose(p, (R_i @ T_TOOL[:3, 3] + p_i) @ T_BASE[:3, :3].T + T_BASE[:3, 3], atol=1e-10)
    Jq, h = model.jacobian_q(q), 1e-6
    _, _, J_r = model.rebase_jacobian(q, (2, 5))
    for j in range(6):
        dq = np.zeros(6)
        dq[j] = h
        fd = _pose_difference(*model.fk(q + dq), *model.fk(q - dq), h)
        np.testing.assert_allclose(Jq[:, :, j], fd, atol=1e-5, rtol=0, err_msg=f"joint {j + 1}")
    np.testing.assert_array_equal(J_r[:, :, 12:], Jq[:, :, [1, 4]])
    theta = model.vector()
    _, _, J = model.jacobian(q)
    np.testing.assert_allclose(J[:, :, -12:], J_r[:, :, :12], atol=1e-12)
    for k in range(theta.size - 12, theta.size):
        dt = np.zeros_like(theta)
        dt[k] = h
        fd = _pose_difference(*model.with_vector(theta + dt).fk(q), *model.with_vector(theta - dt).fk(q), h)
        np.testing.assert_allclose(J[:, :, k], fd, atol=2e-6 * max(1.0, float(np.abs(fd).max())), rtol=0)
    save_model(model, tmp_path / "m.yaml")
    loaded = load_model(tmp_path / "m.yaml", "R1", load_cell().robot("R1").model())
    np.testing.assert_array_equal(loaded.joint_offsets, DQ)
    for a, b in zip(loaded.fk(q), model.fk(q)):
        np.testing.assert_array_equal(a, b)
    ca = pytest.importorskip("casadi")
    qs = ca.SX.sym("q", 6)
    pose = model.casadi(qs)
    f = ca.Function("fk", [qs], [pose.p])
    np.testing.assert_allclose(np.asarray(f(q[0])).ravel(), p[0], atol=1e-9)


def test_bad_offsets_are_refused(inner_models):
    from calibration.errors import ModelError

    q = _q(7, seed=2)
    R, p = inner_models["constant"].fk(q)
    for bad in ((0,), (7,), (2, 2), (True,)):
        with pytest.raises(ModelError, match="offsets: expected distinct joints in 1..6"):
            RebaseProblem(inner_models["constant"], q, R, p, offsets=bad)
    with pytest.raises(ModelError, match="joint_offsets must be 6 finite numbers"):
        RebasedModel("R1", "nls1", inner_models["constant"], joint_offsets=np.array([np.nan] * 6))


def test_the_advice_to_collect_more_poses_is_given_only_for_directions_the_poses_could_not_see(inner_models):
    """Directions left out by the caller (translations only) are held too; the summary told the user to "collect
    poses that rotate the tool more widely to determine them" although no pose could: they were not fitted by
    choice. Held because unseen (one repeated pose), the advice stays."""
    inner = inner_models["constant"]
    truth = RebasedModel("R1", "nls1", inner, T_BASE, T_TOOL)
    wide = np.concatenate([_three_clusters(), _q(14, seed=5)])  # sees all 12 directions
    _, chosen = rebase(inner, _recording(truth, wide), rotations=False)
    assert len(chosen.held) == 6 and all(h.endswith("(excluded)") for h in chosen.held)
    assert "6 of 12 frame directions were held at zero" in chosen.summary()
    assert "Collect poses" not in chosen.summary()
    _, unseen = rebase(inner, _recording(truth, np.repeat(_q(1, seed=2), 7, axis=0)))
    assert "Collect poses that rotate the tool more widely to determine them." in unseen.summary()
    _, both = rebase(inner, _recording(truth, np.repeat(_q(1, seed=2), 7, axis=0)), rotations=False)
    assert any(h.endswith("(excluded)") for h in both.held) and not all(h.endswith("(excluded)") for h in both.held)
    assert "to determine those not excluded." in both.summary()
