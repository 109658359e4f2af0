"""Autoencoder interpolation (``ae``): interpolate the anchors' latent codes, then decode.

1. Standardise the anchor values y (K, m) per column.
2. Train a ReLU autoencoder ``y -> y`` with Adam (scikit-learn ``MLPRegressor``, fixed seed): encoder
   ``hidden`` widths (default 3 x 200), a bottleneck of ``latent`` units (default 6), decoder with the
   mirrored widths, identity output.
3. Split the trained net at the bottleneck. The latent code of an anchor is the bottleneck's
   *pre-activation* z (K, latent); the decoder starts with the ReLU that the trained net applies there,
   so ``decode(z)`` reproduces the trained net exactly at the anchors, while the interpolated codes keep
   the information that a ReLU would clip (scikit-learn has no per-layer activation, hence this split).
4. Interpolate the codes piecewise-linearly over x (the ``linear`` kind: Delaunay triangulation of the
   anchors; outside the convex hull the nearest anchor's code, flagged by ``out_of_range``) and decode.

So outside the hull the value is the autoencoder's reconstruction of the nearest anchor's value (equal
to that value up to the reconstruction error). Only the latent interpolator, the decoder weights and
the output scaler are stored; prediction is a numpy forward pass, bit-identical after a round trip.
``casadi_predict`` chains the linear kind's casadi form of the codes and the decoder's forward pass.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, ClassVar, Self

import numpy as np

from calibration.errors import ModelError
from calibration.interpolation.base import Interpolator, field, from_options
from calibration.interpolation.mlp import (
    DEFAULT_PRECISION,
    EpochCallback,
    Standardiser,
    check_precision,
    check_training_options,
    forward,
    forward_casadi,
    layers_from_dict,
    layers_to_dict,
    scale_casadi,
    stored_precision,
    train_mlp,
)
from calibration.interpolation.scattered import LinearInterpolator

#: The paper's encoder widths (three hidden layers of 200, the decoder mirrored; the default here).
PAPER_HIDDEN = (200, 200, 200)


class AutoencoderInterpolator(Interpolator):
    """Linear interpolation of autoencoder latent codes over x, decoded to values.

    Args:
        latent: bottleneck size (latent code dimension), >= 1.
        hidden: encoder hidden widths; the decoder mirrors them.
        max_iter: training epochs (always run in full; no early stopping).
        learning_rate: Adam step size.
        alpha: L2 weight penalty.
        random_state: seed; the same seed and data give the same network.
        progress: called as ``progress(epoch, max_iter)`` after each training epoch; not part of the model
            (not saved), no effect on the result.
        precision: arithmetic of the training (``calibration.interpolation.mlp.PRECISIONS``); prediction is
            float64 either way.
    """

    kind: ClassVar[str] = "ae"

    def __init__(self, latent: int = 6, hidden: Sequence[int] = PAPER_HIDDEN, max_iter: int = 300,
                 learning_rate: float = 1e-3, alpha: float = 1e-4, random_state: int = 0,
                 progress: EpochCallback | None = None, precision: str = DEFAULT_PRECISION) -> None:
        super().__init__()
        self.progress = progress
        self.precision = check_precision(self.kind, precision)
        if isinstance(latent, bool) or not isinstance(latent, (int, np.integer)) or latent < 1:
            raise ModelError(f"{self.kind}: latent must be a positive int, got {latent!r}")
        self.latent = int(latent)
        self.hidden = check_training_options(self.kind, hidden, max_iter, learning_rate, alpha)
        self.max_iter, self.learning_rate, self.alpha = int(max_iter), float(learning_rate), float(alpha)
        self.random_state = int(random_state)
        self._codes: LinearInterpolator | None = None
        self._ys: Standardiser | None = None
        self._w: list[np.ndarray] = []
        self._b: list[np.ndarray] = []

    def decode(self, z: np.ndarray) -> np.ndarray:
        """Values, shape (N, m), decoded from latent codes z, shape (N, latent)."""
        self._require_fitted()
        z = np.asarray(z, dtype=np.float64)
        if z.ndim != 2 or z.shape[1] != self.latent:
            raise ModelError(f"{self.kind}: latent codes must have shape (N, {self.latent}), got {z.shape}")
        return self._fitted(self._ys).invert(forward(z, self._w, self._b, relu_in=True))

    def out_of_range(self, x: np.ndarray) -> np.ndarray:
        """Whether each query (N, d) lies outside the anchors' convex hull; bool (N,)."""
        x = self._check_query(x)
        return self._latent().out_of_range(x)

    def _check_dim(self, d: int) -> None:
        if d < 2:
            raise ModelError(f"{self.kind}: needs x with at least 2 columns (codes are interpolated on a "
                             f"Delaunay triangulation), got {d}")

    def _fit(self, x: np.ndarray, y: np.ndarray) -> None:
        self._ys = Standardiser.fit(y)
        yz = self._ys.apply(y)
        sizes = (*self.hidden, self.latent, *self.hidden[::-1])
        w, b = train_mlp(yz, yz, sizes, self.max_iter, self.learning_rate, self.alpha, self.random_state,
                         self.progress, self.precision)
        cut = len(self.hidden) + 1  # layers up to and including the bottleneck
        z = forward(yz, w[:cut], b[:cut])  # identity on the last of these: pre-activation codes
        self._codes = LinearInterpolator().fit(x, z)
        self._w, self._b = w[cut:], b[cut:]

    def _predict(self, x: np.ndarray) -> np.ndarray:
        z = self._latent().predict(x)
        return self._fitted(self._ys).invert(forward(z, self._w, self._b, relu_in=True))

    def casadi_predict(self, u: Any) -> Any:
        """The latent codes' linear casadi form, decoded by the decoder's casadi forward pass (m, 1)."""
        self._require_fitted()
        z = self._latent().casadi_predict(u)
        y = forward_casadi(z, self._w, self._b, relu_in=True)
        return scale_casadi(self._fitted(self._ys), y, invert=True)

    def _state(self) -> dict[str, Any]:
        return {"options": {"latent": self.latent, "hidden": list(self.hidden), "max_iter": self.max_iter,
                            "learning_rate": self.learning_rate, "alpha": self.alpha,
                            "random_state": self.random_state, "precision": self.precision},
                "latent_interpolator": self._latent().to_dict(),
                "y_scaler": self._fitted(self._ys).to_dict(),
                "decoder": layers_to_dict(self._w, self._b)}

    @classmethod
    def _from_state(cls, d: dict[str, Any]) -> Self:
        obj = from_options(cls, stored_precision(d))
        obj._codes = codes = LinearInterpolator.from_dict(field(d, "latent_interpolator"))
        obj._ys = Standardiser.from_dict({**field(d, "y_scaler"), "kind": cls.kind})
        obj._w, obj._b = layers_from_dict(d, "decoder")
        if obj._w[0].shape[0] != obj.latent or codes.n_outputs != obj.latent:
            raise ModelError(f"{cls.kind} dict: decoder/latent codes do not match latent = {obj.latent}")
        return obj

    def _latent(self) -> LinearInterpolator:
        if self._codes is None:
            raise ModelError(f"{self.kind} interpolator is not fitted: call fit(x, y) or from_dict() first")
        return self._codes
