"""Dual-robot contact validation (the paper's Table VIII check): how far each model set puts the gun tip.

Method (the paper's): both arms are driven through N configurations, from tucked-in to outstretched, at
which the gun tip (R1's tool point) truly touches one fixed point of the workpiece (a point fixed in R2's
tool frame). Contact is confirmed by the contact probe at every configuration and the joint readings are
recorded. For each model set, the predicted relative position — R1's tool point in R2's tool frame, through
the cell's base-to-base transform — is computed from the readings, and its distance from the known contact
point is reported as mean / std / max [mm]. A model set is not used to move the arms; it only predicts, so
every set is judged on the same physical configurations.

Every move goes through the cell-safety check (limits, floor, both arms' capsules), the whole sequence before
the first motion and each move again against the other arm's live pose (:func:`collect_contacts`).

On the simulated cell (:func:`run_sim_validation`) the contact configurations are planned with the true
twins (so contact truly holds), the simulated arms are driven there, and a simulated probe on python-can's
virtual bus touches when the true tip is within ``tolerance_mm`` of the point (the sensor,
:class:`drivers.sim.contact.SimContactSensor`, polls :func:`true_tip_distance` in its thread); a :class:`CanContactProbe` on
the same bus confirms it. The cell's base-to-base transform is taken as exact in the simulation.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from app.collection.motion import move_safely, read_q
from app.collection.safety import CellSafety
from app.dual.paths import Q_REF_DEG, relative_pose, sweep_path
from app.dual.planner import DualPlanner, PlannerOptions
from app.dual.sim import SIM_METHODS, VALIDATION_CELL, TrainingGrid, fit_model_sets, make_twins
from calibration.errors import ModelError
from calibration.models import ConstantModel
from calibration.models.physics import PhysicsModel
from cell_config.loader import CellSpec
from drivers.can_probe import CanContactProbe
from drivers.errors import DriverTimeout
from drivers.sim import SimClock, SimRobotConfig, SimRobotDriver
from drivers.sim.can_probe import SimulatedProbe
from drivers.sim.contact import SimContactSensor

logger = logging.getLogger("cellcal.app")


@dataclass(frozen=True)
class DeviationStats:
    """Distance of the predicted relative position from the contact point over the configurations [mm]."""

    mean_mm: float
    std_mm: float
    max_mm: float

    @classmethod
    def of(cls, d: np.ndarray) -> DeviationStats:
        return cls(float(np.mean(d)), float(np.std(d)), float(np.max(d)))


@dataclass(frozen=True)
class ContactValidation:
    """Result of a contact validation.

    Attributes:
        models: statistics per model set label, in table order.
        q: joint readings at the confirmed contacts [rad], shape (N, 12) (R1 then R2).
        p_wp_contact: the contact point in R2's tool frame [mm], shape (3,).
        deviations_mm: per model set, the deviation at each configuration [mm], shape (N,).
        truth: the true tip's deviation at the readings when known (simulation), else None.
        unconfirmed: configurations where the probe reported no contact (left out of the statistics).
    """

    models: dict[str, DeviationStats]
    q: np.ndarray
    p_wp_contact: np.ndarray
    deviations_mm: dict[str, np.ndarray] = field(default_factory=dict)
    truth: DeviationStats | None = None
    unconfirmed: int = 0

    @property
    def configurations(self) -> int:
        return int(self.q.shape[0])

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"models": {k: vars(v) for k, v in self.models.items()},
                               "configurations": self.configurations, "unconfirmed": self.unconfirmed,
                               "contact_point_mm": self.p_wp_contact.tolist(),
                               "method": "predicted relative position at true-contact configurations"}
        if self.truth is not None:
            out["truth"] = vars(self.truth)
        return out

    def table(self) -> str:
        """The result as a plain-text table (what ``cellcal validate-dual`` prints)."""
        lines = [f"contact validation on {self.configurations} configurations "
                 f"(predicted gun tip in the workpiece frame vs the contact point)",
                 f"{'model set':<12s} {'mean mm':>8s} {'std mm':>8s} {'max mm':>8s}"]
        for k, s in self.models.items():
            lines.append(f"{k:<12s} {s.mean_mm:8.3f} {s.std_mm:8.3f} {s.max_mm:8.3f}")
        if self.truth is not None:
            lines.append(f"{'(true tip)':<12s} {self.truth.mean_mm:8.3f} {self.truth.std_mm:8.3f} "
                         f"{self.truth.max_mm:8.3f}")
        if self.unconfirmed:
            lines.append(f"{self.unconfirmed} configuration(s) without confirmed contact were left out")
        return "\n".join(lines)


def relative_position(cell: CellSpec, pose_R1: Any, pose_R2: Any, q: np.ndarray) -> np.ndarray:
    """R1's tool point in R2's tool frame [mm], shape (N, 3).

    Args:
        cell: gives each base's pose in the cell frame.
        pose_R1, pose_R2: ``q (N, 6) -> (R (N, 3, 3), p (N, 3))`` in each robot's base frame (``model.fk``).
        q: joint angles [rad], shape (N, 12) (R1 then R2).
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    if q.ndim != 2 or q.shape[1] != 12:
        raise ModelError(f"q must have shape (N, 12) (R1 then R2) [rad], got {q.shape}")
    return relative_from_poses(cell, pose_R1(q[:, :6])[1], pose_R2(q[:, 6:]))


