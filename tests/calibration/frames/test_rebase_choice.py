"""The rebase's choice between both frames and their translations only, on clusters held out in turn."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.data.recording import put_in
from calibration.frames.rebase import AUTO_CHOICES, RebaseRefused, choose_directions, rebase_auto
from calibration.kinematics import so3
from calibration.kinematics.so3 import make_T
from calibration.models import ConstantModel
from tests.conftest import cluster_design, measure


def _three_clusters(model, T_base, T_tool, seed):
    q, cluster = cluster_design(step_deg=30.0, spread_wrist=False)
    keep = cluster < 3
    rec = measure(model.fk, q[keep], 0.02, 0.01, seed, cluster[keep])
    return put_in(rec, T_base, T_tool)


def test_a_rotated_frame_needs_the_rotations(r1_nominal):
    model = ConstantModel("R1", "nls1", r1_nominal)
    T_base = make_T(so3.exp(np.radians([0.05, -0.1, 0.3])), np.array([1.5, -0.8, 0.6]))
    choice, means = choose_directions(model, _three_clusters(model, T_base, np.eye(4), 1))
    assert choice.startswith("frames") and means[choice] < means["translations"]


def test_a_shifted_frame_keeps_to_the_translations(r1_nominal):
    model = ConstantModel("R1", "nls1", r1_nominal)
    T_base = make_T(np.eye(3), np.array([1.5, -0.8, 0.6]))
    rec = _three_clusters(model, T_base, make_T(np.eye(3), np.array([0.3, 0.2, -0.4])), 2)
    rebased, result, choice = rebase_auto(model, rec)
    assert choice == "translations" and result.fitted <= 6
    assert result.mean_after_mm < 0.05 < result.mean_before_mm


def test_poses_without_clusters_are_held_out_one_by_one(r1_nominal):
    model = ConstantModel("R1", "nls1", r1_nominal)
    q = np.random.default_rng(5).uniform(-0.8, 0.8, (10, 6))
    rec = measure(model.fk, q, 0.02, 0.01, 3)
    choice, means = choose_directions(model, rec)
    assert choice == "none" and set(means) == set(AUTO_CHOICES)  # the model as given: no frame change to confirm
    with pytest.raises(RebaseRefused, match="rebase refused: .* no frame change does better than the model as "
                                            "given .*nothing written"):
        rebase_auto(model, rec)
    moved = put_in(rec, make_T(np.eye(3), np.array([1.5, -0.8, 0.6])), np.eye(4))
    assert choose_directions(model, moved)[0] != "none"


def _other_day(seed: int):
    """A model of one day (planted geometry) and another day of the same arm (other planted geometry, base moved
    0.8 mm / 0.05 deg): 3 grid clusters whose wrist is still, and 200 poses that move every joint widely."""
    from calibration.kinematics.parameterisation import MinimalParameterisation
    from cell_config import load_cell
    from tests.conftest import planted_parameters

    par = MinimalParameterisation(load_cell().robot("R1").model(), fit_tool=True)
    given, truth = (ConstantModel("R1", "nls1", par.model(planted_parameters(par, seed=s, offset_mm=0.15,
                                                                            tilt_rad=3e-4))) for s in (seed + 50, seed))
    T_base = make_T(so3.exp(np.radians([0.0, 0.0, 0.05])), np.array([0.8, -0.5, 0.3]))
    q, cluster = cluster_design(step_deg=30.0, spread_wrist=False)
    keep = np.isin(cluster, np.unique(cluster)[[0, 5, 11]])
    rec = put_in(measure(truth.fk, q[keep], 0.02, 0.01, seed, cluster[keep]), T_base, np.eye(4))
    test = put_in(measure(truth.fk, np.random.default_rng(9).uniform(-0.9, 0.9, (200, 6)), 0.02, 0.01, 100 + seed),
                  T_base, np.eye(4))
    return given, rec, test


def _test_mean(model, test) -> float:
    from calibration.kinematics.poe import pose_error

    return float(np.mean(pose_error(test.R, test.p, *model.fk(test.q))[0]))


@pytest.mark.parametrize("seed, expected", [(46, "none"), (25, "frames (well seen)")])
def test_a_rebase_is_never_worse_on_the_new_day_than_the_model_given(seed, expected):
    """3 grid clusters with a still wrist see some frame directions only together; fitting them absorbs the given
    model's own error there. Both frames in full move along those barely seen directions and end worse on the new
    day than the model given. Seed 46: the rule before issue 31 took them (their held-out mean beat the translations'
    by more than a standard error); the held-out check confirms no rebase, and refuses. Seed 25: it takes the frames
    with the barely seen directions held, better than the model given."""
    from calibration.frames.rebase import choice_options, rebase

    given, rec, test = _other_day(seed)
    full, full_result = rebase(given, rec, **choice_options("frames"))
    assert _test_mean(full, test) > _test_mean(given, test)
    choice, _ = choose_directions(given, rec)
    assert choice == expected
    if choice == "none":
        assert choose_directions(given, rec, candidates=("translations", "frames"))[0] == "frames"  # the old rule
        with pytest.raises(RebaseRefused):
            rebase_auto(given, rec)
        return
    rebased, result, _ = rebase_auto(given, rec)
    assert _test_mean(rebased, test) < _test_mean(given, test)
    assert result.fitted < full_result.fitted  # the barely seen directions held


def test_the_move_handed_back_is_scaled_back_by_its_uncertainty_over_the_workspace(r1_nominal):
    """With the robot's workspace (configurations within its joint limits) and the shrink rule, rebase_auto hands back
    the chosen move times :func:`calibration.frames.rebase.shrink_factor` (the fit's own residual scale as the noise), in
    (0, 1] and below 1 when the poses are noisy; without it, the fitted move as before."""
    from calibration.frames.rebase import RebaseProblem, choice_options, shrink_factor, workspace_configurations
    from cell_config import load_cell

    limits = load_cell().robot("R1").robot
    q_ws = workspace_configurations(limits.lower_rad, limits.upper_rad)
    model = ConstantModel("R1", "nls1", r1_nominal)
    T_base = make_T(so3.exp(np.radians([0.05, -0.1, 0.3])), np.array([1.5, -0.8, 0.6]))
    q, cluster = cluster_design(step_deg=30.0, spread_wrist=False)
    keep = cluster < 3
    rec = put_in(measure(model.fk, q[keep], 0.15, 0.05, 1, cluster[keep]), T_base, np.eye(4))
    _, plain, choice = rebase_auto(model, rec)
    _, result, same = rebase_auto(model, rec, q_workspace=q_ws, workspace_rule="shrink")
    problem = RebaseProblem.from_recording(model, rec, **choice_options(choice))
    fitted = problem.solve()
    rows = fitted.n_samples * 6
    factor = shrink_factor(problem, fitted, fitted.objective_after * np.sqrt(rows / (rows - fitted.fitted)), q_ws)
    assert same == choice and 0.0 < factor < 1.0
    np.testing.assert_allclose(plain.delta, fitted.delta, atol=1e-9)
    np.testing.assert_allclose(result.delta, factor * fitted.delta, atol=1e-9)
    assert result.shrink == pytest.approx(factor) and f"The move is {factor:.2f} of the fitted one" in result.summary()
    assert plain.shrink == 1.0 and "of the fitted one" not in plain.summary()


def test_an_unknown_workspace_rule_is_refused_naming_the_valid_ones(r1_nominal):
    from calibration.errors import ModelError

    model = ConstantModel("R1", "nls1", r1_nominal)
    rec = _three_clusters(model, make_T(np.eye(3), np.array([1.5, -0.8, 0.6])), np.eye(4), 2)
    with pytest.raises(ModelError, match="unknown workspace rule 'clamp'; valid: project, shrink, "
                                         "shrink \\(held-out noise\\), "
                                         "refuse"):
        rebase_auto(model, rec, q_workspace=np.zeros((3, 6)), workspace_rule="clamp")
