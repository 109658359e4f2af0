"""Frame checks: a planted base or tool-marker error is found and named, a clean recording is not flagged, a
test recording off by a frame is diagnosed, and frames-first fitting keeps the CDC methods no worse than nls1
when the tool-marker registration is off by 18 mm and 0.5 deg."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.arm import Arm
from calibration.data.recording import put_in, take_out
from calibration.diagnosis.synthetic import Design, tool_error_case
from calibration.evaluation.metrics import errors
from calibration.frames.check import FramedFit, check_recording, check_test, framed
from calibration.kinematics import so3
from calibration.kinematics.parameterisation import MinimalParameterisation
from calibration.kinematics.so3 import make_T
from calibration.methods.fitter import Fitter
from calibration.methods.options import FitOptions
from calibration.models import ConstantModel
from calibration.models.rebased import RebasedModel
from calibration.physics.gravity import GravityModel
from cell_config import load_cell
from tests.conftest import cluster_design, measure, planted_parameters

#: Every fit's options here: the planted recordings' rows all kept (no gross-row screening).
KEEP_ROWS = FitOptions(reject_gross_rows=False)
T_BASE_ERR = make_T(so3.exp(np.radians(0.2) * np.array([0.0, 0.6, 0.8])), np.array([6.0, -4.0, 3.0]))


@pytest.fixture(scope="module")
def arm(r1_nominal):
    """(nominal model, truth model, clean training recording, clean held-out recording) of an arm with errors the
    size of the shared days' (0.5 mm, 0.5 mrad: nominal mean 1.8 mm)."""
    par = MinimalParameterisation(r1_nominal, fit_tool=True)
    truth = par.model(planted_parameters(par, 1, 0.5, 5e-4))
    q, cluster = cluster_design(step_deg=15.0)
    q_test = np.random.default_rng(3).uniform(-0.7, 0.7, (120, 6))
    return (ConstantModel("R1", "nominal", r1_nominal, 0, {}), ConstantModel("R1", "truth", truth, 0, {}),
            measure(truth.fk, q, 0.02, 0.01, 1, cluster), measure(truth.fk, q_test, 0.02, 0.01, 2))


def test_take_out_inverts_put_in(arm):
    _, _, train, _ = arm
    T_tool = make_T(so3.exp(np.array([0.01, -0.02, 0.005])), np.array([10.0, -5.0, 12.0]))
    back = take_out(put_in(train, T_BASE_ERR, T_tool), T_BASE_ERR, T_tool)
    np.testing.assert_allclose(back.p, train.p, atol=1e-9)
    np.testing.assert_allclose(back.R, train.R, atol=1e-12)


def test_clean_recording_is_not_a_frame_problem(arm):
    nominal, _, train, _ = arm
    check = check_recording(nominal, train)
    assert not check.found and check.message() == ""


@pytest.mark.parametrize("planted, frame, word", [("base", "base", "base frame (mocap-to-base"),
                                                  ("tool", "tool", "tool frame (tool-marker-to-flange")])
def test_a_planted_frame_error_is_found_and_named_with_its_size(arm, planted, frame, word):
    nominal, _, train, _ = arm
    T_tool = make_T(so3.exp(np.radians(0.5) * np.array([0.6, 0.0, 0.8])), np.array([12.0, 12.0, -6.0]))
    rec = put_in(train, T_BASE_ERR, np.eye(4)) if planted == "base" else put_in(train, np.eye(4), T_tool)
    check = check_recording(nominal, rec)
    assert check.frame == frame
    assert word in check.message() and (("tool frame (" in check.message()) == (frame == "tool"))
    size_mm = np.linalg.norm((T_BASE_ERR if planted == "base" else T_tool)[:3, 3])
    for fits in ("base and tool", frame):
        fit = check.fits[fits]
        assert abs((fit.base_mm if planted == "base" else fit.tool_mm) - size_mm) < 0.1 * size_mm
    # the message quotes the fit of the frame at fault alone, the one framed() takes out
    assert check.quoted == frame and f"a rigid fit of the {frame} frame brings" in check.message()
    assert f"{(fit.base_mm if planted == 'base' else fit.tool_mm):.2f} mm" in check.message()


