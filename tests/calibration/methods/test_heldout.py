"""The robustness checks of CDC fits: held-out clusters, probe ranges, bounded outputs, the chosen local prior."""

import multiprocessing
import time

import numpy as np
import pytest

from calibration import workers
from calibration.errors import DataError, ModelError, ModelFileError
from calibration.interpolation import Fourier13Interpolator, make_interpolator
from calibration.kinematics.parameterisation import MinimalParameterisation
from calibration.methods import diagnosed, workspace
from calibration.methods import heldout as robust
from calibration.methods.cdc import cluster_anchors, geometric_cdc
from calibration.methods.cdc_fit import cdc_options
from calibration.methods.fitter import Fitter
from calibration.methods.options import FitOptions
from calibration.models import load_model, save_model
from calibration.models.cdc import CDC_INPUTS, CdcModel
from tests.conftest import cluster_design, measure


@pytest.fixture(scope="module")
def fitter(synthetic_arm, r1_nominal):
    _, _, truth = synthetic_arm
    q, cluster = cluster_design(step_deg=15.0)
    return Fitter("R1", r1_nominal, measure(truth.fk, q, 0.02, 0.01, 1, cluster), FitOptions())


def test_cluster_folds_hold_out_every_cluster_once():
    folds = robust.cluster_folds(23, 5, seed=3)
    assert folds.shape == (23,) and set(folds) == set(range(5))
    assert np.bincount(folds).max() - np.bincount(folds).min() <= 1
    np.testing.assert_array_equal(folds, robust.cluster_folds(23, 5, seed=3))


def test_range_excess_in_units_of_the_range():
    x_local = np.array([[0.0, 10.0], [1.0, 10.0]])
    pred = np.array([[0.5, 10.0], [3.0, 10.0], [-0.5, 10.0], [0.5, 10.5]])
    np.testing.assert_allclose(workspace.range_excess(pred, x_local, floor=0.1), [0.0, 2.0, 0.5, 5.0])


def test_one_se_rule_takes_the_strongest_tied_strength():
    h = [robust.HeldOut(r, 1.0, 0.0, 0.0, 0.01) for r in (0.50, 0.495, 0.503, 0.52)]
    assert robust.one_se_choice((0.1, 1.0, 3.0, 10.0), h) == 2


def test_held_out_figures_keep_each_clusters_mean_square():
    err, groups = np.array([1.0, 3.0, 2.0, 2.0]), np.array([7, 7, 2, 2])
    h = robust.HeldOut.of_errors(err, err, groups)
    np.testing.assert_allclose(h.cluster_ms_mm2, [4.0, 5.0])  # sorted labels: cluster 2, then 7


@pytest.mark.parametrize("seed", range(6))
def test_paired_rule_tells_apart_what_shared_folds_tie(seed):
    # Fits scored on the same clusters: per-cluster errors that differ widely between clusters (what each fit's own
    # standard error measures) and a small consistent excess of the stronger strengths. The paired standard error sees
    # the excess; the one-SE rule with each fit's own SE takes the strongest within it, the paired rule the best.
    rng = np.random.default_rng(seed)
    groups = np.repeat(np.arange(40), 7)
    base = rng.uniform(0.05, 0.3, 40)[groups] * rng.uniform(0.8, 1.2, groups.size)
    scores = [robust.HeldOut.of_errors(base * (1.0 + k), base, groups) for k in (0.0, 0.02, 0.5)]
    assert robust.paired_se_mm(scores[1], scores[0]) < 0.2 * scores[0].se_rms_mm
    assert robust.one_se_choice((0.3, 1.0, 10.0), scores) == 1
    assert robust.paired_one_se_choice((0.3, 1.0, 10.0), scores) == 0
    # a fit the held-out clusters cannot tell from the best (the same errors): the stronger one is taken
    assert robust.paired_one_se_choice((0.3, 1.0), [scores[0], scores[0]]) == 1


@pytest.mark.parametrize("seed", range(6))
def test_paired_k_se_rule_leaves_the_stronger_only_beyond_k_paired_errors(seed):
    rng = np.random.default_rng(seed)
    groups = np.repeat(np.arange(30), 7)
    base = rng.uniform(0.05, 0.3, 30)[groups]
    weaker = robust.HeldOut.of_errors(base, base, groups)
    stronger = robust.HeldOut.of_errors(base * (1.0 + rng.normal(0.01, 0.02, 30)[groups]), base, groups)
    if stronger.rms_mm < weaker.rms_mm:
        weaker, stronger = stronger, weaker
    z = (stronger.rms_mm - weaker.rms_mm) / robust.paired_se_mm(stronger, weaker)
    chosen = [robust.paired_one_se_choice((0.3, 1.0), [weaker, stronger], k) for k in (0.5, 1.0, 2.0, 3.0, 5.0)]
    assert chosen == [int(z <= k) for k in (0.5, 1.0, 2.0, 3.0, 5.0)]
    assert robust.CHOICE_RULES["paired_three_se"]((0.3, 1.0), [weaker, stronger]) == int(z <= 3.0)


