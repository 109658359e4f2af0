"""The ground truth behind the simulated devices: a twin that maps joint angles to the true tool pose.

Any object with ``pose(q, context) -> (R (N, 3, 3), p (N, 3))`` is a twin (the physics twin of
``calibration.physics`` has that signature). :class:`PoeTruth` adapts a plain :class:`PoeModel`, and
:func:`planted_truth` builds one with seeded geometric errors planted through the minimal parameterisation,
so a calibration run on simulated data has something to recover.

``context`` maps names to per-sample arrays; the simulated driver passes ``dir`` (N, 6) signs of each joint's
last motion and ``t`` (N,) simulated time [s]. A twin ignores the keys it does not model.

The physics twin (:class:`calibration.physics.Twin`) reads the directions as ``dir1..dir6`` (N,) each;
:class:`TwinTruth` translates, and :func:`physics_truth` plants geometric errors plus a gravity-like joint
compliance, so the simulated arm has a configuration-dependent error for CDC to beat.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, Protocol, runtime_checkable

import numpy as np

from calibration.parameterisation import MinimalParameterisation
from calibration.poe import PoeModel
from drivers.errors import InvalidArgument


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


def sim_context_to_twin(context: Mapping[str, np.ndarray] | None) -> dict[str, np.ndarray]:
    """The simulated driver's context in the physics twin's keys.

    ``dir`` (N, 6) becomes ``dir1..dir6`` (N,) each; every other key passes unchanged.

    Raises:
        InvalidArgument: ``dir`` is not two-dimensional.
    """
    out: dict[str, np.ndarray] = {}
    for key, value in (context or {}).items():
        if key == "dir":
            d = np.asarray(value, dtype=float)
            if d.ndim != 2:
                raise InvalidArgument("sim:truth", "context.dir", d.shape, "an array of shape (N, 6)")
            out.update({f"dir{i + 1}": d[:, i] for i in range(d.shape[1])})
        else:
            out[key] = value
    return out


class TwinTruth:
    """A physics twin (anything with ``pose(q, context)`` reading ``dir1..dir6``) used as the truth.

    Args:
        twin: typically a :class:`calibration.physics.Twin`.
    """

    def __init__(self, twin: Any) -> None:
        if not hasattr(twin, "pose"):
            raise InvalidArgument("sim:truth", "twin", twin, "an object with pose(q, context)")
        self.twin = twin

    def pose(self, q: np.ndarray, context: Mapping[str, np.ndarray] | None = None
             ) -> tuple[np.ndarray, np.ndarray]:
        """Tool pose for joint angles ``q`` [rad], shape (N, 6): ``(R (N, 3, 3), p (N, 3) [mm])``."""
        return self.twin.pose(np.atleast_2d(q), sim_context_to_twin(context))


def physics_truth(nominal: PoeModel, spec: Any, seed: int = 0, origin_std_mm: float = 0.5,
                  tilt_std_deg: float = 0.05, compliance_mm: float = 1.0) -> TwinTruth:
    """A physics twin with planted geometric errors and a gravity-driven joint compliance.

    Args:
        nominal: the nominal arm with its tool.
        spec: the arm's :class:`~cell_config.loader.RobotSpec` (its ``links`` give the gravity torques).
        seed: random seed; the same seed plants the same errors.
        origin_std_mm: standard deviation of the joint-origin offsets [mm].
        tilt_std_deg: standard deviation of the joint-axis tilts [deg].
        compliance_mm: RMS tool displacement [mm] the compliance causes on its own (0: none).
    """
    from calibration.physics import GravityModel, Twin

    effects = {"joint_compliance": compliance_mm} if compliance_mm > 0 else {}
    gravity = GravityModel.from_spec(spec, nominal) if effects else None
    twin = Twin.random(nominal, effects, seed, gravity=gravity, offset_sigma_mm=origin_std_mm,
                       tilt_sigma_rad=math.radians(tilt_std_deg))
    return TwinTruth(twin)
