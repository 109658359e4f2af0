"""Local interpolants through the anchors: nearest anchor, piecewise linear and Clough-Tocher cubic.

All three pass exactly through the anchor values. Linear and cubic are defined on the Delaunay
triangulation of the anchors; outside its convex hull scipy would return NaN, so there they return the
nearest anchor's value instead, and ``out_of_range`` flags those queries.

``casadi_predict`` (exact, checked against ``predict``): nearest is an argmin chain over the anchors (``if_else``,
derivative zero), linear an ``if_else`` chain over the Delaunay simplices (barycentric weights from Qhull's own
transforms, the same inside tolerance as scipy's point location) ending in the nearest-anchor fallback, so
its size grows with the number of simplices times m. Cubic is the same chain over simplices, each with
scipy's Clough-Tocher cubic: its 19 Bernstein coefficients per simplex (from the values, scipy's estimated
gradients ``grad`` and the neighbours' centroids, as scipy's ``_clough_tocher_2d_single``) are computed
once with numpy, and the query enters only through its extended barycentric coordinates (the min of the
three picks the sub-triangle).

Serialisation stores the anchors and values; loading rebuilds the triangulation (Qhull is deterministic
for the same input), so prediction after a round trip is bit-identical.
"""

from __future__ import annotations

from typing import Any, ClassVar, Self

import numpy as np

from calibration.errors import ModelError
from calibration.interpolation.base import Interpolator, array_field, from_options
from calibration.interpolation.support import AnchorSupport
from calibration.kinematics.arrays import FloatArray


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
        return {"options": self._options(), "anchors": self._fitted(self._anchors).tolist(),
                "values": self._fitted(self._values).tolist()}

    @classmethod
    def _from_state(cls, d: dict[str, Any]) -> Self:
        obj = from_options(cls, d)
        obj._fit(array_field(d, "anchors", 2), array_field(d, "values", 2))
        return obj

    def _hull(self) -> AnchorSupport:
        if self._support is None:
            raise ModelError(f"{self.kind} interpolator is not fitted: call fit(x, y) or from_dict() first")
        return self._support

    def _nearest_values(self, x: np.ndarray) -> np.ndarray:
        values: FloatArray = self._fitted(self._values)[self._hull().nearest(x)]
        return values

    def _nearest_casadi(self, u: Any) -> Any:
        """The nearest anchor's values (m, 1) as casadi: a strict-< argmin chain (the first anchor wins ties)."""
        import casadi as ca

        self._require_fitted()
        A, V = self._fitted(self._anchors), self._fitted(self._values)
        best_d: Any = None  # casadi expressions, once the first anchor is seen
        best_v: Any = None
        for k in range(A.shape[0]):
            dk = ca.sumsqr(u - ca.DM(A[k]))
            vk = ca.DM(V[k])
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
        out: FloatArray = self._interp(x)  # scipy's LinearND/CloughTocher2D interpolator (N, m)
        # Same point location as scipy's, plus any NaN scipy produced on the hull boundary.
        fill = self._hull().outside(x) | np.isnan(out).any(axis=1)
        if fill.any():
            out[fill] = self._nearest_values(x[fill])
        return out

    def _triangulation(self) -> Any:
        """The anchors' Delaunay triangulation (scipy's): these kinds need d >= 2, where the support has one."""
        tri = self._hull().tri
        if tri is None:
            raise ModelError(f"{self.kind}: needs x with at least 2 columns; the anchors have no triangulation")
        return tri


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
        tri, V = self._triangulation(), self._fitted(self._values)
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
            value = ca.mtimes(ca.DM(V[tri.simplices[s]].T), bary)
            out = ca.if_else(inside, value, out)
        return out


class CubicInterpolator(_TriangulatedInterpolator):
    """Clough-Tocher C1 piecewise-cubic interpolation on the Delaunay triangulation; d = 2 only."""

    kind: ClassVar[str] = "cubic"
    input_dim: ClassVar[int | None] = 2

    def _build(self) -> None:
        from scipy.interpolate import CloughTocher2DInterpolator

        self._interp = CloughTocher2DInterpolator(self._hull().tri, self._values)

    def casadi_predict(self, u: Any) -> Any:
        """scipy's Clough-Tocher cubic in the simplex containing u, else the nearest anchor's values, as casadi."""
        import casadi as ca

        self._require_fitted()
        tri = self._triangulation()
        eps = 100 * np.finfo(float).eps
        coeffs = _clough_tocher_coefficients(tri, self._interp.values, self._interp.grad)  # (T, m, 19)
        out = self._nearest_casadi(u)
        for s in reversed(range(tri.nsimplex)):
            T = tri.transform[s]
            if not np.all(np.isfinite(T)):
                continue
            c = ca.mtimes(ca.DM(T[:2]), u - ca.DM(T[2]))
            b = [c[0], c[1], 1 - c[0] - c[1]]
            inside = ca.logic_and(ca.logic_and(b[0] >= -eps, b[1] >= -eps), b[2] >= -eps)
            mn = ca.fmin(ca.fmin(b[0], b[1]), b[2])
            b1, b2, b3, b4 = b[0] - mn, b[1] - mn, b[2] - mn, 3 * mn
            mono = ca.vertcat(b1**3, 3*b1**2*b2, 3*b1**2*b3, 3*b1**2*b4, 3*b1*b2**2, 6*b1*b2*b4, 3*b1*b3**2,
                              6*b1*b3*b4, 3*b1*b4**2, b2**3, 3*b2**2*b3, 3*b2**2*b4, 3*b2*b3**2, 6*b2*b3*b4,
                              3*b2*b4**2, b3**3, 3*b3**2*b4, 3*b3*b4**2, b4**3)
            out = ca.if_else(inside, ca.mtimes(ca.DM(coeffs[s]), mono), out)
        return out


