"""One parameter count per model in every report (issue 34): the demo's why box said "nls1 (11 parameters)" where
nls1 carries 27, because nls0 and nls1 counted the directions their data could see while cpa, pi and the CDC methods
counted the parameters they carry; the recommendation, the why box and the method table all read that count."""

from __future__ import annotations

import re

import numpy as np
import pytest

from app.reports.page import recommendation_why
from app.reports.sections import comparison_rows
from app.workflows.compare import recommendation_line, run_comparison
from calibration.kinematics.parameterisation import MinimalParameterisation
from calibration.methods.fitter import Fitter
from cell_config import load_cell
from tests.conftest import cluster_design, measure

METHODS = ["nominal", "base", "nls0", "nls1", "pi", "linear"]


@pytest.fixture(scope="module")
def narrow(synthetic_arm):
    """A comparison on a training set that leaves parameter directions unseen (the wrist still at every anchor)."""
    _, _, truth = synthetic_arm
    q, cluster = cluster_design(step_deg=20.0, spread_wrist=False)
    train = measure(truth.fk, q, 0.02, 0.01, 1, cluster)
    test = measure(truth.fk, np.random.default_rng(5).uniform(-0.6, 0.6, (20, 6)), 0.02, 0.01, 2)
    fitter = Fitter.for_arm(load_cell().robot("R1").arm(), train)
    return fitter, run_comparison(fitter, test, METHODS)


def test_the_training_set_hides_directions(narrow):
    fitter, _ = narrow
    obs = fitter.observability()
    assert obs.rank < len(obs.singular_values)  # else the test below could not tell a rank from a size


def test_a_constant_fit_counts_the_parameters_it_carries_not_the_directions_seen(narrow):
    fitter, cmp = narrow
    size = MinimalParameterisation(fitter.nominal, fit_tool=True).size
    for m in ("nls0", "nls1"):
        assert cmp.models[m].n_parameters == size, (m, cmp.models[m].n_parameters, size)
        assert cmp.models[m].info["hidden_directions"]  # the unseen ones are named, not subtracted from the count


def test_the_why_box_the_table_and_the_cli_line_give_each_method_its_model_count(narrow):
    _, cmp = narrow
    table = {row[0]: row[1] for row in comparison_rows(cmp).rows}
    own = {m: str(model.n_parameters) for m, model in cmp.models.items()}
    assert table == own
    rec = cmp.analysis["recommendation"]
    assert rec["candidates"], rec
    for m, c in rec["candidates"].items():
        assert str(c["n_parameters"]) == own[m], (m, c, own[m])
    text, why_table = recommendation_why(cmp, "the test poses")
    assert why_table is not None
    params = why_table.header.index("params")
    for row in why_table.rows:
        assert row[params] == own[row[0]], (row, own)
    said = " ".join(text) + " " + recommendation_line(cmp)
    named = re.findall(r"([\w+]+) \((?:[\d.]+ mm, )?(\d+) parameters", said)
    assert named, said
    for name, count in named:
        assert count == own[name], (name, count, own)
