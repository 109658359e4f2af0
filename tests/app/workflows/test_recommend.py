"""compare's recommended model: set, one of the fitted methods, chosen on training data alone."""

import numpy as np
import pytest

from app.workflows.compare import run_comparison
from calibration.data.recording import Recording
from calibration.methods.fitter import Fitter
from calibration.methods.options import FitOptions
from tests.conftest import cluster_design, measure

METHODS = ("nominal", "nls1", "pi", "fbf13", "pi+linear")


@pytest.fixture(scope="module")
def constant_truth(synthetic_arm, r1_nominal):
    """Training and test recordings of an arm whose error is constant geometry (what nls1 fits)."""
    _, _, truth = synthetic_arm
    q, cluster = cluster_design(step_deg=15.0)
    train = measure(truth.fk, q, 0.02, 0.01, 1, cluster)
    q_test, _ = cluster_design(step_deg=20.0, seed=3)
    test = measure(truth.fk, q_test, 0.02, 0.01, 2)
    fitter = Fitter("R1", r1_nominal, train, FitOptions())
    return fitter, test, run_comparison(fitter, test, METHODS)


def test_recommended_is_set_and_is_a_fitted_method(constant_truth):
    _, _, cmp = constant_truth
    assert cmp.recommended in cmp.models
    assert cmp.to_json()["recommended"] == cmp.recommended
    rec = cmp.analysis["recommendation"]
    assert rec["method"] == cmp.recommended and cmp.recommended in rec["candidates"]
    assert set(rec["candidates"]) | set(rec["not_candidates"]) == set(METHODS)
    assert not set(rec["candidates"]) & set(rec["not_candidates"])


def test_constant_truth_gives_a_constant_recommendation(constant_truth):
    _, _, cmp = constant_truth
    assert cmp.models[cmp.recommended].kind == "constant", cmp.analysis["recommendation"]
    assert cmp.recommended != "nominal"


def test_the_test_recording_never_enters_the_choice(constant_truth, synthetic_arm):
    fitter, test, cmp = constant_truth
    rng = np.random.default_rng(7)
    # the test poses shuffled against their measurements, and moved by 50 mm: every test error changes
    order = rng.permutation(len(test))
    corrupted = Recording(test.q, test.p[order] + 50.0, test.quat[order], {}, "corrupted")
    again = run_comparison(fitter, corrupted, METHODS)
    assert again.test_errors["nls1"].position_mm.mean() > 10 * cmp.test_errors["nls1"].position_mm.mean()
    assert again.recommended == cmp.recommended
    assert again.analysis["recommendation"] == cmp.analysis["recommendation"]


def test_cdc_methods_on_the_losing_reference_are_not_refitted_on_the_folds(constant_truth):
    """Their held-out errors cannot change the choice ("CDC reference first"), so the recommendation skips them."""
    from calibration.methods.recommend import off_reference

    fitter, _, cmp = constant_truth
    references = {m: ({"fbf13": "nls1", "pi+linear": "pi"}[m], fitter.held_out_errors(
        {"fbf13": "nls1", "pi+linear": "pi"}[m])) for m in ("fbf13", "pi+linear")}
    skipped = set(off_reference(references))
    assert len(skipped) == 1, references  # one of the two references loses
    computed = set(fitter._cache.held_out_errors)
    assert not skipped & computed and ({"fbf13", "pi+linear"} - skipped) <= computed
    assert skipped <= set(cmp.analysis["recommendation"]["not_candidates"])