def test_paired_se_refuses_fits_on_other_clusters():
    a = robust.HeldOut.of_errors(np.ones(6), np.ones(6), np.repeat([0, 1, 2], 2))
    b = robust.HeldOut.of_errors(np.ones(4), np.ones(4), np.repeat([0, 1], 2))
    with pytest.raises(ModelError, match="same clusters"):
        robust.paired_se_mm(a, b)


def test_local_prior_rule_is_validated_and_applied(fitter):
    with pytest.raises(ModelError, match="local_prior_rule.*one_se, paired_one_se, paired_two_se"):
        FitOptions(local_prior_rule="median")
    fitter.local_fits()
    grid, scores, ratios = fitter._cache.local_prior_scores["pi"]
    ok = [i for i, r in enumerate(ratios) if r <= workspace.WORKSPACE_RATIO_LIMIT]
    for name, rule in robust.CHOICE_RULES.items():
        other = Fitter(fitter.robot, fitter.nominal, fitter.train, FitOptions(local_prior_rule=name))
        other._cache.local_by_prior = fitter._cache.local_by_prior  # the same local fits: only the rule runs
        other._cache.pi = fitter._cache.pi
        expected = grid[ok[rule(tuple(grid[i] for i in ok), [scores[i] for i in ok])]] if ok else max(grid)
        assert other.local_prior("pi") == expected
        assert other._cache.local_prior_cv["pi"]["rule"] == name


def test_cdc_model_clips_to_its_bounds_and_keeps_them_in_its_file(tmp_path, r1_nominal):
    par = MinimalParameterisation(r1_nominal)
    rng = np.random.default_rng(2)
    x = rng.uniform(-0.5, 0.5, (30, 2))
    y = np.column_stack([1e-3 * np.sin(3 * x[:, 0] + k) for k in range(par.size)])
    bounds = np.stack([y.min(axis=0), y.max(axis=0)])
    model = CdcModel("R1", "fbf13", *geometric_cdc(par), Fourier13Interpolator().fit(x, y), bounds=bounds)
    far = np.zeros((3, 6))
    far[:, 1:3] = [[2.5, -2.5], [3.0, 3.0], [-3.0, 1.0]]  # far outside the anchors: Fourier extrapolates
    theta = model.parameters_at(far)[:, : par.size]
    assert np.all(theta >= bounds[0]) and np.all(theta <= bounds[1])
    save_model(model, tmp_path / "m.json")
    back = load_model(tmp_path / "m.json")
    np.testing.assert_array_equal(back.bounds, bounds)
    assert np.array_equal(back.fk(far)[1], model.fk(far)[1])


def test_cdc_model_file_with_bad_bounds_is_refused(tmp_path, r1_nominal):
    import json

    par = MinimalParameterisation(r1_nominal)
    x = np.random.default_rng(2).uniform(-0.5, 0.5, (30, 2))
    y = np.zeros((30, par.size))
    model = CdcModel("R1", "fbf13", *geometric_cdc(par), Fourier13Interpolator().fit(x, y),
                     bounds=np.zeros((2, par.size)))
    save_model(model, tmp_path / "m.json")
    doc = json.loads((tmp_path / "m.json").read_text())
    body = doc.get("body", doc)
    body["bounds"] = [[0.0] * 3]
    (tmp_path / "m.json").write_text(json.dumps(doc))
    with pytest.raises(ModelFileError, match="bounds"):
        load_model(tmp_path / "m.json")


def test_cdc_fit_records_its_checks_and_the_chosen_prior(fitter):
    model, _ = fitter.fit("linear")
    held = model.info["heldout"]
    assert held["rms_mm"] > 0 and held["reference_rms_mm"] > 0
    assert model.info["local_prior"]["chosen"] in FitOptions().local_prior_grid
    assert "warning" not in model.info  # planted constant geometry: nothing to flag
    assert model.bounds.shape == (2, fitter.par.size)