def test_framed_fit_wraps_the_kinematics_in_the_frames(arm, r1_nominal):
    nominal, _, train, test = arm
    rec, rec_test = put_in(train, T_BASE_ERR, np.eye(4)), put_in(test, T_BASE_ERR, np.eye(4))
    fitter, check = framed(Arm("R1", "MA2010", r1_nominal), rec, options=KEEP_ROWS)
    assert isinstance(fitter, FramedFit) and check.frame == "base"
    assert fitter.train is rec and fitter.inner.train is not rec
    model, _ = fitter.fit("nls1")
    assert isinstance(model, RebasedModel) and model.info["frames_first"]["frame"] == "base"
    assert model.info["train_samples"] == len(rec)  # the inner model's info is kept (its warnings too)
    assert float(np.mean(errors(model, rec_test).position_mm)) < 0.1
    raw, _ = fitter.fit("nominal")
    assert not isinstance(raw, RebasedModel)


def test_a_test_recording_off_by_a_frame_is_diagnosed(arm):
    _, truth, _, test = arm
    assert not check_test(truth, test).found
    check = check_test(truth, put_in(test, T_BASE_ERR, np.eye(4)))
    assert check.frame == "base" and check.removed_share > 0.9
    assert "test recording against the training recording is off by a frame" in check.message()


def _framed_tool_error_case(seed: int, spread_deg: float):
    """An 18 mm / 0.5 deg tool-marker error on R1, training clusters turning the wrist by ``spread_deg``: the
    frames-first fitter, its frame check and the held-out test recording."""
    robot = load_cell().robot("R1")
    nominal = robot.model()
    gravity = GravityModel.from_spec(robot.robot, nominal)
    train, test, _ = tool_error_case(nominal, gravity, 18.0, 0.5, seed=seed,
                                     train_design=Design(n_q2=6, n_q3=5, spread_deg=spread_deg), n_heldout=150)
    fitter, check = framed(robot.arm(), train, options=KEEP_ROWS)
    return fitter, check, test


def _assert_no_worse_than_nls1(fitter, test, methods: tuple[str, ...]) -> None:
    e = {m: errors(fitter.fit(m)[0], test).position_mm for m in ("nls1",) + methods}
    for m in methods:
        assert np.mean(e[m]) <= np.mean(e["nls1"]) and np.max(e[m]) <= np.max(e["nls1"]), (m, e[m].max(), e["nls1"].max())


def test_cdc_methods_no_worse_than_nls1_with_an_18_mm_tool_marker_error_and_the_wrist_within_3_deg():
    """The narrow training design of the shared days: the marker frame is weakly visible. Fitting both frames
    let the nominal arm's errors bias the split between them (seed 1: pi+linear 0.615/1.790 against nls1's
    0.548/1.241 mm); only the frame at fault is taken out now."""
    fitter, check, test = _framed_tool_error_case(seed=1, spread_deg=3.0)
    assert check.frame == "tool" and "a rigid fit of the tool frame" in check.message()
    assert isinstance(fitter, FramedFit) and np.allclose(fitter.frames.T_base_correction, np.eye(4))
    _assert_no_worse_than_nls1(fitter, test, ("nearest", "linear", "fbf13", "pi+linear", "pi+fbf13"))


def test_cdc_methods_no_worse_than_nls1_with_an_18_mm_tool_marker_error():
    """The fast version of scripts/benchmarks/bench_frames.py: a smaller design, three CDC methods. The training clusters
    turn the wrist by up to 20 deg so that the marker frame is observable (with the shared days' 1-2 deg the
    marker offset along the flange's rotation axis is not, with or without the error: see the script)."""
    fitter, check, test = _framed_tool_error_case(seed=0, spread_deg=20.0)
    assert check.frame == "tool" and "tool frame (tool-marker-to-flange registration)" in check.message()
    assert abs(check.fits["base and tool"].tool_mm - 18.0) < 1.0
    _assert_no_worse_than_nls1(fitter, test, ("nearest", "linear", "fbf13"))


