"""Radial-basis-function interpolation (scipy ``RBFInterpolator``), thin-plate spline by default.

With ``smoothing = 0`` the interpolant passes exactly through the anchors; a positive smoothing trades
that for a smoother surface (useful when the per-anchor parameters are noisy). The RBF extrapolates
smoothly outside the anchors' convex hull, where ``out_of_range`` flags the queries but the values are
the RBF's own (no nearest-anchor fallback).

``casadi_predict`` writes scipy's evaluation out in casadi from the fitted object's own arrays: the kernel
of ``|epsilon (x - y_k)|`` over the anchors y_k plus the monomial tail of ``(x - shift) / scale`` (scipy's
``_shift``, ``_scale``, ``powers``, ``_coeffs``). Kernels are written on the squared distance, with the
kernel's value at distance 0 taken explicitly where the closed form has a 0 * log 0 or sqrt'(0).

Serialisation stores the anchors, values and options; loading refits (a deterministic (K + p)-square
linear solve), so prediction after a round trip is bit-identical on the same machine and BLAS.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from calibration.errors import ModelError
from calibration.interpolation.base import check_choice
from calibration.interpolation.scattered import AnchoredInterpolator
from calibration.kinematics.arrays import FloatArray

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

    def casadi_predict(self, u: Any) -> Any:
        """scipy's RBF evaluation (kernel sum plus polynomial tail) as a casadi column (m, 1)."""
        import casadi as ca

        self._require_fitted()
        rbf = self._rbf
        y, eps = np.asarray(rbf.y, dtype=float), float(rbf.epsilon)
        coeffs = np.asarray(rbf._coeffs, dtype=float)
        shift, scale = np.asarray(rbf._shift, dtype=float), np.asarray(rbf._scale, dtype=float)
        powers = np.asarray(rbf.powers, dtype=int)
        ue = u * eps
        terms = [_kernel_sx(rbf.kernel, ca.sumsqr(ue - ca.DM(yk * eps))) for yk in y]
        xhat = (u - ca.DM(shift)) / ca.DM(scale)
        for pw in powers:
            mono = ca.SX(1.0)
            for i, e in enumerate(pw):
                if e:
                    mono = mono * xhat[i] ** int(e)
            terms.append(mono)
        return ca.mtimes(ca.DM(coeffs.T), ca.vertcat(*terms))

    def _predict(self, x: np.ndarray) -> np.ndarray:
        if x.shape[0] == 0:
            return np.zeros((0, self.n_outputs))
        y: FloatArray = self._rbf(x)  # scipy's RBFInterpolator (N, m)
        return y


def _kernel_sx(kernel: str, r2: Any) -> Any:
    """scipy's kernel ``phi(r)`` as casadi, of the squared scaled distance r2 = r^2."""
    import casadi as ca

    pos = r2 > 0
    if kernel == "thin_plate_spline":
        return ca.if_else(pos, 0.5 * r2 * ca.log(ca.if_else(pos, r2, 1.0)), 0.0)
    if kernel == "linear":
        return ca.if_else(pos, -ca.sqrt(ca.if_else(pos, r2, 1.0)), 0.0)
    if kernel == "cubic":
        return ca.if_else(pos, r2 * ca.sqrt(ca.if_else(pos, r2, 1.0)), 0.0)
    if kernel == "quintic":
        return ca.if_else(pos, -r2 * r2 * ca.sqrt(ca.if_else(pos, r2, 1.0)), 0.0)
    if kernel == "multiquadric":
        return -ca.sqrt(r2 + 1.0)
    if kernel == "inverse_multiquadric":
        return 1.0 / ca.sqrt(r2 + 1.0)
    if kernel == "inverse_quadratic":
        return 1.0 / (r2 + 1.0)
    if kernel == "gaussian":
        return ca.exp(-r2)
    raise ModelError(f"rbf: no casadi form of kernel {kernel!r}")
