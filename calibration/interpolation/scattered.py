"""Local interpolants through the anchors: nearest anchor, piecewise linear and Clough-Tocher cubic.

All three pass exactly through the anchor values. Linear and cubic are defined on the Delaunay
triangulation of the anchors; outside its convex hull scipy would return NaN, so there they return the
nearest anchor's value instead, and ``out_of_range`` flags those queries.

``casadi_predict`` (exact, checked against ``predict``): nearest is an argmin chain over the anchors (``if_else``,
derivative zero), linear an ``if_else`` chain over the Delaunay simplices (barycentric weights from Qhull's own
transforms, the same inside tolerance as scipy's point location) ending in the nearest-anchor fallback, so
its size grows with the number of simplices times m. Cubic (Clough-Tocher: estimated gradients and a
split into three Bernstein sub-triangles per simplex) has no casadi form here and stays frozen.

Serialisation stores the anchors and values; loading rebuilds the triangulation (Qhull is deterministic
for the same input), so prediction after a round trip is bit-identical.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from calibration.errors import ModelError
from calibration.interpolation.base import Interpolator, array_field, from_options
from calibration.interpolation.support import AnchorSupport


class AnchoredInterpolator(Interpolator):
    """Base for the kinds whose whole state is the anchors, the values and a few options."""

    def __init__(self) -> None:
        super().__init__()
        self._anchors: np.ndarray | None = None
        self._values: np.ndarray | None = None
        self._support: AnchorSupport | None = None

    def out_of_range(self, x: np.ndarray) -> np.ndarray:
        """Whether each query (N, d) lies outside the anchors' convex hull; bool (N,)."""
        x = self._check_query(x)
        return self._hull().outside(x)

    def _fit(self, x: np.ndarray, y: np.ndarray) -> None:
        self._support = AnchorSupport(x, unique=True)
        self._anchors, self._values = x, y
        self._build()

    def _build(self) -> None:
        """Build the scipy object from ``self._anchors`` and ``self._values`` (fit and load)."""

    def _options(self) -> dict[str, Any]:
        """Constructor keyword arguments, stored with the arrays."""
        return {}

    def _state(self) -> dict[str, Any]:
        return {"options": self._options(), "anchors": self._anchors.tolist(),  # type: ignore[union-attr]
                "values": self._values.tolist()}  # type: ignore[union-attr]

    @classmethod
    def _from_state(cls, d: dict[str, Any]) -> Interpolator:
        obj = from_options(cls, d)
        obj._fit(array_field(d, "anchors", 2), array_field(d, "values", 2))
        return obj

    def _hull(self) -> AnchorSupport:
        if self._support is None:
            raise ModelError(f"{self.kind} interpolator is not fitted: call fit(x, y) or from_dict() first")
        return self._support

    def _nearest_values(self, x: np.ndarray) -> np.ndarray:
        return self._values[self._hull().nearest(x)]  # type: ignore[index]

    def _nearest_casadi(self, u: Any) -> Any:
        """The nearest anchor's values (m, 1) as casadi: a strict-< argmin chain (the first anchor wins ties)."""
        import casadi as ca

        self._require_fitted()
        A, V = self._anchors, self._values
        best_d, best_v = None, None
        for k in range(A.shape[0]):  # type: ignore[union-attr]
            dk = ca.sumsqr(u - ca.DM(A[k]))  # type: ignore[index]
            vk = ca.DM(V[k])  # type: ignore[index]
            if best_d is None:
                best_d, best_v = dk, vk
            else:
                closer = dk < best_d
                best_v = ca.if_else(closer, vk, best_v)
                best_d = ca.if_else(closer, dk, best_d)
        return best_v


class NearestInterpolator(AnchoredInterpolator):
    """Value of the nearest anchor (Euclidean distance in x); defined everywhere, flagged outside the hull."""

    kind: ClassVar[str] = "nearest"

    def _predict(self, x: np.ndarray) -> np.ndarray:
        return self._nearest_values(x)

    def casadi_predict(self, u: Any) -> Any:
        """The nearest anchor's values as casadi (piecewise constant: zero derivative)."""
        return self._nearest_casadi(u)


class _TriangulatedInterpolator(AnchoredInterpolator):
    """Piecewise interpolant on the anchors' Delaunay triangulation, nearest anchor outside the hull."""

    def __init__(self) -> None:
        super().__init__()
        self._interp: Any = None

    def _predict(self, x: np.ndarray) -> np.ndarray:
        out = self._interp(x)
        # Same point location as scipy's, plus any NaN scipy produced on the hull boundary.
        fill = self._hull().outside(x) | np.isnan(out).any(axis=1)
        if fill.any():
            out[fill] = self._nearest_values(x[fill])
        return out


class LinearInterpolator(_TriangulatedInterpolator):
    """Piecewise-linear (barycentric) interpolation on the Delaunay triangulation; any d >= 2."""

    kind: ClassVar[str] = "linear"

    def _check_dim(self, d: int) -> None:
        if d < 2:
            raise ModelError(f"{self.kind}: needs x with at least 2 columns, got {d}; use 'nearest' or "
                             "'rbf' for one input")

    def _build(self) -> None:
        from scipy.interpolate import LinearNDInterpolator

        self._interp = LinearNDInterpolator(self._hull().tri, self._values)

    def casadi_predict(self, u: Any) -> Any:
        """Barycentric interpolation in the simplex containing u, else the nearest anchor's values, as casadi."""
        import casadi as ca

        self._require_fitted()
        tri = self._hull().tri
        eps = 100 * np.finfo(float).eps  # scipy's find_simplex tolerance on the barycentric coordinates
        d = self.n_inputs
        out = self._nearest_casadi(u)
        for s in reversed(range(tri.nsimplex)):
            T = tri.transform[s]
            if not np.all(np.isfinite(T)):
                continue  # a degenerate simplex scipy never locates a point in
            c = ca.mtimes(ca.DM(T[:d]), u - ca.DM(T[d]))
            bary = ca.vertcat(c, 1 - ca.sum1(c))
            inside = bary[0] >= -eps
            for j in range(1, d + 1):
                inside = ca.logic_and(inside, bary[j] >= -eps)
            value = ca.mtimes(ca.DM(self._values[tri.simplices[s]].T), bary)  # type: ignore[index]
            out = ca.if_else(inside, value, out)
        return out


class CubicInterpolator(_TriangulatedInterpolator):
    """Clough-Tocher C1 piecewise-cubic interpolation on the Delaunay triangulation; d = 2 only."""

    kind: ClassVar[str] = "cubic"
    input_dim: ClassVar[int | None] = 2

    def _build(self) -> None:
        from scipy.interpolate import CloughTocher2DInterpolator

        self._interp = CloughTocher2DInterpolator(self._hull().tri, self._values)