def test_the_other_frame_is_taken_out_too_when_it_is_beyond_the_limits_once_the_one_at_fault_is_out():
    """A base off by 4.5 mm / 0.24 deg (within the limits, so the check names the tool alone) under an 18 mm marker
    error: once the marker is out, the base fitted alone moves beyond the limits, so both frames come out."""
    robot = load_cell().robot("R1")
    nominal = robot.model()
    gravity = GravityModel.from_spec(robot.robot, nominal)
    train, _, _ = tool_error_case(nominal, gravity, 18.0, 0.5, seed=2,
                                  train_design=Design(n_q2=6, n_q3=5, spread_deg=3.0), n_heldout=1)
    T_base = make_T(so3.exp(np.radians(0.3) * np.array([0.0, 0.6, 0.8])), np.array([1.0, -2.0, 4.0]))
    rec = put_in(train, T_base, np.eye(4))
    arm = ConstantModel("R1", "nominal", nominal, 0, {})
    assert check_recording(arm, rec).frame == "tool"
    fitter, check = framed(Arm("R1", "MA2010", nominal), rec, options=KEEP_ROWS)
    assert check.frame == "base and tool" and "a rigid fit of the base and tool frames brings" in check.message()
    assert "base frame (mocap-to-base registration) and tool frame" in check.message()
    assert "(tool-marker-to-flange registration) are off (" in check.message()  # two frames: 'are', not 'is'
    joint = check.fits["base and tool"].result
    np.testing.assert_array_equal(fitter.frames.T_base_correction, joint.T_base_correction)
    np.testing.assert_array_equal(fitter.frames.T_tool_correction, joint.T_tool_correction)
    back = put_in(fitter.inner.train, joint.T_base_correction, joint.T_tool_correction)
    np.testing.assert_allclose(back.p, rec.p, atol=1e-9)


@pytest.mark.parametrize("free", ["rotation", "all"])
def test_pi_is_not_thrown_by_a_marker_rotation_the_frame_check_lets_through(free):
    """A tool marker rotated 0.3 deg on the flange (too little for the frame check) and the wrist within 3 deg in
    training: pi with the marker's rotation damped toward nominal carries the error to poses that turn the wrist;
    left free (FitOptions.pi_registration_free) the rotation is fitted and the held-out error is as without it."""
    robot = load_cell().robot("R1")
    nominal = robot.model()
    gravity = GravityModel.from_spec(robot.robot, nominal)

    def pi_mean(angle_deg: float, parts: str) -> float:
        train, test, _ = tool_error_case(nominal, gravity, 0.0, angle_deg, seed=1,
                                         train_design=Design(n_q2=6, n_q3=5, spread_deg=3.0), n_heldout=150)
        assert not check_recording(ConstantModel("R1", "nominal", nominal, 0, {}), train).found
        fitter = Fitter("R1", nominal, train, FitOptions(pi_registration_free=parts), None, gravity,
                        (robot.robot.lower_rad, robot.robot.upper_rad))
        return float(np.mean(errors(fitter.fit("pi")[0], test).position_mm))

    clean, damped, freed = pi_mean(0.0, free), pi_mean(0.3, "none"), pi_mean(0.3, free)
    assert freed <= 1.05 * clean
    assert damped >= 1.3 * clean


def test_registration_mask_names_the_marker_parameters():
    from calibration.errors import ModelError
    from calibration.physics.extended import ExtendedKinematics

    kin = ExtendedKinematics(MinimalParameterisation(load_cell().robot("R1").model(), fit_tool=True))
    names = np.array(kin.names())
    assert list(names[kin.registration_mask("rotation")]) == ["tool_rx_rad", "tool_ry_rad", "tool_rz_rad"]
    assert list(names[kin.registration_mask("shift")]) == ["flange_dx_mm", "flange_dy_mm", "flange_dz_mm"]
    assert kin.registration_mask("all").sum() == 6 and not kin.registration_mask("none").any()
    with pytest.raises(ModelError, match="registration parts"):
        kin.registration_mask("tool")
    with pytest.raises(ModelError, match="pi_registration_free must be one of none, rotation, shift, all"):
        FitOptions(pi_registration_free="tool")  # refused when the options are made, not at the pi fit


