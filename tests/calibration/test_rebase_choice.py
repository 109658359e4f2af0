"""The rebase's choice between both frames and their translations only, on clusters held out in turn."""

from __future__ import annotations

import numpy as np

from calibration import so3
from calibration.frames import put_in
from calibration.models import ConstantModel
from calibration.models.rebased import make_T
from calibration.rebase import choose_directions, rebase_auto
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
    assert choice == "frames" and means["frames"] < means["translations"]


def test_a_shifted_frame_keeps_to_the_translations(r1_nominal):
    model = ConstantModel("R1", "nls1", r1_nominal)
    T_base = make_T(np.eye(3), np.array([1.5, -0.8, 0.6]))
    rec = _three_clusters(model, T_base, make_T(np.eye(3), np.array([0.3, 0.2, -0.4])), 2)
    rebased, result, choice = rebase_auto(model, rec)
    assert choice == "translations" and result.fitted <= 6
    assert result.mean_after_mm < 0.05 < result.mean_before_mm


def test_poses_without_clusters_get_the_full_frames(r1_nominal):
    model = ConstantModel("R1", "nls1", r1_nominal)
    q = np.random.default_rng(5).uniform(-0.8, 0.8, (10, 6))
    rec = measure(model.fk, q, 0.02, 0.01, 3)
    assert choose_directions(model, rec) == ("frames", {})