def test_an_interpolator_worse_than_the_reference_is_seen_on_held_out_clusters(fitter):
    local, pi = fitter.local_fits(), fitter.physics_informed()
    groups, _ = cluster_anchors(fitter.train)
    noisy = local.x + np.random.default_rng(0).normal(0.0, 0.3, local.x.shape) * fitter.par.scale()
    h = robust.held_out(lambda: make_interpolator("nearest"), pi.kinematics, pi.theta, local.anchors, noisy,
                        groups, fitter.train, CDC_INPUTS)
    assert h.ratio > robust.HELDOUT_RATIO_LIMIT


def test_workspace_probes_keep_the_interpolation_inputs_at_anchors_and_the_joints_within_limits():
    anchors = np.radians([[0.0, 10.0], [20.0, -30.0], [-40.0, 5.0]])
    lo, hi = np.radians([-170, -90, -80, -150, -135, -210.0]), np.radians([170, 150, 150, 150, 90, 210.0])
    q = workspace.workspace_probes(anchors, (lo, hi), 6, CDC_INPUTS, n=500, seed=1)
    assert q.shape == (500, 6) and np.all(q >= lo) and np.all(q <= hi)
    assert {tuple(r) for r in q[:, 1:3]} <= {tuple(r) for r in anchors}


def test_workspace_ratio_compares_corrections_on_probes_and_training_poses():
    def ref(q):
        return None, np.zeros((len(q), 3))

    def model(q):  # correction grows with |q4|: small on training poses (q4 ~ 0), large over the workspace
        return None, np.column_stack([0.1 + np.abs(q[:, 3]), np.zeros(len(q)), np.zeros(len(q))])

    q_train = np.zeros((10, 6))
    q_probe = np.zeros((10, 6))
    q_probe[:, 3] = 1.0
    ratio, probe, train = workspace.workspace_ratio(model, ref, q_train, q_probe)
    np.testing.assert_allclose([ratio, probe, train], [11.0, 1.1, 0.1])


@pytest.mark.parametrize("kind", ["nn", "rbf"])
def test_held_out_folds_in_worker_processes_give_the_same_bits(fitter, kind):
    local, pi = fitter.local_fits(), fitter.physics_informed()
    groups, _ = cluster_anchors(fitter.train)
    options = {"hidden": (8, 8), "max_iter": 10} if kind == "nn" else {}

    def check(workers):
        return robust.held_out(lambda: make_interpolator(kind, **options), pi.kinematics, pi.theta,
                               local.anchors, local.x, groups, fitter.train, CDC_INPUTS, workers=workers)

    assert check(2) == check(1)


def test_a_cancelled_held_out_check_stops_its_workers(fitter):
    local, pi = fitter.local_fits(), fitter.physics_informed()
    groups, _ = cluster_anchors(fitter.train)
    check = robust.HeldOutCheck(lambda: make_interpolator("nn", hidden=(8,), max_iter=5), pi.kinematics,
                                pi.theta, local.anchors, local.x, groups, fitter.train, CDC_INPUTS, workers=2)
    assert multiprocessing.active_children()  # the workers started with the check
    check.cancel()
    assert multiprocessing.active_children() == []


def test_a_held_out_worker_that_dies_is_an_error_not_a_hang(fitter):
    import os
    from concurrent.futures.process import BrokenProcessPool

    local, pi = fitter.local_fits(), fitter.physics_informed()
    groups, _ = cluster_anchors(fitter.train)
    with pytest.raises(BrokenProcessPool):
        robust.held_out(lambda: os._exit(3), pi.kinematics, pi.theta, local.anchors, local.x, groups,
                        fitter.train, CDC_INPUTS, workers=2)


def test_held_out_on_the_first_folds_scores_both_fits_on_those_clusters_only(fitter):
    local, pi = fitter.local_fits(), fitter.physics_informed()
    groups, _ = cluster_anchors(fitter.train)
    args = (lambda: make_interpolator("rbf"), pi.kinematics, pi.theta, local.anchors, local.x, groups, fitter.train,
            CDC_INPUTS)
    full, two = robust.held_out(*args), robust.held_out(*args, n_evaluated=2)
    assert robust.held_out(*args, n_evaluated=robust.N_FOLDS) == full
    rows = np.isin(robust.cluster_folds(len(local.anchors))[groups], [0, 1])
    ref = robust.position_errors(pi.kinematics, pi.theta, fitter.train)[rows]
    np.testing.assert_allclose(two.reference_rms_mm, np.sqrt(np.mean(ref ** 2)), rtol=1e-12)
    assert two.reference_max_mm == ref.max() and two != full
    with pytest.raises(ModelError, match="n_evaluated"):
        robust.held_out(*args, n_evaluated=robust.N_FOLDS + 1)


