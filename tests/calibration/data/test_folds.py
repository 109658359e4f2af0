"""The extrapolation folds of a clustered recording (:mod:`calibration.data.folds`): whole clusters at the edges of a
joint's range, and the poses that step the still joints away from their anchor."""

import numpy as np

from calibration.data.folds import edge_mask, step_mask
from calibration.data.recording import Recording
from tests.conftest import cluster_design


def _recording(q, cluster):
    n = len(q)
    return Recording(q, np.zeros((n, 3)), np.tile([1.0, 0, 0, 0], (n, 1)), {"cluster": cluster.astype(float)}, "t")


def test_edge_folds_hold_out_whole_clusters_at_either_end_of_the_joint_range():
    q, cluster = cluster_design(step_deg=15.0, spread_wrist=False)
    rec = _recording(q, cluster)
    held = edge_mask(rec, 1)
    first = np.r_[0, np.flatnonzero(np.diff(cluster)) + 1]  # each cluster's anchor
    anchor_q2, anchor_held = q[first, 1], held[first]
    assert held.any() and not held.all()
    assert set(np.unique(cluster[held])) & set(np.unique(cluster[~held])) == set()  # whole clusters
    kept = anchor_q2[~anchor_held]
    assert np.all((anchor_q2[anchor_held] < kept.min()) | (anchor_q2[anchor_held] > kept.max()))
    assert anchor_q2[anchor_held].min() == anchor_q2.min() and anchor_q2[anchor_held].max() == anchor_q2.max()


def test_step_folds_hold_out_the_poses_stepping_the_still_joints():
    q, cluster = cluster_design(step_deg=30.0, spread_wrist=False)
    q = q.copy()
    q[3::7, 0] += np.radians(4.0)  # one pose per cluster steps q1 by 4 deg (the others by at most 1)
    held = step_mask(_recording(q, cluster))
    np.testing.assert_array_equal(np.flatnonzero(held), np.arange(3, len(q), 7))
