"""ISO 9283 AP_p and RP_l against a small example computed by hand."""

import math

import numpy as np
import pytest

from calibration.evaluation.iso9283 import (
    accuracy_mm,
    accuracy_per_pose,
    repeatability_mm,
    repeated_poses,
    repeated_rows,
)


def test_accuracy_and_repeatability_of_three_visits_by_hand():
    # commanded at the origin; visits (1,0,0), (-1,0,0), (0,3,0): barycentre (0,1,0), so AP_p = 1.
    # l = sqrt2, sqrt2, 2; l_bar = (2 + 2 sqrt2)/3; S_l = (2 - sqrt2)/sqrt3; RP_l = l_bar + 3 S_l.
    p = np.array([[1.0, 0, 0], [-1.0, 0, 0], [0, 3.0, 0]])
    assert accuracy_mm(p, [0, 0, 0]) == pytest.approx(1.0, abs=1e-12)
    s2, s3 = math.sqrt(2), math.sqrt(3)
    assert repeatability_mm(p) == pytest.approx((2 + 2 * s2) / 3 + s3 * (2 - s2), abs=1e-12)
    assert repeatability_mm(p + [100.0, -5.0, 7.0]) == pytest.approx(repeatability_mm(p), abs=1e-12)


def test_repeated_rows_need_bit_identical_joints_and_two_visits():
    q = np.array([[0.1] * 6, [0.2] * 6, [0.1] * 6, [0.2 + 1e-12] + [0.2] * 5, [0.3] * 6, [0.1] * 6, [0.3] * 6])
    groups = repeated_rows(q)
    assert [g.tolist() for g in groups] == [[0, 2, 5], [4, 6]]
    assert repeated_rows(np.random.default_rng(0).uniform(-1, 1, (50, 6))) == []


def test_per_pose_figures_follow_the_commanded_position_of_the_model():
    q = np.array([[0.0] * 6, [0.5] * 6, [0.0] * 6, [0.5] * 6])
    p = np.array([[1.0, 0, 0], [10.0, 0, 0], [-1.0, 0, 0], [12.0, 0, 0]])
    poses = repeated_poses(q, p)
    assert [r.n for r in poses] == [2, 2]
    # two visits: l = half the spread for both, S_l = 0
    assert [r.rp_mm for r in poses] == pytest.approx([1.0, 1.0])
    p_model = np.array([[0.0, 2, 0], [11.0, 0, 0], [0.0, 2, 0], [11.0, 0, 0]])
    np.testing.assert_allclose(accuracy_per_pose(poses, p, p_model), [2.0, 0.0], atol=1e-12)
    with pytest.raises(ValueError, match="at least 2"):
        repeatability_mm(p[:1])
