"""Multilayer-perceptron interpolation (``nn``): a ReLU MLP from configuration to values.

Inputs and outputs are standardised (per column: subtract the anchors' mean, divide by their standard
deviation, 1 for constant columns), the network is trained with Adam (:func:`train_mlp`: scikit-learn's
``MLPRegressor`` arithmetic in numpy, fixed ``random_state``, so training is repeatable), and only the weights,
biases and scalers are kept: prediction is a numpy forward pass over the stored arrays, so it is fast and bit-identical after a
``to_dict`` / ``from_dict`` round trip.

The network extrapolates (piecewise linearly) outside the anchors' convex hull, where ``out_of_range``
flags the queries but the values are the network's own.

``casadi_predict`` is the same forward pass on casadi symbols (``fmax(., 0)`` for the ReLU), exact but
dense: three 200-wide layers are ~80k SX operations.

The helpers ``Standardiser``, ``train_mlp``, ``forward`` and ``forward_casadi`` are shared with the autoencoder kind.
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar, Self

import numpy as np

from calibration.errors import ModelError
from calibration.interpolation.base import Interpolator, array_field, field, from_options
from calibration.interpolation.support import AnchorSupport
from calibration.kinematics.arrays import FloatArray

logger = logging.getLogger("cellcal.calibration")

#: ``progress(epoch, n_epochs)``, called after each training epoch (epoch counts from 1).
EpochCallback = Callable[[int, int], None]


@dataclass(frozen=True)
class Standardiser:
    """Per-column affine scaling ``z = (v - mean) / scale``.

    Attributes:
        mean: column means, shape (c,).
        scale: column standard deviations (1 where a column is constant), shape (c,).
    """

    mean: np.ndarray
    scale: np.ndarray

    @classmethod
    def fit(cls, v: np.ndarray) -> Standardiser:
        """Scaler of the columns of v, shape (K, c)."""
        std = v.std(axis=0)
        return cls(v.mean(axis=0), np.where(std > 0.0, std, 1.0))

    def apply(self, v: np.ndarray) -> np.ndarray:
        """Standardised v, same shape."""
        scaled: FloatArray = (v - self.mean) / self.scale
        return scaled

    def invert(self, z: np.ndarray) -> np.ndarray:
        """Original units from standardised z, same shape."""
        unscaled: FloatArray = z * self.scale + self.mean
        return unscaled

    def to_dict(self) -> dict[str, list[float]]:
        return {"mean": self.mean.tolist(), "scale": self.scale.tolist()}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Standardiser:
        return cls(array_field(d, "mean", 1), array_field(d, "scale", 1))


def check_training_options(kind: str, hidden: Sequence[int], max_iter: int, learning_rate: float,
                           alpha: float) -> tuple[int, ...]:
    """Validate the shared training options; returns ``hidden`` as a tuple of ints."""
    if not hidden or any(isinstance(h, bool) or not isinstance(h, (int, np.integer)) or h < 1 for h in hidden):
        raise ModelError(f"{kind}: hidden must be a non-empty sequence of positive ints, got {hidden!r}")
    if not isinstance(max_iter, (int, np.integer)) or max_iter < 1:
        raise ModelError(f"{kind}: max_iter must be a positive int, got {max_iter!r}")
    if not (np.isfinite(learning_rate) and learning_rate > 0.0):
        raise ModelError(f"{kind}: learning_rate must be > 0, got {learning_rate!r}")
    if not (np.isfinite(alpha) and alpha >= 0.0):
        raise ModelError(f"{kind}: alpha must be >= 0, got {alpha!r}")
    return tuple(int(h) for h in hidden)


#: Arithmetic of the network trainings: float32 since issue 14 (half the cost of float64; on the 8 R1 training
#: recordings the same recommendation, best method and robustness flags as float64, every candidate's held-out RMS
#: within 0.0003 mm, ``scripts/studies/recommend_days.py --against``). Files saved before it
#: name no precision and were trained in float64, which :func:`stored_precision` keeps.
PRECISIONS = ("float32", "float64")
DEFAULT_PRECISION = "float32"


def check_precision(kind: str, precision: str) -> str:
    if precision not in PRECISIONS:
        raise ModelError(f"{kind}: precision must be one of {', '.join(PRECISIONS)}, got {precision!r}")
    return precision


def stored_precision(d: dict[str, Any]) -> dict[str, Any]:
    """``d`` with its options naming the precision the network was trained in (float64 when a file older than the
    option names none)."""
    options = d.get("options", {})
    if isinstance(options, dict) and "precision" not in options:
        d = {**d, "options": {**options, "precision": "float64"}}
    return d


@contextlib.contextmanager
def one_blas_thread() -> Iterator[None]:
    """Run the enclosed matrix products on one BLAS thread (no-op without ``threadpoolctl``).

    The products here are small (K x 200, or blocks of 8192 x 200), so BLAS threads mostly add
    synchronisation: measured 2-4x slower with 2 threads on a loaded 2-core machine, with stalls of
    seconds. One thread also makes training independent of the core count. Costs ~1 ms per entry.
    """
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:
        yield
        return
    with threadpool_limits(limits=1, user_api="blas"):
        yield


#: Adam settings of the training (scikit-learn's MLPRegressor defaults, which the networks were trained with).
ADAM_BETA_1, ADAM_BETA_2, ADAM_EPSILON = 0.9, 0.999, 1e-8
#: Mini-batch size (MLPRegressor's "auto": min(200, K)).
BATCH_SIZE = 200


def train_mlp(x: np.ndarray, y: np.ndarray, hidden: Sequence[int], max_iter: int, learning_rate: float,
              alpha: float, random_state: int, progress: EpochCallback | None = None,
              precision: str = "float64") -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Train a ReLU MLP ``x -> y`` (identity output, squared loss) with Adam, full budget of epochs.

    The same arithmetic, in the same order, as scikit-learn's ``MLPRegressor(activation="relu", solver="adam",
    shuffle=True, tol=0)`` (Glorot-uniform initialisation and batch shuffles from ``RandomState(random_state)``,
    batches of min(200, K)), so it gives the same bits as the networks trained with it before (checked by
    tests/calibration/interpolation/test_interpolation.py against scikit-learn), without scikit-learn and about a third faster:
    no loss evaluated per batch, Adam's moments updated in place.

    Args:
        x: standardised inputs, shape (K, d).
        y: standardised targets, shape (K, m).
        hidden: hidden layer widths.
        max_iter: epochs.
        learning_rate: Adam step size.
        alpha: L2 penalty.
        random_state: seed of the weight initialisation and batch shuffling.
        progress: called as ``progress(epoch, max_iter)`` after each epoch (a progress bar); no effect on the
            result.
        precision: ``float64`` or ``float32``, the arithmetic of the training (scikit-learn's too when given
            float32 data: the same bits); float32 halves the cost of the matrix products.

    Returns:
        Weights (list of (n_in, n_out) arrays) and biases (list of (n_out,) arrays), input layer first, float64
        (exact copies of float32 ones), so prediction is the same float64 pass however they were trained.
    """
    dtype = np.dtype(check_precision("train_mlp", precision))
    x, y = np.ascontiguousarray(x, dtype=dtype), np.ascontiguousarray(y, dtype=dtype)
    t0 = time.perf_counter()
    rs = np.random.RandomState(random_state)
    weights, biases = _glorot_uniform(rs, [x.shape[1], *hidden, y.shape[1]], dtype)
    n_layers, n = len(weights), x.shape[0]
    params = weights + biases
    m1, m2 = [np.zeros_like(p) for p in params], [np.zeros_like(p) for p in params]
    # the step is float64 whatever the precision, as in scikit-learn: -lr * m / (sqrt(v) + eps) with lr a float64
    scratch, step = [np.empty_like(p) for p in params], [np.empty(p.shape) for p in params]
    grads: list[np.ndarray] = [np.empty(0)] * len(params)
    acts: list[np.ndarray] = [np.empty(0)] * (n_layers + 1)
    batch, order, t = min(BATCH_SIZE, n), np.arange(n), 0
    with one_blas_thread():
        for epoch in range(max_iter):
            perm = np.arange(n)
            rs.shuffle(perm)
            order = order[perm]
            for start in range(0, n, batch):
                idx = order[start:start + batch]
                _gradients(x[idx], y[idx], weights, biases, alpha, acts, grads)
                t += 1
                lr = learning_rate * np.sqrt(1 - ADAM_BETA_2 ** t) / (1 - ADAM_BETA_1 ** t)
                _adam_step(params, m1, m2, grads, scratch, step, lr)
            if progress is not None:
                progress(epoch + 1, max_iter)
    if not all(np.isfinite(p).all() for p in params):
        raise ModelError(f"MLP training diverged (non-finite weights) on {n} anchors; check the anchor values")
    logger.info("trained MLP %s: %d epochs (%s), %.2f s", tuple(hidden), max_iter, precision, time.perf_counter() - t0)
    return [w.astype(np.float64) for w in weights], [b.astype(np.float64) for b in biases]


