"""A rebased model keeps its inner model's training range: ``extrapolation`` (evaluate's, predict's and the reports'
warning) counts the poses outside it as the inner model would at the readings it sees, for every inner kind, with and
without joint offsets, also after a file round trip. It counted none: a rebased model read the region from its own
info only, where ``rebase`` never put one, so evaluate of 0725's test recording on a rebased 0801 model said nothing
of poses 92 deg outside the training range."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.models import load_model, save_model
from calibration.models.guard import Region, extrapolation
from calibration.models.rebased import RebasedModel
from tests.calibration.models.kinds import T_BASE, T_TOOL, models_of_every_kind

OFFSETS = {"no offsets": np.zeros(6), "offsets": np.array([0.01, -0.02, 0.0, 0.03, 0.0, -0.01])}


@pytest.fixture(scope="module")
def kinds() -> dict:
    k = models_of_every_kind()
    return {"constant": k.constant, "pi": k.pi, "cdc": k.cdc, "physics": k.physics, "diagnosed": k.diagnosed,
            "rebased": RebasedModel("R1", "nls1", k.constant, T_TOOL, T_BASE, 12)}


@pytest.mark.parametrize("offsets", list(OFFSETS), ids=list(OFFSETS))
@pytest.mark.parametrize("kind", ["constant", "pi", "cdc", "physics", "diagnosed", "rebased"])
def test_a_rebased_model_counts_the_poses_outside_its_inner_models_training_range(kinds, kind, offsets, tmp_path):
    dq = OFFSETS[offsets]
    inner = kinds[kind].with_region(Region(np.full(6, -0.4), np.full(6, 0.4)))
    model = RebasedModel("R1", inner.method, inner, T_BASE, T_TOOL, 12, joint_offsets=dq)
    q = np.random.default_rng(9).uniform(-0.6, 0.6, (40, 6))
    expected = extrapolation(inner, q + dq)
    assert expected["outside_training_range"] > 0
    save_model(model, tmp_path / "rebased.yaml")
    for m in (model, load_model(tmp_path / "rebased.yaml")):
        got = extrapolation(m, q)
        assert got["region_known"]
        assert got["outside_training_range"] == expected["outside_training_range"]
        assert got["max_excess_deg"] == pytest.approx(expected["max_excess_deg"], abs=1e-9)


def test_a_region_given_to_a_rebased_model_reaches_its_inner_model_in_the_inner_readings(kinds):
    dq = OFFSETS["offsets"]
    model = RebasedModel("R1", "nls1", kinds["constant"], T_BASE, T_TOOL, 12, joint_offsets=dq)
    moved = model.with_region(Region(np.full(6, -0.4), np.full(6, 0.4)))
    np.testing.assert_allclose(moved.region().lower_rad, -0.4)
    np.testing.assert_allclose(moved.inner.region().lower_rad, -0.4 + dq)
    assert model.with_region(None).region() is None
