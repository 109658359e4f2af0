"""Fourier basis functions (FBF) in the shoulder/elbow angles (q2, q3), full (13 terms) and SVD-reduced.

The 13-term basis of the CDC paper, in the column order of ``FBF13_TERMS``::

    b(q2, q3) = [sin q2, sin q3, cos q2, cos q3, sin(q2+q3), cos(q2+q3),            (a = 1)
                 sin 2q2, sin 2q3, cos 2q2, cos 2q3, sin 2(q2+q3), cos 2(q2+q3),    (a = 2)
                 1]

The values are modelled as ``y(x) = A b(x)`` with the coefficient matrix A, shape (m, 13), fitted by least
squares (pseudo-inverse) over the anchors. The reduced kind takes the SVD ``A = U S V^T``, keeps the top
``rank`` right singular vectors ``V_r`` (13, r) as new basis functions ``V_r^T b(x)`` and refits
coefficients C, shape (m, r), by least squares on them.

With sparse anchors the plain least squares over 13 terms is nearly interpolating and oscillates between
the anchors (on 16 clusters of the 0801 recording fbf13 reached a 3.8 mm max on the test poses); a ridge > 0
on the 12 non-constant coefficients (relative to the basis Gram matrix's mean diagonal) shrinks the fit toward
the anchors' mean and makes the problem well-posed with fewer than 13 anchors. The Fitter chooses the strength on
held-out training clusters (:func:`calibration.methods.cdc_fit._choose_strength`), never on a test recording.

Both are global smooth fits: they are exact only when the values lie in the span of the basis, and they
extrapolate outside the anchors' convex hull, where ``out_of_range`` flags queries (see ``support``).
Serialisation stores the coefficient arrays themselves, so prediction after a round trip is bit-identical.
``casadi_predict(u)`` gives the same prediction as a casadi expression of symbolic (q2, q3), so planners
get exact derivatives of the parameters with respect to the joints (casadi is imported only there).
"""

from __future__ import annotations

import abc
from typing import Any, ClassVar, Self

import numpy as np

from calibration.errors import ModelError
from calibration.interpolation.base import Interpolator, array_field, as_matrix, from_options
from calibration.interpolation.support import AnchorSupport
from calibration.kinematics.arrays import FloatArray

#: Names of the 13 basis functions, in column order (labels for the singular-vector heat map).
FBF13_TERMS = ("sin q2", "sin q3", "cos q2", "cos q3", "sin(q2+q3)", "cos(q2+q3)",
               "sin 2q2", "sin 2q3", "cos 2q2", "cos 2q3", "sin 2(q2+q3)", "cos 2(q2+q3)", "1")


def fbf13_basis(x: np.ndarray) -> np.ndarray:
    """The 13 Fourier basis functions at each configuration.

    Args:
        x: configurations (q2, q3) [rad], shape (N, 2).

    Returns:
        Basis matrix, shape (N, 13), columns ordered as ``FBF13_TERMS``.
    """
    x = as_matrix(x, "x", allow_empty=True)
    if x.shape[1] != 2:
        raise ModelError(f"fbf13 basis: needs x with 2 columns (q2, q3) [rad], got {x.shape[1]}")
    q2, q3 = x[:, 0], x[:, 1]
    cols = []
    for a in (1.0, 2.0):
        cols += [np.sin(a * q2), np.sin(a * q3), np.cos(a * q2), np.cos(a * q3),
                 np.sin(a * (q2 + q3)), np.cos(a * (q2 + q3))]
    cols.append(np.ones_like(q2))
    return np.stack(cols, axis=1)


def fbf13_basis_casadi(u: Any) -> Any:
    """The 13 Fourier basis functions of one symbolic configuration.

    Args:
        u: casadi SX/MX (or DM) 2-vector (q2, q3) [rad].

    Returns:
        casadi column (13, 1), terms ordered as ``FBF13_TERMS``.

    Raises:
        ModelError: u does not have 2 entries.
    """
    import casadi as ca

    if u.numel() != 2:
        raise ModelError(f"fbf13 basis: needs u with 2 entries (q2, q3) [rad], got {u.numel()}")
    q2, q3 = u[0], u[1]
    terms = []
    for a in (1.0, 2.0):
        terms += [ca.sin(a * q2), ca.sin(a * q3), ca.cos(a * q2), ca.cos(a * q3),
                  ca.sin(a * (q2 + q3)), ca.cos(a * (q2 + q3))]
    terms.append(1.0)
    return ca.vertcat(*terms)