def _clough_tocher_coefficients(tri: Any, values: np.ndarray, grad: np.ndarray) -> np.ndarray:
    """Bernstein coefficients (T, m, 19) of scipy's Clough-Tocher cubic on every simplex, in the monomial order
    of :meth:`CubicInterpolator.casadi_predict` (c3000, c2100, c2010, c2001, c1200, c1101, c1020, c1011, c1002,
    c0300, c0210, c0201, c0120, c0111, c0102, c0030, c0021, c0012, c0003); scipy's formulas, vectorised."""
    P, S = tri.points, tri.simplices
    out = np.empty((tri.nsimplex, values.shape[1], 19))
    for s in range(tri.nsimplex):
        v = S[s]
        e12, e23, e31 = P[v[1]] - P[v[0]], P[v[2]] - P[v[1]], P[v[0]] - P[v[2]]
        f1, f2, f3 = values[v[0]], values[v[1]], values[v[2]]
        g1, g2, g3 = grad[v[0]], grad[v[1]], grad[v[2]]  # (m, 2)
        df12, df21 = g1 @ e12, -(g2 @ e12)
        df23, df32 = g2 @ e23, -(g3 @ e23)
        df31, df13 = g3 @ e31, -(g1 @ e31)
        c3000, c2100, c2010 = f1, (df12 + 3 * f1) / 3, (df13 + 3 * f1) / 3
        c0300, c1200, c0210 = f2, (df21 + 3 * f2) / 3, (df23 + 3 * f2) / 3
        c0030, c1020, c0120 = f3, (df31 + 3 * f3) / 3, (df32 + 3 * f3) / 3
        c2001 = (c2100 + c2010 + c3000) / 3
        c0201 = (c1200 + c0300 + c0210) / 3
        c0021 = (c1020 + c0120 + c0030) / 3
        g = np.empty(3)
        T = tri.transform[s]
        for k in range(3):
            n = tri.neighbors[s, k]
            if n == -1:
                g[k] = -0.5
                continue
            y = P[S[n]].sum(axis=0) / 3  # scipy: (a + b + c) / 3 per coordinate
            c = np.empty(3)
            c[0] = T[0, 0] * (y[0] - T[2, 0]) + T[0, 1] * (y[1] - T[2, 1])
            c[1] = T[1, 0] * (y[0] - T[2, 0]) + T[1, 1] * (y[1] - T[2, 1])
            c[2] = 1.0 - c[0] - c[1]
            if k == 0:
                g[k] = (2 * c[2] + c[1] - 1) / (2 - 3 * c[2] - 3 * c[1])
            elif k == 1:
                g[k] = (2 * c[0] + c[2] - 1) / (2 - 3 * c[0] - 3 * c[2])
            else:
                g[k] = (2 * c[1] + c[0] - 1) / (2 - 3 * c[1] - 3 * c[0])
        c0111 = (g[0] * (-c0300 + 3 * c0210 - 3 * c0120 + c0030) + (-c0300 + 2 * c0210 - c0120 + c0021 + c0201)) / 2
        c1011 = (g[1] * (-c0030 + 3 * c1020 - 3 * c2010 + c3000) + (-c0030 + 2 * c1020 - c2010 + c2001 + c0021)) / 2
        c1101 = (g[2] * (-c3000 + 3 * c2100 - 3 * c1200 + c0300) + (-c3000 + 2 * c2100 - c1200 + c2001 + c0201)) / 2
        c1002 = (c1101 + c1011 + c2001) / 3
        c0102 = (c1101 + c0111 + c0201) / 3
        c0012 = (c1011 + c0111 + c0021) / 3
        c0003 = (c1002 + c0102 + c0012) / 3
        out[s] = np.stack([c3000, c2100, c2010, c2001, c1200, c1101, c1020, c1011, c1002, c0300, c0210, c0201,
                           c0120, c0111, c0102, c0030, c0021, c0012, c0003], axis=1)
    return out