def _here_and_prefetched(synthetic_arm, r1_nominal, method: str):
    """The training recording, ``method`` fitted in this process, and a Fitter that has prefetched it."""
    _, _, truth = synthetic_arm
    q, cluster = cluster_design(step_deg=30.0)
    train = measure(truth.fk, q, 0.02, 0.01, 1, cluster)
    here, _ = Fitter("R1", r1_nominal, train, FitOptions(local_prior=0.1)).fit(method)
    fitter = Fitter("R1", r1_nominal, train, FitOptions(local_prior=0.1))
    fitter.prefetch(["nominal", method])
    return train, here, fitter


def test_a_prefetched_neural_fit_is_the_fit_made_here(synthetic_arm, r1_nominal):
    train, here, fitter = _here_and_prefetched(synthetic_arm, r1_nominal, "nn")
    assert multiprocessing.active_children() or workers.default_workers(robust.N_FOLDS) < 2
    there, seconds = fitter.fit("nn")
    assert np.array_equal(there.fk(train.q)[1], here.fk(train.q)[1]) and seconds > 0
    assert there.info["heldout"] == here.info["heldout"]
    assert multiprocessing.active_children() == []  # the pool is shut once every prefetched fit is collected


def test_a_prefetched_diagnosis_runs_in_its_own_worker_and_is_the_fit_made_here(synthetic_arm, r1_nominal):
    """compare's diagnosed fit shares nothing with the other methods: prefetch forks it first, so it overlaps the
    shared fits; the same model as diagnosed here."""
    train, here, fitter = _here_and_prefetched(synthetic_arm, r1_nominal, "diagnosed")
    assert fitter._cache.diagnosis_job is not None or workers.default_workers(robust.N_FOLDS) < 2
    assert multiprocessing.active_children() or workers.default_workers(robust.N_FOLDS) < 2
    there, seconds = fitter.fit("diagnosed")
    assert np.array_equal(there.fk(train.q)[1], here.fk(train.q)[1]) and seconds > 0
    assert there.info["verdict"] == here.info["verdict"]
    assert fitter._cache.diagnosis_job is None and multiprocessing.active_children() == []


def _diagnosis_in_a_worker(synthetic_arm, r1_nominal, monkeypatch, job) -> Fitter:
    """A Fitter whose ``diagnosed`` fit (replaced by ``job``) prefetch has started in its worker process."""
    if workers.default_workers(robust.N_FOLDS) < 2:
        pytest.skip("one usable core: no worker is forked")
    _, _, truth = synthetic_arm
    q, cluster = cluster_design(step_deg=30.0)
    monkeypatch.setattr(diagnosed, "run_diagnosis", job)
    fitter = Fitter("R1", r1_nominal, measure(truth.fk, q, 0.02, 0.01, 1, cluster), FitOptions(local_prior=0.1))
    fitter.prefetch(["nominal", "diagnosed"])
    return fitter


def test_a_data_error_in_the_diagnosis_worker_reaches_the_caller_as_itself(synthetic_arm, r1_nominal, monkeypatch):
    """An error raised in the forked worker must come back as the same one-line error (exit 2 in the CLI), not
    as a broken pool: the data-carrying errors take several arguments and must still pickle."""
    def bad(self):
        raise DataError("train.csv", 4, "q2", "not a number")

    fitter = _diagnosis_in_a_worker(synthetic_arm, r1_nominal, monkeypatch, bad)
    with pytest.raises(DataError, match=r"train.csv, row 4, column 'q2': not a number") as e:
        fitter.fit("diagnosed")
    assert (e.value.path, e.value.row, e.value.column) == ("train.csv", 4, "q2")
    assert fitter._cache.diagnosis_job is None and multiprocessing.active_children() == []


def test_a_failure_elsewhere_stops_the_diagnosis_worker_without_waiting_for_it(synthetic_arm, r1_nominal,
                                                                                monkeypatch):
    """abort_jobs (what compare calls when anything fails) ends a diagnosis still running in its worker."""
    def slow(self):
        time.sleep(60.0)

    fitter = _diagnosis_in_a_worker(synthetic_arm, r1_nominal, monkeypatch, slow)
    assert multiprocessing.active_children()
    start = time.monotonic()
    fitter.abort_jobs()
    assert time.monotonic() - start < 10.0 and multiprocessing.active_children() == []
    assert fitter._cache.diagnosis_job is None