class _FourierBase(Interpolator):
    """Shared parts: d = 2, the anchors' hull for ``out_of_range``, the 13-term basis."""

    input_dim: ClassVar[int | None] = 2

    def __init__(self) -> None:
        super().__init__()
        self.ridge = 0.0  # set by the kinds; > 0 lets fewer than 13 anchors be fitted
        self._anchors: np.ndarray | None = None
        self._support: AnchorSupport | None = None

    def basis(self, x: np.ndarray) -> np.ndarray:
        """The 13 Fourier basis functions, shape (N, 13), at configurations x (N, 2) [rad]."""
        return fbf13_basis(x)

    def out_of_range(self, x: np.ndarray) -> np.ndarray:
        """Whether each query (N, 2) lies outside the anchors' convex hull; bool (N,)."""
        x = self._check_query(x)
        return self._fitted(self._support).outside(x)

    def casadi_predict(self, u: Any) -> Any:
        """The prediction as a casadi expression: ``M b(u)`` with M the (m, 13) map from the 13-term basis.

        Args:
            u: casadi SX/MX 2-vector (q2, q3) [rad].

        Returns:
            casadi column (m, 1) of the interpolated values, equal to ``predict`` at numeric u.
        """
        import casadi as ca

        self._require_fitted()
        return ca.mtimes(ca.DM(self._basis_map()), fbf13_basis_casadi(u))

    @abc.abstractmethod
    def _basis_map(self) -> np.ndarray:
        """The (m, 13) matrix taking the 13-term basis to the outputs."""

    def _set_anchors(self, x: np.ndarray) -> None:
        if x.shape[0] < 13 and not self.ridge > 0.0:
            raise ModelError(f"{self.kind}: needs at least 13 anchors for 13 basis functions with ridge = 0, got "
                             f"{x.shape[0]}; a ridge > 0 makes fewer anchors well-posed")
        self._support = AnchorSupport(x)
        self._anchors = x


def _ridge_solve(b: np.ndarray, y: np.ndarray, ridge: float) -> np.ndarray:
    """Coefficients (m, n) of ``y ~ b c``: least squares (pseudo-inverse) for ridge = 0, else ridge regression
    with penalty ``ridge * mean(diag(b^T b))`` on every column but a constant one (the mean is not shrunk)."""
    if ridge == 0.0:
        A: FloatArray = (np.linalg.pinv(b) @ y).T
        return A
    gram = b.T @ b
    const = np.all(np.isclose(b, b[:1]), axis=0)
    penalty = ridge * float(np.mean(np.diag(gram))) * np.diag(~const).astype(float)
    return np.linalg.solve(gram + penalty, b.T @ y).T


def _check_ridge(kind: str, ridge: float) -> float:
    if isinstance(ridge, bool) or not isinstance(ridge, (int, float, np.floating)) or not (
            np.isfinite(ridge) and ridge >= 0.0):
        raise ModelError(f"{kind}: ridge must be a finite number >= 0, got {ridge!r}")
    return float(ridge)


class Fourier13Interpolator(_FourierBase):
    """Least-squares fit of the 13-term Fourier basis: ``y(x) = A b(x)``, A shape (m, 13).

    Args:
        ridge: ridge strength on the 12 non-constant coefficients, relative to the mean diagonal of the basis
            Gram matrix (0 = the paper's plain least squares).
    """

    kind: ClassVar[str] = "fbf13"

    def __init__(self, ridge: float = 0.0) -> None:
        super().__init__()
        self.ridge = _check_ridge(self.kind, ridge)
        self._A: np.ndarray | None = None

    @property
    def coefficients(self) -> np.ndarray:
        """Coefficient matrix A, shape (m, 13) (rows: outputs, columns: ``FBF13_TERMS``)."""
        self._require_fitted()
        return self._fitted(self._A).copy()

    def singular_values(self) -> np.ndarray:
        """Singular values of A, descending, shape (min(m, 13),)."""
        return np.linalg.svd(self.coefficients, compute_uv=False)

    def right_singular_vectors(self) -> np.ndarray:
        """V of ``A = U S V^T``, shape (13, 13): column j is the j-th right singular vector, row i is
        basis term ``FBF13_TERMS[i]``. Columns beyond min(m, 13) span the null space of A."""
        return np.linalg.svd(self.coefficients, full_matrices=True)[2].T

    def _fit(self, x: np.ndarray, y: np.ndarray) -> None:
        self._set_anchors(x)
        self._A = _ridge_solve(fbf13_basis(x), y, self.ridge)

    def _basis_map(self) -> np.ndarray:
        return self._fitted(self._A)

    def _predict(self, x: np.ndarray) -> np.ndarray:
        y: FloatArray = fbf13_basis(x) @ self._fitted(self._A).T
        return y

    def _state(self) -> dict[str, Any]:
        return {"options": {"ridge": self.ridge}, "anchors": self._fitted(self._anchors).tolist(),
                "coefficients": self._fitted(self._A).tolist()}

    @classmethod
    def _from_state(cls, d: dict[str, Any]) -> Self:
        obj = from_options(cls, d)
        obj._set_anchors(array_field(d, "anchors", 2))
        obj._A = _checked(d, "coefficients", (None, 13))
        return obj


