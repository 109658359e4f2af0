"""The simulated dual-robot cell for validation: true twins, calibration data from them, fitted model sets.

Each arm's truth is a :class:`~calibration.physics.Twin` from the one planter,
:func:`~calibration.physics.planted_twin`, with the errors of :data:`VALIDATION_CELL`: planted geometric errors
(joint-origin offsets and axis tilts) and a gravity-like joint compliance (joints 2, 3, 5 sag in proportion to
the arm's own gravity torque, link masses from the robot YAML). Calibration data are measured from the twin
directly with Gaussian position/orientation noise (no simulated motion, so it stays fast):

* training: the paper's cluster design, anchors on a (q2, q3) grid each followed by +1 deg on every joint;
* CPA: one single-joint sweep per joint about a mid-workspace pose (120 deg each: shorter arcs make the circle
  fits, hence the axes, noise-sensitive).

Model sets are fitted on them with :class:`~calibration.methods.fitter.Fitter` (``nominal``, ``cpa``, ``fbf13``,
``ae``, ``pi`` the physics-informed model, ...). ``pi`` knows the shape of gravity torques but not the link
masses, so it does not get the twin's structure for free.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import numpy as np

from app.collection.runtime.sim import SimCellOptions
from calibration.data.recording import Recording
from calibration.errors import ModelError
from calibration.kinematics import so3
from calibration.method_names import METHODS
from calibration.methods.cdc import expand_anchors
from calibration.methods.fitter import Fitter
from calibration.models import KinematicModel
from calibration.physics import GravityModel, PlantedErrors, planted_twin
from cell_config.loader import CellSpec

logger = logging.getLogger("cellcal.app")
ROBOTS = ("R1", "R2")
#: Model sets the simulated validation fits by default, in table order.
SIM_METHODS = ("nominal", "cpa", "fbf13", "ae", "pi")


#: The simulated cell of ``validate-dual --sim``: its planted errors and the noise of its calibration data.
VALIDATION_CELL = SimCellOptions(seed=7, noise_pos_mm=0.03, noise_rot_deg=0.01,
                                 errors=PlantedErrors(offset_std_mm=0.3, tilt_std_rad=4e-4, compliance_mm=0.6))


@dataclass(frozen=True)
class TrainingGrid:
    """Where the training anchors of each arm lie.

    Attributes:
        grid_step_deg: (q2, q3) spacing of the training anchors [deg].
        wrist_spread_deg: joints 1, 4, 5, 6 of each anchor uniform in +- this [deg].
    """

    grid_step_deg: float = 10.0
    wrist_spread_deg: float = 30.0


def make_twins(cell: CellSpec, options: SimCellOptions = VALIDATION_CELL) -> dict[str, Any]:
    """The true twin of each arm (R1 seeded ``options.seed``, R2 ``options.seed + 1``), from the one planter."""

    twins = {}
    for k, name in enumerate(ROBOTS):
        spec = cell.robot(name)
        nominal = spec.model()
        gravity = GravityModel.from_spec(spec.robot, nominal)
        twins[name] = planted_twin(nominal, options.errors, options.seed + k, gravity)
    return twins


def measure(twin: Any, q: np.ndarray, options: SimCellOptions, seed: int,
            cluster: np.ndarray | None = None) -> Recording:
    """A recording of the twin at joint angles q [rad] (N, 6) with Gaussian noise; ``cluster`` (N,) ids."""
    rng = np.random.default_rng(seed)
    R, p = twin.pose(q)
    p = p + rng.normal(0.0, options.noise_pos_mm, p.shape)
    R = so3.exp(rng.normal(0.0, np.radians(options.noise_rot_deg), p.shape)) @ R
    extra = {} if cluster is None else {"cluster": np.asarray(cluster, dtype=float)}
    return Recording(np.asarray(q, dtype=float), p, so3.R_to_quat(R), extra, "simulated twin")


def training_design(cell: CellSpec, name: str, options: SimCellOptions, grid: TrainingGrid = TrainingGrid()
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Cluster design inside the arm's limits: ``(q (N, 6) [rad], cluster (N,))``, 7 samples per anchor."""
    spec = cell.robot(name).robot
    lo, hi = np.degrees(spec.lower_rad) + 5.0, np.degrees(spec.upper_rad) - 5.0
    rng = np.random.default_rng(options.seed + 100)
    s = grid.grid_step_deg
    anchors = []
    for q2 in np.arange(max(-45.0, lo[1]), min(50.0, hi[1]) + 1e-9, s):
        for q3 in np.arange(max(-45.0, lo[2]), min(35.0, hi[2]) + 1e-9, s):
            w = rng.uniform(-grid.wrist_spread_deg, grid.wrist_spread_deg, 4)
            anchors.append([w[0], q2, q3, w[1], w[2], w[3]])
    return expand_anchors(np.radians(anchors))


def cpa_design(n_per_sweep: int = 15, span_deg: float = 120.0) -> tuple[np.ndarray, np.ndarray]:
    """Single-joint sweeps about a mid-workspace pose: ``(q (6 n, 6) [rad], cluster (6 n,))``."""
    base = np.radians([0.0, 10.0, 0.0, 0.0, -30.0, 0.0])
    q, cluster = [], []
    for j in range(6):
        for v in np.linspace(-0.5, 0.5, n_per_sweep) * np.radians(span_deg):
            b = base.copy()
            b[j] += v
            q.append(b)
            cluster.append(j)
    return np.array(q), np.array(cluster)


def check_methods(methods: tuple[str, ...]) -> None:
    """Raise ModelError naming the first unknown method and the valid ones."""

    bad = [m for m in methods if m not in METHODS]
    if bad:
        raise ModelError(f"unknown model set {bad[0]!r}; valid: {', '.join(METHODS)}")


def fit_model_sets(cell: CellSpec, twins: dict[str, Any], methods: tuple[str, ...] = SIM_METHODS,
                   options: SimCellOptions = VALIDATION_CELL, grid: TrainingGrid = TrainingGrid()
                   ) -> dict[str, dict[str, KinematicModel]]:
    """Fit every requested model set on data measured from the twins.

    Returns:
        ``{method: {"R1": model, "R2": model}}`` in the order of ``methods``.

    Raises:
        ModelError: an unknown method (the message names the valid ones).
    """

    check_methods(methods)
    out: dict[str, dict[str, KinematicModel]] = {m: {} for m in methods}
    for k, name in enumerate(ROBOTS):
        spec = cell.robot(name)
        q, cluster = training_design(cell, name, options, grid)
        train = measure(twins[name], q, options, options.seed + 10 + k, cluster)
        qc, cc = cpa_design()
        cpa = measure(twins[name], qc, options, options.seed + 20 + k, cc)
        fitter = Fitter.for_arm(spec.arm(), train, cpa)
        for method in methods:
            out[method][name] = fitter.fit(method)[0]
            logger.info("fitted %s for %s on %d samples", method, name, len(train))
    return out
