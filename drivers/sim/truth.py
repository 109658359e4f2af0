"""The ground truth behind the simulated devices: a twin that maps joint angles to the true tool pose.

Any object with ``pose(q, context) -> (R (N, 3, 3), p (N, 3))`` and ``context_keys`` is a twin (the physics twin of
``calibration.physics`` has both). :func:`planted_truth` builds one with the one error planter,
:func:`calibration.physics.planted_twin` (seeded geometric errors and, optionally, a gravity-like joint
compliance), so a calibration run on simulated data has something to recover.

``context`` maps names to per-sample arrays; the simulated driver passes ``dir`` (N, 6) signs of each joint's
last motion and ``t`` (N,) simulated time [s]. A twin ignores the keys it does not model; its ``context_keys`` say
which it reads (None: any), so the driver can reuse a pose while the arm stands still.

The physics twin (:class:`calibration.physics.Twin`) reads the directions as ``dir1..dir6`` (N,) each;
:class:`TwinTruth` translates.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Protocol, runtime_checkable

import numpy as np

from calibration.kinematics.poe import PoeModel
from calibration.physics import GravityModel, PlantedErrors, planted_twin
from cell_config.loader import CellSpec, RobotSpec
from drivers.errors import InvalidArgument


@runtime_checkable
class Truth(Protocol):
    """A twin: the true tool-marker pose in the robot base frame."""

    def pose(self, q: np.ndarray, context: Mapping[str, np.ndarray] | None = None
             ) -> tuple[np.ndarray, np.ndarray]:
        """Tool pose for joint angles ``q`` [rad], shape (N, 6): ``(R (N, 3, 3), p (N, 3) [mm])``."""

    @property
    def context_keys(self) -> frozenset[str] | None:
        """The context entries :meth:`pose` reads (``dir``, ``t``, ...), or None when it may read any."""


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

    def __init__(self, twin: Truth) -> None:
        if not (hasattr(twin, "pose") and hasattr(twin, "context_keys")):
            raise InvalidArgument("sim:truth", "twin", twin, "an object with pose(q, context) and context_keys")
        self.twin = twin

    def pose(self, q: np.ndarray, context: Mapping[str, np.ndarray] | None = None
             ) -> tuple[np.ndarray, np.ndarray]:
        """Tool pose for joint angles ``q`` [rad], shape (N, 6): ``(R (N, 3, 3), p (N, 3) [mm])``."""
        return self.twin.pose(np.atleast_2d(q), sim_context_to_twin(context))

    @property
    def context_keys(self) -> frozenset[str] | None:
        """The simulated driver's context entries the pose reads (``dir``, ``t``, ...), or None when the twin does
        not say (see :attr:`calibration.physics.Effect.context_keys`)."""
        return self.twin.context_keys


def planted_truth(nominal: PoeModel, errors: PlantedErrors = PlantedErrors(), seed: int = 0,
                  spec: RobotSpec | None = None) -> TwinTruth:
    """A simulated arm's truth: the one planter, :func:`calibration.physics.planted_twin`, behind a :class:`TwinTruth`.

    Args:
        nominal: the nominal arm with its tool.
        errors: the planted magnitudes (geometric errors and the gravity compliance).
        seed: random seed; the same seed plants the same errors.
        spec: the arm's :class:`~cell_config.loader.RobotSpec` (its ``links`` give the gravity torques); needed
            when ``errors.compliance_mm > 0``.

    Raises:
        InvalidArgument: a compliance is asked for without ``spec``.
    """
    gravity = None
    if errors.compliance_mm > 0:
        if spec is None:
            raise InvalidArgument("sim:truth", "spec", None, "a RobotSpec (link masses) to plant a compliance")
        gravity = GravityModel.from_spec(spec, nominal)
    return TwinTruth(planted_twin(nominal, errors, seed, gravity))


def cell_truths(cell: CellSpec, seed: int, errors: PlantedErrors, robots: tuple[str, ...] | None = None
                ) -> dict[str, TwinTruth]:
    """Each arm's truth, seeded as the simulated cell seeds them (``seed * 100 + k + 1`` for the k-th arm).

    Args:
        cell: the :class:`~cell_config.loader.CellSpec`.
        seed: the cell's seed.
        errors: the planted magnitudes, the same for every arm.
        robots: the arms, in order (default every arm of the cell).
    """
    out = {}
    for k, name in enumerate(robots or cell.robots):
        r = cell.robot(name)
        out[name] = planted_truth(r.model(), errors, seed * 100 + k + 1, r.robot)
    return out