class FourierReducedInterpolator(_FourierBase):
    """SVD-reduced Fourier basis: ``y(x) = C V_r^T b(x)``, C shape (m, r), V_r shape (13, r).

    Args:
        rank: number r of reduced basis functions kept, 1..13 (the paper uses 7).
        ridge: ridge strength of both least-squares fits (as ``fbf13``'s; 0 = the paper's).
    """

    kind: ClassVar[str] = "fbf7"

    def __init__(self, rank: int = 7, ridge: float = 0.0) -> None:
        super().__init__()
        self.ridge = _check_ridge(self.kind, ridge)
        if isinstance(rank, bool) or not isinstance(rank, (int, np.integer)) or not 1 <= rank <= 13:
            raise ModelError(f"{self.kind}: rank must be an int in 1..13, got {rank!r}")
        self.rank = int(rank)
        self._V: np.ndarray | None = None
        self._C: np.ndarray | None = None

    @property
    def reduced_basis(self) -> np.ndarray:
        """V_r, shape (13, r): column j holds the weights of reduced basis function j on ``FBF13_TERMS``."""
        self._require_fitted()
        return self._fitted(self._V).copy()

    @property
    def coefficients(self) -> np.ndarray:
        """Coefficients C on the reduced basis, shape (m, r)."""
        self._require_fitted()
        return self._fitted(self._C).copy()

    def _fit(self, x: np.ndarray, y: np.ndarray) -> None:
        self._set_anchors(x)
        b = fbf13_basis(x)
        A = _ridge_solve(b, y, self.ridge)
        V = np.linalg.svd(A, full_matrices=True)[2].T  # (13, 13), columns by decreasing singular value
        self._V = np.ascontiguousarray(V[:, :self.rank])
        self._C = _ridge_solve(b @ self._V, y, self.ridge)

    def _predict(self, x: np.ndarray) -> np.ndarray:
        y: FloatArray = (fbf13_basis(x) @ self._fitted(self._V)) @ self._fitted(self._C).T
        return y

    def _basis_map(self) -> np.ndarray:
        M: FloatArray = self._fitted(self._C) @ self._fitted(self._V).T
        return M

    def _state(self) -> dict[str, Any]:
        return {"options": {"rank": self.rank, "ridge": self.ridge}, "anchors": self._fitted(self._anchors).tolist(),
                "reduced_basis": self._fitted(self._V).tolist(), "coefficients": self._fitted(self._C).tolist()}

    @classmethod
    def _from_state(cls, d: dict[str, Any]) -> Self:
        obj = from_options(cls, d)
        obj._set_anchors(array_field(d, "anchors", 2))
        obj._V = _checked(d, "reduced_basis", (13, obj.rank))
        obj._C = _checked(d, "coefficients", (None, obj.rank))
        return obj


def _checked(d: dict[str, Any], key: str, shape: tuple[int | None, int]) -> np.ndarray:
    arr = array_field(d, key, 2)
    if any(s is not None and s != a for s, a in zip(shape, arr.shape)):
        raise ModelError(f"{d.get('kind')} dict: {key!r} has shape {arr.shape}, expected "
                         f"{tuple('m' if s is None else s for s in shape)}")
    return arr
