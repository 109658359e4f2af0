"""Interpolation of per-anchor kinematic-error parameters over the configuration space.

CDC identifies a parameter vector (m values) at K cluster anchors x (d inputs, in practice the
shoulder/elbow angles (q2, q3) [rad]); an ``Interpolator`` gives every other configuration its own
parameters. Kinds (``KINDS``):

- ``nearest``: value of the nearest anchor.
- ``linear``: piecewise-linear on the anchors' Delaunay triangulation (d >= 2).
- ``cubic``: Clough-Tocher C1 cubic on the triangulation (d = 2).
- ``rbf``: radial basis functions, thin-plate spline by default.
- ``fbf13``: least-squares fit of the 13-term Fourier basis in (q2, q3) (d = 2).
- ``fbf7``: the Fourier basis reduced by SVD to ``rank`` functions (default 7) (d = 2).
- ``nn``: ReLU MLP, 3 hidden layers x 200, Adam.
- ``ae``: autoencoder latent codes of the anchors, interpolated linearly, then decoded (d >= 2).

Every kind flags queries outside the anchors' convex hull with ``out_of_range``; nearest, linear, cubic
and ae return the nearest anchor's value there (ae: its reconstruction), the others extrapolate.

``casadi_predict(u)`` (declared on ``Interpolator``) gives the same prediction as a casadi expression of one
symbolic query, so planners differentiate through it exactly; every kind here has one (a kind that does
not override it raises ModelError, and its CDC models plan with frozen parameters).

Example::

    interp = make_interpolator("rbf", smoothing=0.0).fit(q23_anchors, params)   # (K, 2), (K, 24)
    params_q = interp.predict(q23)                                               # (N, 24)
    saved = json.dumps(interp.to_dict())
    same = interpolator_from_dict(json.loads(saved))                             # predicts bit-identically
"""

from __future__ import annotations

import inspect
from typing import Any

from calibration.errors import ModelError
from calibration.interpolation.autoencoder import AutoencoderInterpolator
from calibration.interpolation.base import Interpolator
from calibration.interpolation.fourier import (
    FBF13_TERMS,
    Fourier13Interpolator,
    FourierReducedInterpolator,
    fbf13_basis,
)
from calibration.interpolation.mlp import MlpInterpolator
from calibration.interpolation.rbf import RBF_KERNELS, RbfInterpolator
from calibration.interpolation.scattered import CubicInterpolator, LinearInterpolator, NearestInterpolator

_CLASSES: dict[str, type[Interpolator]] = {cls.kind: cls for cls in (
    NearestInterpolator, LinearInterpolator, CubicInterpolator, RbfInterpolator, Fourier13Interpolator,
    FourierReducedInterpolator, MlpInterpolator, AutoencoderInterpolator)}

#: Names accepted by ``make_interpolator`` and stored as ``"kind"`` by ``to_dict``.
KINDS: tuple[str, ...] = tuple(_CLASSES)


def interpolator_class(kind: Any) -> type[Interpolator]:
    """The class implementing ``kind`` (any value, as read from a file); ModelError naming the valid kinds otherwise."""
    try:
        return _CLASSES[kind]
    except (KeyError, TypeError):
        raise ModelError(f"unknown interpolator kind {kind!r}; valid kinds: {', '.join(KINDS)}") from None


def make_interpolator(kind: str, **options: Any) -> Interpolator:
    """A new, unfitted interpolator.

    Args:
        kind: one of ``KINDS``.
        **options: the kind's constructor options (e.g. ``rank=7`` for fbf7, ``kernel="cubic"`` for rbf).

    Raises:
        ModelError: unknown kind, or an option the kind does not take (the message lists the valid ones).
    """
    cls = interpolator_class(kind)
    valid = [p for p in inspect.signature(cls.__init__).parameters if p != "self"]
    unknown = sorted(set(options) - set(valid))
    if unknown:
        raise ModelError(f"{kind}: unknown option(s) {', '.join(unknown)}; valid options: "
                         f"{', '.join(valid) if valid else 'none'}")
    return cls(**options)


def interpolator_from_dict(d: dict[str, Any]) -> Interpolator:
    """Rebuild any interpolator from its ``to_dict()`` output, dispatching on ``d["kind"]``."""
    if not isinstance(d, dict):
        raise ModelError(f"expected an interpolator dict with a 'kind' key, got {type(d).__name__}")
    return interpolator_class(d.get("kind")).from_dict(d)


__all__ = [
    "KINDS", "RBF_KERNELS", "FBF13_TERMS",
    "Interpolator", "make_interpolator", "interpolator_from_dict", "interpolator_class", "fbf13_basis",
    "NearestInterpolator", "LinearInterpolator", "CubicInterpolator", "RbfInterpolator",
    "Fourier13Interpolator", "FourierReducedInterpolator", "MlpInterpolator", "AutoencoderInterpolator",
]
