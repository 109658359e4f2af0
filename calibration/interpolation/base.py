"""The interpolator interface shared by every kind, and the checks and (de)serialisation helpers they use.

An interpolator maps a configuration ``x`` (d inputs, in practice the shoulder/elbow angles (q2, q3)
[rad]) to a value vector ``y`` (m outputs, in practice the 24 kinematic-error parameters identified at a
cluster anchor). It is fitted once on K anchors, then predicts for any number of queries in one
vectorised call, and serialises to a JSON/YAML-safe dict from which it predicts bit-identically.
"""

from __future__ import annotations

import abc
import logging
from typing import Any, ClassVar, Self, TypeVar

import numpy as np

from calibration.errors import ModelError

logger = logging.getLogger("cellcal.calibration")

#: Version of the dict layout written by ``to_dict``; bumped on incompatible changes.
FORMAT_VERSION = 1

_T = TypeVar("_T")


class Interpolator(abc.ABC):
    """Interpolate per-anchor value vectors over the configuration space.

    Subclasses set ``kind`` (the name used by ``make_interpolator`` and stored in ``to_dict``) and
    implement ``_fit``, ``_predict``, ``out_of_range``, ``_state`` and ``_from_state``; this base class
    validates shapes and dtypes so every kind rejects bad input with the same messages.
    """

    kind: ClassVar[str]
    #: Required input dimension, or None when any d >= 1 works.
    input_dim: ClassVar[int | None] = None

    def __init__(self) -> None:
        self._d: int | None = None
        self._m: int | None = None

    # -- public API -------------------------------------------------------------------------------

    @property
    def is_fitted(self) -> bool:
        """Whether ``fit`` (or ``from_dict``) has run."""
        return self._d is not None

    @property
    def n_inputs(self) -> int:
        """Input dimension d (the anchors' columns)."""
        return self._dims()[0]

    @property
    def n_outputs(self) -> int:
        """Output dimension m (the values' columns)."""
        return self._dims()[1]

    def fit(self, x: np.ndarray, y: np.ndarray) -> Self:
        """Fit on the anchors.

        Args:
            x: anchor configurations, shape (K, d) (e.g. (q2, q3) [rad]).
            y: values at the anchors, shape (K, m) (e.g. 24 kinematic-error parameters).

        Returns:
            self, fitted.

        Raises:
            ModelError: shapes do not match, values are not finite, or d is wrong for this kind.
        """
        x = as_matrix(x, "x")
        y = as_matrix(y, "y")
        if x.shape[0] != y.shape[0]:
            raise ModelError(f"{self.kind}: x has {x.shape[0]} anchors but y has {y.shape[0]} rows; "
                             "they must match (x: (K, d), y: (K, m))")
        self._check_dim(x.shape[1])
        self._fit(x, y)
        self._d, self._m = x.shape[1], y.shape[1]
        logger.debug("fitted %s interpolator: K=%d, d=%d, m=%d", self.kind, *x.shape, y.shape[1])
        return self

    def predict(self, x: np.ndarray) -> np.ndarray:
        """Interpolated values at the queries.

        Args:
            x: query configurations, shape (N, d).

        Returns:
            Values, shape (N, m); always finite (outside the support each kind falls back as documented).
        """
        x = self._check_query(x)
        return self._predict(x)

    def casadi_predict(self, u: Any) -> Any:
        """The prediction as a casadi expression of one symbolic query, equal to ``predict`` at numeric u.

        Args:
            u: casadi SX column (d,) (e.g. symbolic (q2, q3) [rad]).

        Returns:
            casadi column (m, 1).

        Raises:
            ModelError: this kind has no exact casadi form (the default; callers then freeze the values).
        """
        raise ModelError(f"{self.kind}: no exact casadi form of this interpolator kind "
                         "(its values must be frozen at an iterate)")

    @abc.abstractmethod
    def out_of_range(self, x: np.ndarray) -> np.ndarray:
        """Whether each query lies outside the anchors' support.

        Args:
            x: query configurations, shape (N, d).

        Returns:
            Boolean mask, shape (N,).
        """

    def to_dict(self) -> dict[str, Any]:
        """JSON/YAML-safe description (str, int, float and nested lists only) of the fitted interpolator."""
        self._require_fitted()
        return {"kind": self.kind, "version": FORMAT_VERSION, "n_inputs": self._d, "n_outputs": self._m,
                **self._state()}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Self:
        """Rebuild an interpolator written by ``to_dict``; it predicts bit-identically.

        Raises:
            ModelError: wrong kind, unknown version or missing/malformed entries.
        """
        if not isinstance(d, dict):
            raise ModelError(f"{cls.kind}: expected a dict from to_dict(), got {type(d).__name__}")
        if d.get("kind") != cls.kind:
            raise ModelError(f"{cls.__name__}.from_dict: kind is {d.get('kind')!r}, expected {cls.kind!r}")
        if d.get("version") != FORMAT_VERSION:
            raise ModelError(f"{cls.kind}: unsupported format version {d.get('version')!r}; "
                             f"this cellcal reads version {FORMAT_VERSION}")
        obj = cls._from_state(d)
        obj._d, obj._m = int(field(d, "n_inputs")), int(field(d, "n_outputs"))
        return obj

    # -- for subclasses ---------------------------------------------------------------------------

    @abc.abstractmethod
    def _fit(self, x: np.ndarray, y: np.ndarray) -> None:
        """Fit on validated float arrays x (K, d), y (K, m)."""

    @abc.abstractmethod
    def _predict(self, x: np.ndarray) -> np.ndarray:
        """Predict on a validated query array (N, d)."""

    @abc.abstractmethod
    def _state(self) -> dict[str, Any]:
        """Options and fitted arrays (as lists) that prediction needs."""

    @classmethod
    @abc.abstractmethod
    def _from_state(cls, d: dict[str, Any]) -> Self:
        """Rebuild from the dict written by ``_state`` (plus the base keys)."""

    def _require_fitted(self) -> None:
        self._dims()

    def _fitted(self, value: _T | None) -> _T:
        """``value``, a part of the fitted state (None before ``fit``), or ModelError when not fitted."""
        if value is None:
            raise ModelError(f"{self.kind} interpolator is not fitted: call fit(x, y) or from_dict() first")
        return value

    def _dims(self) -> tuple[int, int]:
        if self._d is None or self._m is None:
            raise ModelError(f"{self.kind} interpolator is not fitted: call fit(x, y) or from_dict() first")
        return self._d, self._m

    def _check_dim(self, d: int) -> None:
        if self.input_dim is not None and d != self.input_dim:
            raise ModelError(f"{self.kind}: needs x with {self.input_dim} columns (q2, q3) [rad], got {d}")

    def _check_query(self, x: np.ndarray) -> np.ndarray:
        self._require_fitted()
        x = as_matrix(x, "x", allow_empty=True)
        if x.shape[1] != self._d:
            raise ModelError(f"{self.kind}: query x has {x.shape[1]} columns, the anchors had {self._d}")
        return x