def relative_from_poses(cell: CellSpec, p1: np.ndarray, pose2: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """R1's tool point p1 (N, 3) in R2's tool frame ``pose2 = (R (N, 3, 3), p (N, 3))``, both in base frames [mm]."""
    R2, p2 = pose2
    T1, T2 = cell.robot("R1").T_cell_base, cell.robot("R2").T_cell_base
    p1c = p1 @ T1[:3, :3].T + T1[:3, 3]
    R2c, p2c = T2[:3, :3] @ R2, p2 @ T2[:3, :3].T + T2[:3, 3]
    p_tool2_tool1: np.ndarray = np.einsum("nji,nj->ni", R2c, p1c - p2c)
    return p_tool2_tool1


def evaluate_models(cell: CellSpec, model_sets: dict[str, dict[str, Any]], q: np.ndarray,
                    p_wp_contact: np.ndarray) -> tuple[dict[str, DeviationStats], dict[str, np.ndarray]]:
    """Statistics and per-configuration deviations of each model set (``{label: {"R1": m, "R2": m}}``)."""
    stats, devs = {}, {}
    for label, pair in model_sets.items():
        d = np.linalg.norm(relative_position(cell, pair["R1"].fk, pair["R2"].fk, q) - p_wp_contact, axis=1)
        stats[label], devs[label] = DeviationStats.of(d), d
    return stats, devs


def true_tip_distance(cell: CellSpec, drivers: dict[str, Any], p_wp_contact: np.ndarray) -> Callable[[], float]:
    """A function giving the true distance of the gun tip from the contact point now [mm] (simulated arms)."""
    p = np.asarray(p_wp_contact, dtype=float)

    def distance_mm() -> float:
        t = np.array([drivers["R1"].clock.now()])
        p1 = drivers["R1"].true_pose(t)[1]
        return float(np.linalg.norm(relative_from_poses(cell, p1, drivers["R2"].true_pose(t))[0] - p))

    return distance_mm


#: The order in which collect_contacts moves the arms to each configuration (one at a time, each checked).
CONTACT_ORDER = ("R1", "R2")


def check_contact_sequence(safety: Any, q_plan: np.ndarray, q_start: np.ndarray) -> None:
    """Check every move :func:`collect_contacts` makes, before any motion.

    For each configuration R1 moves first (R2 still at its previous pose), then R2 (R1 at its new pose); each
    joint-space path is checked against limits, floor and the other arm's capsules.

    Args:
        safety: the cell's :class:`~app.collection.safety.CellSafety`.
        q_plan: configurations [rad], shape (N, 12) (R1 then R2).
        q_start: both arms' joint angles now [rad], shape (12,).

    Raises:
        UnsafeTarget: the first unsafe move (its configuration number in the message).
    """
    prev = np.asarray(q_start, dtype=float)
    for i, q in enumerate(np.atleast_2d(np.asarray(q_plan, dtype=float))):
        safety.check_motion("R1", prev[:6], q[:6], {"R2": prev[6:]}, i)
        safety.check_motion("R2", prev[6:], q[6:], {"R1": q[:6]}, i)
        prev = q


def collect_contacts(drivers: dict[str, Any], probe: Any, q_plan: np.ndarray, safety: Any,
                     speed_fraction: float = 0.2, settle_timeout_s: float = 60.0,
                     contact_timeout_s: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Drive both arms through the configurations and record the joint readings where contact is confirmed.

    The whole sequence is checked first (:func:`check_contact_sequence`); then each arm moves in turn through
    :func:`~app.collection.motion.move_safely` (checked again against the other arm's live pose).

    Args:
        drivers: ``{"R1": RobotDriver, "R2": RobotDriver}``, connected.
        probe: a connected contact probe with ``latest`` and ``wait_for_contact`` (:class:`CanContactProbe`).
        q_plan: configurations [rad], shape (N, 12) (R1 then R2).
        safety: the cell's :class:`~app.collection.safety.CellSafety`.
        speed_fraction: fraction of the maximum joint speeds.
        settle_timeout_s: per move [s]. contact_timeout_s: how long to wait for a touch after settling [s].

    Returns:
        ``(readings (N, 12) [rad], confirmed (N,) bool)``.

    Raises:
        UnsafeTarget: a move is unsafe (refused before the first motion when the plan is, else before that move).
        NonFiniteFeedback: an arm's joint feedback is not finite (nothing more moves).
    """

    q_plan = np.atleast_2d(np.asarray(q_plan, dtype=float))
    check_contact_sequence(safety, q_plan, np.concatenate([read_q(drivers[n]) for n in CONTACT_ORDER]))
    readings, confirmed = [], []
    for i, q in enumerate(q_plan):
        for k, name in enumerate(CONTACT_ORDER):
            others = {n: d for n, d in drivers.items() if n != name}
            move_safely(drivers[name], q[6 * k:6 * k + 6], safety, others, speed_fraction, settle_timeout_s, index=i)
        reading = np.concatenate([read_q(drivers[n]) for n in CONTACT_ORDER])
        latest = probe.latest
        ok = latest is not None and latest.touched
        if not ok:
            try:
                probe.wait_for_contact(contact_timeout_s)
                ok = True
            except DriverTimeout:
                logger.warning("configuration %d: no contact confirmed within %.2f s", i, contact_timeout_s)
        readings.append(reading)
        confirmed.append(ok)
    return np.array(readings), np.array(confirmed)


def contact_plan(cell: CellSpec, twins: dict[str, Any], n: int) -> tuple[np.ndarray, np.ndarray]:
    """Configurations where the true tip touches the point: planned with the twins along the default sweep.

    Returns:
        ``(q (n, 12) [rad], p_wp_contact (3,) [mm])``; the point is where the true tip is at ``Q_REF_DEG``.

    Raises:
        ModelError: a configuration could not be solved (its reason is in the message).
    """

    truth = {k: PhysicsModel(k, "twin", t.geometry, t.effects) for k, t in twins.items()}
    planner = DualPlanner(cell, truth["R1"], truth["R2"], PlannerOptions(compile="off"))
    q0 = np.radians(Q_REF_DEG)
    T_rel = relative_pose(planner, q0)
    plan = planner.plan(sweep_path(planner, n), T_rel, q0)
    if not plan.converged:
        i = plan.failed[0]
        raise ModelError(f"contact configuration {i} could not be planned: {plan.waypoints[i].reason}")
    return plan.q(), T_rel[:3, 3].copy()


def run_sim_validation(cell: CellSpec, n: int = 20, model_sets: dict[str, dict[str, Any]] | None = None,
                       methods: tuple[str, ...] | None = None, options: Any = None, grid: Any = None,
                       tolerance_mm: float = 0.1, channel: str = "cellcal-validate") -> ContactValidation:
    """The whole check on the simulated cell: twins, fitted model sets (unless given), contacts, statistics.

    Args:
        cell: the loaded cell.
        n: number of contact configurations (>= 2).
        model_sets: ``{label: {"R1": model, "R2": model}}``; fitted on twin data when None.
        methods: model sets to fit when ``model_sets`` is None (default ``SIM_METHODS``).
        options: the simulated cell, :class:`~app.collection.runtime.sim.SimCellOptions` (default
            :data:`~app.dual.sim.VALIDATION_CELL`).
        grid: where the training anchors lie, :class:`~app.dual.sim.TrainingGrid`.
        tolerance_mm: the simulated probe touches within this distance [mm].
        channel: python-can virtual channel shared by the simulated and the reading probe.
    """

    if n < 2:
        raise ModelError(f"validation needs at least 2 configurations, got {n}")
    options = options or VALIDATION_CELL
    twins = make_twins(cell, options)
    if model_sets is None:
        model_sets = fit_model_sets(cell, twins, methods or SIM_METHODS, options, grid or TrainingGrid())
    q_plan, p_contact = contact_plan(cell, twins, n)
    clock = SimClock(200.0)
    drivers = {k: SimRobotDriver(k, cell.robot(k).robot, twins[k], q0=q_plan[0, 6 * i:6 * i + 6], clock=clock,
                                 config=SimRobotConfig(settle_time_s=0.2)) for i, k in enumerate(("R1", "R2"))}
    try:
        with SimulatedProbe(channel, heartbeat_period_s=0.02) as sim_probe, \
                CanContactProbe(channel, interface="virtual") as probe:
            for d in drivers.values():
                d.connect()
            with SimContactSensor(true_tip_distance(cell, drivers, p_contact), sim_probe, tolerance_mm):
                readings, confirmed = collect_contacts(drivers, probe, q_plan, CellSafety(cell))
    finally:
        for d in drivers.values():
            d.close()
    q = readings[confirmed]
    if not len(q):
        raise ModelError("no contact was confirmed at any configuration")
    stats, devs = evaluate_models(cell, {"nominal": {k: _nominal(cell, k) for k in ("R1", "R2")},
                                         **{k: v for k, v in model_sets.items() if k != "nominal"}}, q, p_contact)
    d_true = np.linalg.norm(relative_position(cell, twins["R1"].pose, twins["R2"].pose, q) - p_contact, axis=1)
    return ContactValidation(stats, q, p_contact, devs, DeviationStats.of(d_true), int((~confirmed).sum()))


def _nominal(cell: CellSpec, name: str) -> Any:

    return ConstantModel(name, "nominal", cell.robot(name).model())
