"""Folds of a clustered training recording that a fit must extrapolate to: the clusters at either edge of a joint's
training range, and the poses that step the still joints away from their cluster's anchor. Held out of a refit,
they test what a model does beyond its data, as on a task that leaves the training band
(``scripts/studies/extrapolation_folds.py``, the held-out residual of :mod:`calibration.methods.topup_sigma`)."""

from __future__ import annotations

import numpy as np

from calibration.data.recording import Recording

#: Share of the anchors held out at each end of a joint's training range.
EDGE_SHARE = 0.15
#: The joints (0-based) whose edges are held out: the two the training design spans.
EDGE_JOINTS = (1, 2)
#: The joints (0-based) the design keeps near zero and steps within a cluster: holding their steps out leaves a fit
#: that never saw them move, as on a test recording that moves them by tens of degrees.
STEP_JOINTS = (0, 3, 4, 5)


def edge_mask(rec: Recording, joint: int, share: float = EDGE_SHARE, cluster_size: int = 7) -> np.ndarray:
    """Samples (N,) of the clusters whose anchor (first pose) of ``joint`` is among the lowest or highest
    ``share`` of the anchors."""
    cluster = rec.clusters(cluster_size)
    ids = np.unique(cluster)
    anchor = np.array([rec.q[np.flatnonzero(cluster == c)[0], joint] for c in ids])
    lo, hi = np.quantile(anchor, [share, 1.0 - share])
    edge = ids[(anchor <= lo) | (anchor >= hi)]
    return np.isin(cluster, edge)


def step_mask(rec: Recording, joints: tuple[int, ...] = STEP_JOINTS, cluster_size: int = 7) -> np.ndarray:
    """Samples (N,) that step ``joints`` away from their cluster's anchor by more than half the largest step of
    the recording (0524/0613/0620: the +-4 and +-6 deg steps, fitted on the anchors and the +-2 deg ones; the
    other days: every 1 deg step of those joints)."""
    cluster = rec.clusters(cluster_size)
    first = np.r_[0, np.flatnonzero(np.diff(cluster)) + 1]
    anchor = rec.q[first][np.searchsorted(first, np.arange(len(rec)), side="right") - 1]
    step = np.max(np.abs(rec.q[:, list(joints)] - anchor[:, list(joints)]), axis=1)
    return np.asarray(step > 0.5 * step.max(), dtype=bool)