def test_held_out_errors_refitted_in_workers_are_those_refitted_here(synthetic_arm, r1_nominal):
    """The recommendation's fold refits of the networks run in forked workers: the same bits as in-process."""
    _, _, truth = synthetic_arm
    q, cluster = cluster_design(step_deg=30.0)
    train = measure(truth.fk, q, 0.02, 0.01, 1, cluster)
    here = Fitter("R1", r1_nominal, train, FitOptions(local_prior=0.1)).held_out_errors("nn")
    fitter = Fitter("R1", r1_nominal, train, FitOptions(local_prior=0.1))
    fitter.prefetch_held_out_errors(["nominal", "nn"])
    assert "nn" in fitter._cache.held_out_errors or workers.default_workers(robust.N_FOLDS) < 2
    there = fitter.held_out_errors("nn")
    assert there.shape == (len(train),) and np.all(np.isfinite(there))
    assert np.array_equal(there, here)
    assert multiprocessing.active_children() == []


def test_the_neural_check_scores_the_recommendations_fold_refits(synthetic_arm, r1_nominal):
    """nn/ae's held-out check is the method and its constant reference refitted without each of the first folds:
    the same refits as held_out_errors, so compare trains no network for the check alone."""
    _, _, truth = synthetic_arm
    q, cluster = cluster_design(step_deg=30.0)
    train = measure(truth.fk, q, 0.02, 0.01, 1, cluster)
    fitter = Fitter("R1", r1_nominal, train, FitOptions(local_prior=0.1))
    held = fitter.fit("pi+nn")[0].info["heldout"]
    groups, anchors = cluster_anchors(train)
    rows = np.isin(robust.cluster_folds(len(anchors))[groups], range(robust.NEURAL_EVALUATED_FOLDS))
    err, ref = fitter.held_out_errors("pi+nn")[rows], fitter.held_out_errors("pi")[rows]
    assert held["rms_mm"] == round(float(np.sqrt(np.mean(err ** 2))), 4)
    assert held["reference_rms_mm"] == round(float(np.sqrt(np.mean(ref ** 2))), 4)
    assert held["max_mm"] == round(float(err.max()), 4) and held["reference_max_mm"] == round(float(ref.max()), 4)


def test_pi_ae_trains_the_issue_14_autoencoder_and_the_papers_ae_keeps_the_papers(fitter):
    """pi+ae's encoder is two layers of 128 since issue 14 (chosen on held-out training clusters); the paper's ae keeps
    the paper's three of 200, which is also the interpolator's default and one option away for pi+ae."""
    from calibration.interpolation.autoencoder import PAPER_HIDDEN, AutoencoderInterpolator

    assert cdc_options(fitter, "pi+ae")["hidden"] == (128, 128) == FitOptions().pi_ae_hidden
    assert "hidden" not in cdc_options(fitter, "ae") and AutoencoderInterpolator().hidden == PAPER_HIDDEN == (200,) * 3
    paper = Fitter(fitter.robot, fitter.nominal, fitter.train, FitOptions(local_prior=0.1, pi_ae_hidden=PAPER_HIDDEN))
    assert cdc_options(paper, "pi+ae")["hidden"] == PAPER_HIDDEN
    assert not any("hidden" in cdc_options(fitter, m) for m in ("nn", "pi+nn"))  # nn keeps the paper's network


def test_the_unstable_fit_warning_says_what_a_user_can_do(synthetic_arm, r1_nominal, monkeypatch):
    _, _, truth = synthetic_arm
    q, cluster = cluster_design(step_deg=15.0)
    fitter = Fitter("R1", r1_nominal, measure(truth.fk, q, 0.02, 0.01, 1, cluster), FitOptions(local_prior=0.1))
    monkeypatch.setattr(robust, "HELDOUT_RATIO_LIMIT", 0.0)  # every CDC fit fails the held-out check
    warning = fitter.fit("linear")[0].info["warning"]
    assert "linear may be unstable" in warning and "--method pi" in warning
    assert "FitOptions" not in warning and "local_prior" not in warning


def test_a_cdc_fit_says_when_no_local_prior_passed_the_workspace_check(synthetic_arm, r1_nominal, monkeypatch):
    """No prior within the limit: the strongest is taken, which holds the local fits at the reference; the fit said
    nothing of it (the final fit's own ratio is then small), and a CDC method quietly gave what pi gives."""
    _, _, truth = synthetic_arm
    q, cluster = cluster_design(step_deg=15.0)
    monkeypatch.setattr(workspace, "WORKSPACE_RATIO_LIMIT", 0.0)
    fitter = Fitter("R1", r1_nominal, measure(truth.fk, q, 0.02, 0.01, 1, cluster),
                    FitOptions(local_prior_grid=(0.3, 10.0)))
    model, _ = fitter.fit("pi+nearest")
    assert model.info["local_prior"]["chosen"] == 10.0
    assert "no local prior of [0.3, 10.0] kept its correction over the workspace" in model.info["warning"]
