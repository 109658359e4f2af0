"""The anchors' support: convex-hull membership and nearest-anchor lookup, shared by every kind.

Every interpolator kind flags a query as out of range when it lies outside the convex hull of the
anchors (a Delaunay point-location test, with Qhull's default tolerance of 100 machine epsilons, so
anchors and points on the hull's edges count as inside). The hull is used for the smooth global kinds
(Fourier, MLP) too, rather than a bounding box: the anchor grid of a CDC campaign is not a rectangle
(the q3 range depends on q2), so a box would call the empty corners "in range" while every kind there
extrapolates. For d = 1 the hull is the interval [min, max].
"""

from __future__ import annotations

import numpy as np

from calibration.errors import ModelError
from calibration.kinematics.arrays import BoolArray, IntArray


class AnchorSupport:
    """Convex hull of the anchors and a k-d tree over them.

    Args:
        anchors: anchor configurations, shape (K, d), finite.
        unique: reject repeated anchors (needed by the kinds that pass through every anchor).

    Raises:
        ModelError: fewer than d + 1 anchors, anchors that span no d-dimensional volume, or repeated
            anchors when ``unique`` is set.
    """

    def __init__(self, anchors: np.ndarray, unique: bool = False) -> None:
        from scipy.spatial import Delaunay, QhullError, cKDTree

        self.anchors = anchors
        k, d = anchors.shape
        if unique and np.unique(anchors, axis=0).shape[0] != k:
            raise ModelError(f"anchors: {k - np.unique(anchors, axis=0).shape[0]} repeated anchor(s); "
                             "average the values of repeated configurations before fitting")
        if k < d + 1:
            raise ModelError(f"anchors: need at least d + 1 = {d + 1} anchors for {d} inputs, got {k}")
        self.tri = None
        if d == 1:
            self._lo, self._hi = float(anchors.min()), float(anchors.max())
            if self._lo == self._hi:
                raise ModelError("anchors: all anchors are the same point")
        else:
            try:
                self.tri = Delaunay(anchors)
            except QhullError as e:
                raise ModelError(f"anchors: the {k} anchors span no {d}-dimensional volume "
                                 "(all on a line or plane?); cannot triangulate") from e
        self._tree = cKDTree(anchors)

    def outside(self, x: np.ndarray) -> np.ndarray:
        """Whether each query is outside the anchors' convex hull.

        Args:
            x: queries, shape (N, d).

        Returns:
            Boolean mask, shape (N,).
        """
        if self.tri is None:
            return (x[:, 0] < self._lo) | (x[:, 0] > self._hi)
        outside: BoolArray = self.tri.find_simplex(x) < 0
        return outside

    def nearest(self, x: np.ndarray) -> np.ndarray:
        """Index of the nearest anchor (Euclidean in x) for each query, shape (N,) int."""
        if x.shape[0] == 0:
            return np.zeros(0, dtype=np.intp)
        index: IntArray = self._tree.query(x)[1]
        return index