def _glorot_uniform(rs: np.random.RandomState, units: Sequence[int],
                    dtype: np.dtype) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """scikit-learn's Glorot-uniform initialisation: per layer its weights, then its biases, from ``rs``."""
    weights, biases = [], []
    for fan_in, fan_out in zip(units[:-1], units[1:]):
        bound = np.sqrt(6.0 / (fan_in + fan_out))
        weights.append(rs.uniform(-bound, bound, (fan_in, fan_out)).astype(dtype, copy=False))
        biases.append(rs.uniform(-bound, bound, fan_out).astype(dtype, copy=False))
    return weights, biases


def _gradients(xb: np.ndarray, yb: np.ndarray, weights: Sequence[np.ndarray], biases: Sequence[np.ndarray],
               alpha: float, acts: list[np.ndarray], grads: list[np.ndarray]) -> None:
    """One batch's forward pass into ``acts`` and its squared-loss gradients (L2 ``alpha``) into ``grads``:
    the weights' first, then the biases'."""
    n_layers = len(weights)
    acts[0] = xb
    for i in range(n_layers):
        a = acts[i] @ weights[i]
        a += biases[i]
        if i < n_layers - 1:
            np.maximum(a, 0, out=a)
        acts[i + 1] = a
    delta = acts[-1] - yb
    for i in range(n_layers - 1, -1, -1):
        g = acts[i].T @ delta
        g += alpha * weights[i]
        g /= len(xb)
        grads[i], grads[n_layers + i] = g, np.sum(delta, axis=0) / len(xb)
        if i > 0:
            delta = delta @ weights[i].T
            np.copyto(delta, 0.0, where=acts[i] == 0)  # ReLU derivative


