"""The ground truth behind the simulated devices: a twin that maps joint angles to the true tool pose.

Any object with ``pose(q, context) -> (R (N, 3, 3), p (N, 3))`` is a twin (the physics twin of
``calibration.physics`` has that signature). :class:`PoeTruth` adapts a plain :class:`PoeModel`, and
:func:`planted_truth` builds one with seeded geometric errors planted through the minimal parameterisation,
so a calibration run on simulated data has something to recover.

``context`` maps names to per-sample arrays; the simulated driver passes ``dir`` (N, 6) signs of each joint's
last motion and ``t`` (N,) simulated time [s]. A twin ignores the keys it does not model.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Protocol, runtime_checkable

import numpy as np

from calibration.parameterisation import MinimalParameterisation
from calibration.poe import PoeModel


@runtime_checkable
class Truth(Protocol):
    """A twin: the true tool-marker pose in the robot base frame."""

    def pose(self, q: np.ndarray, context: Mapping[str, np.ndarray] | None = None
             ) -> tuple[np.ndarray, np.ndarray]:
        """Tool pose for joint angles ``q`` [rad], shape (N, 6): ``(R (N, 3, 3), p (N, 3) [mm])``."""


class PoeTruth:
    """A constant POE model used as the truth (context is ignored).

    Args:
        model: the true arm with its tool.
        params: the planted parameter vector, kept for reference (None when not planted).
    """

    def __init__(self, model: PoeModel, params: np.ndarray | None = None) -> None:
        self.model = model
        self.params = None if params is None else np.asarray(params, dtype=float)

    def pose(self, q: np.ndarray, context: Mapping[str, np.ndarray] | None = None
             ) -> tuple[np.ndarray, np.ndarray]:
        """Tool pose for joint angles ``q`` [rad], shape (N, 6)."""
        return self.model.fk(np.atleast_2d(q))


def planted_truth(nominal: PoeModel, origin_std_mm: float = 0.5, tilt_std_deg: float = 0.05,
                  seed: int = 0) -> PoeTruth:
    """A POE truth with random geometric errors around ``nominal``.

    Args:
        nominal: the nominal arm with its tool.
        origin_std_mm: standard deviation of the joint-origin offsets [mm].
        tilt_std_deg: standard deviation of the joint-axis tilts [deg].
        seed: random seed; the same seed plants the same errors.
    """
    par = MinimalParameterisation(nominal)
    rng = np.random.default_rng(seed)
    n = nominal.n_joints
    x = np.concatenate([rng.normal(0.0, origin_std_mm, 2 * n),
                        rng.normal(0.0, math.radians(tilt_std_deg), 2 * n)])
    return PoeTruth(par.model(x), x)