InterpolatorT = TypeVar("InterpolatorT", bound=Interpolator)


def as_matrix(a: Any, name: str, allow_empty: bool = False) -> np.ndarray:
    """A finite float64 array of shape (rows, cols), or ModelError naming the expected shape."""
    try:
        arr = np.asarray(a, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise ModelError(f"{name}: expected a numeric array of shape (rows, columns)") from e
    if arr.ndim != 2:
        raise ModelError(f"{name}: expected shape (rows, columns), got shape {arr.shape}; "
                         "reshape a single column with a[:, None]")
    if arr.shape[1] == 0 or (arr.shape[0] == 0 and not allow_empty):
        raise ModelError(f"{name}: empty array of shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ModelError(f"{name}: contains NaN or infinite entries")
    return arr


def from_options(cls: type[InterpolatorT], d: dict[str, Any]) -> InterpolatorT:
    """``cls(**d["options"])`` (empty options when absent), or ModelError for a malformed mapping."""
    options = d.get("options", {})
    if not isinstance(options, dict):
        raise ModelError(f"{cls.kind} dict: 'options' must be a mapping, got {type(options).__name__}")
    try:
        return cls(**options)
    except TypeError as e:
        raise ModelError(f"{cls.kind} dict: bad 'options' {sorted(options)}: {e}") from e


def field(d: dict[str, Any], key: str) -> Any:
    """``d[key]`` or ModelError naming the missing key."""
    try:
        return d[key]
    except KeyError:
        raise ModelError(f"{d.get('kind', 'interpolator')} dict: missing key {key!r}") from None


def array_field(d: dict[str, Any], key: str, ndim: int) -> np.ndarray:
    """``d[key]`` as a float64 array with ``ndim`` dimensions, or ModelError."""
    try:
        arr = np.asarray(field(d, key), dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise ModelError(f"{d.get('kind')} dict: {key!r} is not a numeric array") from e
    if arr.ndim != ndim:
        raise ModelError(f"{d.get('kind')} dict: {key!r} must have {ndim} dimensions, got shape {arr.shape}")
    return arr


def check_choice(kind: str, option: str, value: Any, choices: tuple[Any, ...]) -> None:
    """ModelError naming the valid choices when ``value`` is not one of them."""
    if value not in choices:
        raise ModelError(f"{kind}: unknown {option} {value!r}; valid choices: {', '.join(map(str, choices))}")
