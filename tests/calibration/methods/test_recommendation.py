"""The recommendation rule (calibration.methods.recommend): fewest parameters tied with the best on held-out clusters."""

import numpy as np
import pytest

from calibration.errors import ModelError
from calibration.methods.recommend import cluster_rms, off_reference, recommend

K, SIZE = 60, 7
GROUPS = np.repeat(np.arange(K), SIZE)


def errors(level: float, seed: int, noise: float = 0.02) -> np.ndarray:
    return np.abs(level + np.random.default_rng(seed).normal(0, noise, K * SIZE))


def test_cluster_rms_is_the_rms_of_each_cluster():
    e = np.arange(K * SIZE, dtype=float)
    expected = [np.sqrt(np.mean(e[GROUPS == k] ** 2)) for k in range(K)]
    np.testing.assert_allclose(cluster_rms(e, GROUPS), expected)


def test_fewest_parameters_among_the_tied_methods():
    shared = errors(0.2, 0)
    held_out = {"big": shared, "small": shared + np.random.default_rng(1).normal(0, 1e-3, K * SIZE),
                "worse": shared + 0.05, "nominal": errors(1.3, 2)}
    n = {"big": 400, "small": 77, "worse": 11, "nominal": 0}
    rec = recommend(held_out, n, GROUPS)
    assert rec.candidates["small"]["tied"] and not rec.candidates["worse"]["tied"]
    assert not rec.candidates["nominal"]["tied"]
    assert rec.method == "small"
    assert rec.best in ("big", "small")


def test_a_clearly_better_method_wins_whatever_its_size():
    held_out = {"big": errors(0.1, 0), "small": errors(0.3, 1)}
    rec = recommend(held_out, {"big": 1000, "small": 3}, GROUPS)
    assert rec.method == rec.best == "big"
    assert rec.candidates["small"]["p_worse_than_best"] < 0.05


def test_methods_without_held_out_errors_are_not_candidates():
    rec = recommend({"a": errors(0.2, 0), "diagnosed": None, "broken": np.full(K * SIZE, np.nan)},
                    {"a": 5, "diagnosed": 1, "broken": 1}, GROUPS)
    assert rec.method == "a"
    assert set(rec.not_candidates) == {"diagnosed", "broken"}
    with pytest.raises(ModelError, match="no method has held-out errors"):
        recommend({"diagnosed": None}, {"diagnosed": 1}, GROUPS)


def test_cdc_methods_around_the_worse_reference_are_not_candidates():
    nls1, pi = errors(0.28, 3), errors(0.16, 4)
    geometric_cdc, pi_cdc = errors(0.12, 5), errors(0.14, 6)  # the geometric one best on held-out clusters
    held_out = {"nls1": nls1, "pi": pi, "rbf": geometric_cdc, "pi+rbf": pi_cdc}
    n = {"nls1": 11, "pi": 77, "rbf": 6746, "pi+rbf": 6746}
    references = {"rbf": ("nls1", nls1), "pi+rbf": ("pi", pi)}
    rec = recommend(held_out, n, GROUPS, cdc_references=references)
    assert "rbf" in rec.not_candidates and "rbf" not in rec.candidates
    assert rec.method == rec.best == "pi+rbf"
    # one reference only: no such step, the held-out figures alone decide
    assert recommend(held_out, n, GROUPS, cdc_references={"rbf": ("nls1", nls1)}).method == "rbf"
    assert recommend(held_out, n, GROUPS).method == "rbf"


def test_the_held_out_errors_of_cdc_methods_on_the_worse_reference_are_not_read():
    nls1, pi, pi_cdc = errors(0.28, 3), errors(0.16, 4), errors(0.14, 6)
    n = {"nls1": 11, "pi": 77, "rbf": 6746, "pi+rbf": 6746}
    references = {"rbf": ("nls1", nls1), "pi+rbf": ("pi", pi)}
    assert set(off_reference(references)) == {"rbf"} and off_reference({"rbf": ("nls1", nls1)}) == {}
    fitted = recommend({"nls1": nls1, "pi": pi, "rbf": errors(0.12, 5), "pi+rbf": pi_cdc}, n, GROUPS,
                       cdc_references=references)
    unread = recommend({"nls1": nls1, "pi": pi, "rbf": None, "pi+rbf": pi_cdc}, n, GROUPS, cdc_references=references)
    assert unread == fitted and unread.not_candidates["rbf"] == off_reference(references)["rbf"]
