"""The cause survey's helpers (scripts/studies/sameday_causes.py) on planted cases: approach directions, backlash, and
time- versus configuration-structured residuals."""

import numpy as np

from scripts.studies.sameday_causes import approach_directions, backlash_fit, neighbour_differences


def test_approach_direction_is_the_sign_of_the_last_real_move():
    q = np.radians(np.array([[0.0], [1.0], [1.01], [0.0], [0.0], [2.0]]))  # 0.01 deg is below the 0.05 deg step
    np.testing.assert_array_equal(approach_directions(q)[:, 0], [0, 1, 1, -1, -1, 1])


def test_planted_backlash_is_recovered():
    rng = np.random.default_rng(0)
    n = 400
    J = rng.normal(size=(n, 3, 6))
    d = np.sign(rng.normal(size=(n, 6)))
    b = np.array([1e-4, 0, 2e-4, 0, 0, 0])
    r = np.einsum("nij,nj->ni", J, d * b / 2) + rng.normal(0, 1e-6, (n, 3))
    got, rms_after = backlash_fit(J, d, r)
    np.testing.assert_allclose(got, b, atol=1e-6)
    assert rms_after < 1e-5


def _grid():
    """20 columns of q2 (5 deg apart), q3 swept 5 deg per cluster within each column, as the recordings do."""
    anchors = np.array([[q2, q3] for q2 in range(-50, 50, 5) for q3 in range(-40, 30, 5)], float)
    groups = np.repeat(np.arange(len(anchors)), 7)
    return anchors, groups


def test_smooth_configuration_error_gives_a_ratio_near_one():
    anchors, groups = _grid()
    smooth = np.stack([0.3 * np.sin(np.radians(anchors[:, 0] + anchors[:, 1]) * 3)] * 3, axis=1)[groups]
    same, nxt = neighbour_differences(smooth, groups, anchors)
    assert 0.7 < nxt / same < 1.4


def test_column_offsets_give_a_ratio_well_above_one():
    """An offset that changes from one column (recording pass) to the next, on top of the smooth error."""
    anchors, groups = _grid()
    rng = np.random.default_rng(1)
    smooth = np.stack([0.3 * np.sin(np.radians(anchors[:, 0] + anchors[:, 1]) * 3)] * 3, axis=1)
    column = np.unique(anchors[:, 0], return_inverse=True)[1]
    offsets = rng.normal(0, 0.2, (column.max() + 1, 3))[column]
    same, nxt = neighbour_differences((smooth + offsets)[groups], groups, anchors)
    assert nxt / same > 1.5
