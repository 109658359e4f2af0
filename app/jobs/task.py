"""The task a top-up design is chosen for: the joint angles a robot will run, read from a joints CSV, a dual plan
or an INFORM job (:func:`read_task`). In ``jobs`` because a task may be a controller job; the design itself is
:mod:`app.collection.plans.design`."""

from __future__ import annotations

import math

import numpy as np

from app.collection.plans.reader import read_plan
from app.jobs.jbi import JobError, read_job
from calibration.data.recording import read_joints
from calibration.errors import DataError
from cell_config.loader import CellSpec

#: File name endings of a task given as a JBI job, and as a dual plan; any other is a joints CSV.
JOB_SUFFIXES = (".jbi",)
PLAN_SUFFIXES = (".json",)


def read_task(path: str, robot: str, cell: CellSpec) -> np.ndarray:
    """The joint angles [rad] (T, 6) of the task ``robot`` will run: a joints CSV (``q1..q6`` in rad, header or 6
    headerless columns), a dual plan (``.json``: the robot's waypoints; refused waypoints left out) or a JBI job
    (``.jbi``: the robot's PULSE positions, by the cell's pulse convention). Every configuration is checked against
    the robot's joint limits.

    Raises:
        DataError, JobError: an unreadable task, one without a configuration of ``robot``, a Cartesian job position
            (its joint angles depend on the model; teach it in pulses or give the joints), or a joint out of limits.
    """
    from pathlib import Path


    spec = cell.robot(robot).robot
    lower, upper = spec.lower_rad, spec.upper_rad
    suffix = Path(path).suffix.lower()
    if suffix in JOB_SUFFIXES:
        job = read_job(path)
        units = {f"RB{i}": name for i, name in enumerate(cell.robots, start=1)}
        q = []
        for pos in job.positions:
            if units.get(pos.unit) != robot:
                continue
            if pos.postype != "PULSE":
                raise JobError(job.path, pos.line, f"{pos.name} is a Cartesian position ({pos.postype}); the top-up "
                                                   "design reads joint angles: teach the task in pulses or give a "
                                                   "joints CSV")
            q.append(spec.from_pulses(np.asarray(pos.values[:6])))
        if not q:
            raise JobError(job.path, None, f"no position of {robot} in the job (units: "
                                           f"{', '.join(f'{u} = {r}' for u, r in units.items())})")
        q_task = np.array(q)
    elif suffix in PLAN_SUFFIXES:
        plan = read_plan(path, "dual")
        if robot not in ("R1", "R2"):
            raise DataError(path, None, None, f"a dual plan holds the waypoints of R1 and R2, not of {robot}")
        q_task = np.array([getattr(w, f"q_{robot}") for w in plan.waypoints if w.converged])
        if not len(q_task):
            raise DataError(path, None, None, f"the plan holds no solved waypoint of {robot}")
    else:
        return read_joints(path, lower, upper)
    outside = (q_task < lower - 1e-9) | (q_task > upper + 1e-9)
    if outside.any():
        i, j = (int(v) for v in np.argwhere(outside)[0])
        raise DataError(path, i + 1, f"q{j + 1}", f"{math.degrees(q_task[i, j]):.6g} deg is outside {robot}'s joint "
                                                  "limits")
    return q_task