def _adam_step(params: Sequence[np.ndarray], m1: Sequence[np.ndarray], m2: Sequence[np.ndarray],
               grads: Sequence[np.ndarray], scratch: Sequence[np.ndarray], step: Sequence[np.ndarray],
               lr: float) -> None:
    """Adam's update of ``params`` in place at the bias-corrected rate ``lr``: the moments ``m1``, ``m2`` updated in
    place, ``scratch`` in the parameters' precision, the ``step`` in float64 (as scikit-learn's)."""
    for p, m, v, g, s, u in zip(params, m1, m2, grads, scratch, step):
        m *= ADAM_BETA_1
        np.multiply(g, 1 - ADAM_BETA_1, out=s)
        m += s
        v *= ADAM_BETA_2
        np.square(g, out=s)
        s *= 1 - ADAM_BETA_2
        v += s
        np.sqrt(v, out=s)
        s += ADAM_EPSILON
        np.multiply(m, -lr, out=u)
        u /= s
        p += u


def forward(z: np.ndarray, weights: Sequence[np.ndarray], biases: Sequence[np.ndarray],
            relu_in: bool = False, chunk: int = 8192) -> np.ndarray:
    """ReLU MLP forward pass: ReLU after every layer but the last (identity output).

    Rows are processed in blocks of ``chunk`` so 10^5 queries through 200-wide layers need a few MB of
    scratch instead of hundreds of MB. The blocking is fixed, so the same queries give the same bits.

    Args:
        z: layer input, shape (N, n_in).
        weights, biases: the layers, as returned by ``train_mlp`` (or a slice of them).
        relu_in: apply a ReLU to z first (a decoder fed with pre-activation latent codes).
        chunk: rows per block.

    Returns:
        Output, shape (N, n_out).
    """
    out = np.empty((z.shape[0], weights[-1].shape[1]))
    last = len(weights) - 1
    with one_blas_thread():
        for start in range(0, z.shape[0], chunk):
            h = z[start:start + chunk]
            if relu_in:
                h = np.maximum(h, 0.0)
            for i, (w, b) in enumerate(zip(weights, biases)):
                h = h @ w
                h += b
                if i < last:
                    np.maximum(h, 0.0, out=h)
            out[start:start + chunk] = h
    return out


def forward_casadi(z: Any, weights: Sequence[np.ndarray], biases: Sequence[np.ndarray],
                   relu_in: bool = False) -> Any:
    """:func:`forward` on one casadi column z (n_in,): the same layers and ReLUs, output (n_out, 1)."""
    import casadi as ca

    h = ca.fmax(z, 0.0) if relu_in else z
    last = len(weights) - 1
    for i, (w, b) in enumerate(zip(weights, biases)):
        h = ca.mtimes(ca.DM(w.T), h) + ca.DM(b)
        if i < last:
            h = ca.fmax(h, 0.0)
    return h


def scale_casadi(s: Standardiser, v: Any, invert: bool = False) -> Any:
    """``s.apply`` (or ``s.invert``) on a casadi column."""
    import casadi as ca

    return v * ca.DM(s.scale) + ca.DM(s.mean) if invert else (v - ca.DM(s.mean)) / ca.DM(s.scale)


