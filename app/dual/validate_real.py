"""The paper's contact validation on the real cell: a dual plan driven on the controller, contacts from the probe.

The configurations are the waypoints of a dual plan (``cellcal plan-dual --out``) planned to hold the gun tip on
a point of the workpiece (the plan's relative pose). Both arms visit each configuration in turn through the
guarded moves of :func:`app.dual.validate.collect_contacts` (the whole sequence is checked against the cell's
safety model first); the CAN contact probe confirms the touch. Each model set's predicted gun tip in the
workpiece frame at the confirmed readings is compared with the contact point.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np

from app.collection.motion import live_poses
from app.collection.plan_safety import check_plan_safe
from app.collection.plans.reader import read_plan
from app.collection.runtime.cell import Cell
from app.dual.validate import (
    ContactValidation,
    DeviationStats,
    check_contact_sequence,
    collect_contacts,
    evaluate_models,
)
from calibration.errors import CellCalError, ConfigError, DataError, ModelError
from calibration.models import ConstantModel
from drivers.can_probe import CanContactProbe

log = logging.getLogger("cellcal.app")


def contact_configurations(plan_path: str | Path, cell: Any,
                           models: dict[str, Any] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(q (N, 12) [rad], p_wp_contact (3,) [mm])`` from a dual plan file that passes the checks every plan
    passes before it leaves (:func:`app.collection.plan_safety.check_plan_safe`).

    Args:
        plan_path: the dual plan file.
        cell: the cell.
        models: the models the plan was solved with (nominal for a robot not given): the relative pose is
            recomputed from them.

    Raises:
        DataError: not a dual plan file.
        ModelError: the plan has unsolved waypoints or fewer than 2.
        UnsafeTarget: an :class:`~app.collection.plan_safety.UnsafePlan` naming the waypoint.
    """

    plan = read_plan(plan_path, "dual")
    check_plan_safe(cell, plan, str(plan_path), models=models)
    unsolved = [i for i, w in enumerate(plan.waypoints) if not w.converged]
    if unsolved:
        raise ModelError(f"{plan_path}: waypoints {unsolved[:5]} are not solved; validate only a fully solved plan")
    q = plan.q()
    if len(q) < 2:
        raise ModelError(f"{plan_path}: a contact validation needs at least 2 configurations, got {len(q)}")
    if plan.T_wp_gun is None:
        raise DataError(plan_path, None, "T_wp_gun", "missing: a contact validation needs the relative pose the plan "
                                                     "held")
    return q, plan.T_wp_gun[:3, 3].copy()


def open_probe(cell: Any) -> Any:
    """The cell's CAN contact probe (``probe`` block), not yet connected.

    Raises:
        ConfigError: the cell file has no probe block.
    """

    p = cell.probe
    if p is None:
        raise ConfigError(cell.path, "probe", "no probe block: the contact validation needs the CAN probe's "
                                              "interface and channel (or run with --sim)")
    return CanContactProbe(p.channel, interface=p.interface, base_id=p.base_id, bitrate=p.bitrate)


def run_real_validation(cell: Any, rt: Cell, safety: Any, q_plan: np.ndarray, p_contact: np.ndarray,
                        model_sets: dict[str, dict[str, Any]], probe: Any, *,
                        speed_fraction: float = 0.2) -> ContactValidation:
    """Drive the configurations on the real arms, confirm contacts, and score every model set.

    Args:
        cell: the cell. rt: the open :class:`~app.collection.runtime.cell.Cell` (a RealCell of both arms).
        safety: the cell's safety checker. q_plan: configurations [rad] (N, 12). p_contact: the point [mm] (3,).
        model_sets: ``{label: {"R1": model, "R2": model}}``; the nominal pair is always added.
        probe: a connected contact probe.

    Raises:
        UnsafeTarget: a move of the sequence is unsafe (before any motion).
        CellCalError: no contact was confirmed at any configuration.
    """

    now = live_poses(rt.drivers)
    check_contact_sequence(safety, q_plan, np.concatenate([now["R1"], now["R2"]]))
    readings, confirmed = collect_contacts(rt.drivers, probe, q_plan, safety, speed_fraction)
    q = readings[confirmed]
    if not len(q):
        raise CellCalError("no contact was confirmed at any configuration; check the probe and the plan's "
                           "relative pose")
    nominal = {k: ConstantModel(k, "nominal", cell.robot(k).model()) for k in ("R1", "R2")}
    stats, devs = evaluate_models(cell, {"nominal": nominal, **{k: v for k, v in model_sets.items()
                                                                if k != "nominal"}}, q, p_contact)
    return ContactValidation(stats, q, p_contact, devs, None, int((~confirmed).sum()))


__all__ = ["DeviationStats", "contact_configurations", "open_probe", "run_real_validation"]