def test_base_motion_is_the_arm_moved_rigidly():
    """The 6 parameter directions of ExtendedKinematics.base_motion move every pose of the arm as a small rigid
    motion of the measurement frame would (to second order in its size)."""
    from calibration.physics.extended import ExtendedKinematics

    kin = ExtendedKinematics(MinimalParameterisation(load_cell().robot("R1").model(), fit_tool=True))
    q = np.random.default_rng(0).uniform(-1.0, 1.0, (40, 6))
    B = kin.base_motion(q)
    xi = np.array([2e-4, -3e-4, 1e-4, 0.3, -0.2, 0.1])  # rad, mm
    R0, p0 = kin.pose(q, np.zeros(kin.size))
    R1, p1 = kin.pose(q, B @ xi)
    E = so3.exp(xi[:3])
    np.testing.assert_allclose(p1, p0 @ E.T + xi[3:], atol=2e-4)
    np.testing.assert_allclose(R1, E @ R0, atol=1e-7)
    assert not B[kin.par.size + 3:].any()  # the geometric block and the tool rotation alone


def test_a_prior_matrix_is_the_prior_its_diagonal_weights_give():
    from calibration.errors import ModelError
    from calibration.identification.geometric import GeometricProblem

    nominal = load_cell().robot("R1").model()
    par = MinimalParameterisation(nominal, fit_tool=True)
    truth = par.model(planted_parameters(par, 1, 0.5, 5e-4))
    q, cluster = cluster_design(step_deg=15.0)
    rec = measure(truth.fk, q, 0.02, 0.01, 1, cluster)
    rng = np.random.default_rng(1)
    w = rng.uniform(0.1, 2.0, par.size)
    by_vector = GeometricProblem(par, rec.q, rec.R, rec.p, prior_weight=w).solve().x
    by_matrix = GeometricProblem(par, rec.q, rec.R, rec.p, prior_weight=np.diag(w)).solve().x
    np.testing.assert_allclose(by_matrix, by_vector, atol=1e-9)
    # a non-square, non-symmetric matrix with a basis: the prior residual is W (x - x_ref), its Jacobian W basis
    W, basis, x_ref = rng.normal(size=(5, par.size)), rng.normal(size=(par.size, 4)), rng.normal(size=par.size)
    problem = GeometricProblem(par, rec.q, rec.R, rec.p, prior_weight=W, basis=basis, x_ref=x_ref)
    z = rng.normal(size=(1, 4)) * 1e-3
    lin = problem.linearise(z)
    np.testing.assert_allclose(lin.residuals.prior[0], W @ (basis @ z[0]), atol=1e-12)
    np.testing.assert_allclose(lin.J_prior, W @ basis, atol=1e-12)
    with pytest.raises(ModelError, match=r"prior_weight must be \(27,\) or \(p, 27\)"):
        GeometricProblem(par, rec.q, rec.R, rec.p, prior_weight=np.ones((3, 5)))


def test_the_base_free_prior_ignores_a_rigid_motion_and_damps_the_rest_as_before():
    """|W P x| is |w * (x - B xi)| at the xi that minimises it, in the prior's own weights (not unit ones: the
    parameters mix mm and rad)."""
    from calibration.identification.observability import base_free_prior
    from calibration.physics.extended import ExtendedKinematics

    kin = ExtendedKinematics(MinimalParameterisation(load_cell().robot("R1").model(), fit_tool=True))
    B = kin.base_motion(np.random.default_rng(0).uniform(-1.0, 1.0, (40, 6)))
    rng = np.random.default_rng(2)
    w = rng.uniform(0.1, 10.0, kin.size)
    M = base_free_prior(w, B)
    np.testing.assert_allclose(M @ B, 0.0, atol=1e-9 * np.abs(w[:, None] * B).max())
    x = rng.normal(size=kin.size) * 1e-3
    xi = np.linalg.lstsq(w[:, None] * B, w * x, rcond=None)[0]
    np.testing.assert_allclose(M @ x, w * (x - B @ xi), atol=1e-12)
    assert np.linalg.norm(M @ x) < np.linalg.norm(w * x)  # a rigid part taken out of a random x