def layers_to_dict(weights: Sequence[np.ndarray], biases: Sequence[np.ndarray]) -> dict[str, Any]:
    return {"weights": [w.tolist() for w in weights], "biases": [b.tolist() for b in biases]}


def layers_from_dict(d: dict[str, Any], key: str) -> tuple[list[np.ndarray], list[np.ndarray]]:
    sub = field(d, key)
    sub = {**sub, "kind": d.get("kind")}
    weights = [np.asarray(w, dtype=np.float64) for w in field(sub, "weights")]
    biases = [np.asarray(b, dtype=np.float64) for b in field(sub, "biases")]
    if len(weights) != len(biases) or not weights or any(
            w.ndim != 2 or b.shape != (w.shape[1],) for w, b in zip(weights, biases)) or any(
            a.shape[1] != b.shape[0] for a, b in zip(weights, weights[1:])):
        raise ModelError(f"{d.get('kind')} dict: {key!r} layers have inconsistent shapes")
    return weights, biases


class MlpInterpolator(Interpolator):
    """ReLU MLP trained on the anchors (default 3 hidden layers x 200, Adam).

    Args:
        hidden: hidden layer widths.
        max_iter: training epochs (always run in full; no early stopping).
        learning_rate: Adam step size.
        alpha: L2 weight penalty.
        random_state: seed; the same seed and data give the same network.
        progress: called as ``progress(epoch, max_iter)`` after each training epoch; not part of the model
            (not saved), no effect on the result.
        precision: arithmetic of the training (:data:`PRECISIONS`); prediction is float64 either way.
    """

    kind: ClassVar[str] = "nn"

    def __init__(self, hidden: Sequence[int] = (200, 200, 200), max_iter: int = 300,
                 learning_rate: float = 1e-3, alpha: float = 1e-4, random_state: int = 0,
                 progress: EpochCallback | None = None, precision: str = DEFAULT_PRECISION) -> None:
        super().__init__()
        self.progress = progress
        self.precision = check_precision(self.kind, precision)
        self.hidden = check_training_options(self.kind, hidden, max_iter, learning_rate, alpha)
        self.max_iter, self.learning_rate, self.alpha = int(max_iter), float(learning_rate), float(alpha)
        self.random_state = int(random_state)
        self._support: AnchorSupport | None = None
        self._anchors: np.ndarray | None = None
        self._xs: Standardiser | None = None
        self._ys: Standardiser | None = None
        self._w: list[np.ndarray] = []
        self._b: list[np.ndarray] = []

    def out_of_range(self, x: np.ndarray) -> np.ndarray:
        """Whether each query (N, d) lies outside the anchors' convex hull; bool (N,)."""
        x = self._check_query(x)
        return self._fitted(self._support).outside(x)

    def _fit(self, x: np.ndarray, y: np.ndarray) -> None:
        self._support, self._anchors = AnchorSupport(x), x
        self._xs, self._ys = Standardiser.fit(x), Standardiser.fit(y)
        self._w, self._b = train_mlp(self._xs.apply(x), self._ys.apply(y), self.hidden, self.max_iter,
                                     self.learning_rate, self.alpha, self.random_state, self.progress,
                                     self.precision)

    def _predict(self, x: np.ndarray) -> np.ndarray:
        return self._fitted(self._ys).invert(forward(self._fitted(self._xs).apply(x), self._w, self._b))

    def casadi_predict(self, u: Any) -> Any:
        """The standardise / forward / unstandardise pass of ``predict`` as a casadi column (m, 1)."""
        self._require_fitted()
        z = forward_casadi(scale_casadi(self._fitted(self._xs), u), self._w, self._b)
        return scale_casadi(self._fitted(self._ys), z, invert=True)

    def _state(self) -> dict[str, Any]:
        return {"options": {"hidden": list(self.hidden), "max_iter": self.max_iter,
                            "learning_rate": self.learning_rate, "alpha": self.alpha,
                            "random_state": self.random_state, "precision": self.precision},
                "anchors": self._fitted(self._anchors).tolist(),
                "x_scaler": self._fitted(self._xs).to_dict(), "y_scaler": self._fitted(self._ys).to_dict(),
                "network": layers_to_dict(self._w, self._b)}

    @classmethod
    def _from_state(cls, d: dict[str, Any]) -> Self:
        obj = from_options(cls, stored_precision(d))
        anchors = array_field(d, "anchors", 2)
        obj._support, obj._anchors = AnchorSupport(anchors), anchors
        obj._xs = Standardiser.from_dict({**field(d, "x_scaler"), "kind": cls.kind})
        obj._ys = Standardiser.from_dict({**field(d, "y_scaler"), "kind": cls.kind})
        obj._w, obj._b = layers_from_dict(d, "network")
        return obj
