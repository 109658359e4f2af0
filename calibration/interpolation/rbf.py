"""Radial-basis-function interpolation (scipy ``RBFInterpolator``), thin-plate spline by default.

With ``smoothing = 0`` the interpolant passes exactly through the anchors; a positive smoothing trades
that for a smoother surface (useful when the per-anchor parameters are noisy). The RBF extrapolates
smoothly outside the anchors' convex hull, where ``out_of_range`` flags the queries but the values are
the RBF's own (no nearest-anchor fallback).

Serialisation stores the anchors, values and options; loading refits (a deterministic (K + p)-square
linear solve), so prediction after a round trip is bit-identical on the same machine and BLAS.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from calibration.errors import ModelError
from calibration.interpolation.base import check_choice
from calibration.interpolation.scattered import AnchoredInterpolator

#: Kernels accepted by scipy's RBFInterpolator.
RBF_KERNELS = ("thin_plate_spline", "cubic", "quintic", "linear", "gaussian", "multiquadric",
               "inverse_multiquadric", "inverse_quadratic")
#: Kernels that need a shape parameter ``epsilon``.
_SCALE_VARIANT = ("gaussian", "multiquadric", "inverse_multiquadric", "inverse_quadratic")


class RbfInterpolator(AnchoredInterpolator):
    """scipy ``RBFInterpolator`` over the anchors.

    Args:
        kernel: one of ``RBF_KERNELS``.
        smoothing: smoothing parameter (0 = exact at the anchors), >= 0.
        epsilon: shape parameter [1/input unit]; required for the scale-variant kernels
            (gaussian, multiquadric, inverse_multiquadric, inverse_quadratic), ignored by scipy otherwise.
        degree: degree of the added polynomial, or None for the kernel's minimum.
    """

    kind: ClassVar[str] = "rbf"

    def __init__(self, kernel: str = "thin_plate_spline", smoothing: float = 0.0,
                 epsilon: float | None = None, degree: int | None = None) -> None:
        super().__init__()
        check_choice(self.kind, "kernel", kernel, RBF_KERNELS)
        if not (np.isfinite(smoothing) and smoothing >= 0.0):
            raise ModelError(f"{self.kind}: smoothing must be a finite number >= 0, got {smoothing!r}")
        if kernel in _SCALE_VARIANT and epsilon is None:
            raise ModelError(f"{self.kind}: kernel {kernel!r} needs epsilon [1/input unit]")
        if epsilon is not None and not (np.isfinite(epsilon) and epsilon > 0.0):
            raise ModelError(f"{self.kind}: epsilon must be a finite number > 0, got {epsilon!r}")
        if degree is not None and (not isinstance(degree, int) or degree < -1):
            raise ModelError(f"{self.kind}: degree must be an int >= -1 or None, got {degree!r}")
        self.kernel = kernel
        self.smoothing = float(smoothing)
        self.epsilon = None if epsilon is None else float(epsilon)
        self.degree = degree
        self._rbf: Any = None

    def _options(self) -> dict[str, Any]:
        return {"kernel": self.kernel, "smoothing": self.smoothing, "epsilon": self.epsilon,
                "degree": self.degree}

    def _build(self) -> None:
        from scipy.interpolate import RBFInterpolator

        try:
            self._rbf = RBFInterpolator(self._anchors, self._values, kernel=self.kernel,
                                        smoothing=self.smoothing, epsilon=self.epsilon, degree=self.degree)
        except (ValueError, np.linalg.LinAlgError) as e:
            raise ModelError(f"{self.kind}: scipy RBFInterpolator failed: {e}") from e

    def _predict(self, x: np.ndarray) -> np.ndarray:
        if x.shape[0] == 0:
            return np.zeros((0, self.n_outputs))
        return self._rbf(x)