def test_a_base_free_pi_is_refused_where_it_cannot_be_built():
    from calibration.errors import ModelError
    from calibration.frames.check import base_free
    from calibration.physics.extended import ExtendedKinematics

    with pytest.raises(ModelError, match="pi_base_free needs fit_tool"):
        FitOptions(pi_base_free=True, fit_tool=False)
    kin = ExtendedKinematics(MinimalParameterisation(load_cell().robot("R1").model(), fit_tool=True))
    with pytest.raises(ModelError, match=r"3 poses do not determine the rigid motion"):
        kin.base_motion(np.zeros((3, 6)))
    with pytest.raises(ModelError, match=r"needs a fresh Fitter \(Fitter.for_arm\), got str"):
        base_free("not a fitter")


def _pi_mean(train, test, base_free: bool) -> float:
    robot = load_cell().robot("R1")
    gravity = GravityModel.from_spec(robot.robot, robot.model())
    fitter = Fitter("R1", robot.model(), train, FitOptions(pi_base_free=base_free), None, gravity,
                    (robot.robot.lower_rad, robot.robot.upper_rad))
    return float(np.mean(errors(fitter.fit("pi")[0], test).position_mm))


def test_pi_with_a_free_base_is_not_thrown_by_a_base_error_the_frame_check_lets_through():
    """A base frame off by 1.5 mm and 0.1 deg (too little for the frame check) and the wrist within 3 deg in
    training: pi damped toward nominal spreads the error over its geometry and carries it to poses that turn the
    wrist; with FitOptions.pi_base_free the rigid part is not damped and the held-out error is as without it."""
    robot = load_cell().robot("R1")
    nominal = robot.model()
    gravity = GravityModel.from_spec(robot.robot, nominal)
    train, test, _ = tool_error_case(nominal, gravity, 0.0, 0.0, seed=1,
                                     train_design=Design(n_q2=6, n_q3=5, spread_deg=3.0), n_heldout=150)
    T = make_T(so3.exp(np.radians(0.1) * np.array([0.6, -0.8, 0.0])), 1.5 * np.array([0.48, 0.36, -0.8]))
    off_train, off_test = put_in(train, T, np.eye(4)), put_in(test, T, np.eye(4))
    assert not check_recording(ConstantModel("R1", "nominal", nominal, 0, {}), off_train).found
    clean, damped, freed = _pi_mean(train, test, True), _pi_mean(off_train, off_test, False), \
        _pi_mean(off_train, off_test, True)
    assert freed <= 1.02 * clean
    assert damped >= 1.5 * clean


def test_the_frames_first_fit_leaves_the_base_free_and_a_clean_recording_does_not():
    robot = load_cell().robot("R1")
    nominal = robot.model()
    gravity = GravityModel.from_spec(robot.robot, nominal)
    train, _, _ = tool_error_case(nominal, gravity, 18.0, 0.5, seed=1,
                                  train_design=Design(n_q2=6, n_q3=5, spread_deg=3.0), n_heldout=10)
    fitter, check = framed(robot.arm(), train, options=KEEP_ROWS)
    assert check.found and isinstance(fitter, FramedFit) and fitter.inner.options.pi_base_free
    clean, _, _ = tool_error_case(nominal, gravity, 0.0, 0.0, seed=1,
                                  train_design=Design(n_q2=6, n_q3=5, spread_deg=3.0), n_heldout=10)
    fitter, check = framed(robot.arm(), clean, options=KEEP_ROWS)
    assert not check.found and not fitter.options.pi_base_free
