"""A dual plan's controller targets as one INFORM job (``export-targets --jbi``).

One two-group job, ``///GROUP1 RB1`` (R1) and ``///GROUP2 RB2`` (R2), one coordinated line per waypoint
(``MOVJ C00000 VJ=.. +MOVJ C00001 VJ=..``): a dual plan's waypoints are pairs that hold the relative tool pose only
together, and two separate jobs would let one arm run ahead of the other. The pulses are the robot YAML's
convention, ``pulse = pulse_zero + pulse_sign * q_deg * pulses_per_deg`` rounded
(:meth:`cell_config.loader.RobotSpec.to_pulses`, the same numbers as the targets CSV's pulse columns); R1 is RB1
and R2 is RB2, the controller's robot numbering of this cell (its MotoROS groups 0 and 1).
"""

from __future__ import annotations

from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from app.jobs.jbi import JobError, pulse_job

#: The controller's robot unit of each arm of the cell (one control group each, in this order).
JOB_UNITS: dict[str, str] = {"R1": "RB1", "R2": "RB2"}
#: Default joint speed of the job's moves [% of each joint's maximum speed]: slow, for a first run on the cell.
JOB_SPEED_PCT = 10.0


def job_bytes(rows: list[dict[str, Any]], path: str | Path, speed_pct: float = JOB_SPEED_PCT,
              date: datetime | None = None) -> bytes:
    """The two-group INFORM job of export rows (:func:`app.dual.export_targets.checked_rows`), named after
    ``path``'s stem.

    Raises:
        JobError: ``path`` is not a ``.JBI`` file, a stem that is not a job name, a speed outside VJ's range.
    """
    path = Path(path)
    if path.suffix.upper() != ".JBI":
        raise JobError(path, None, f"unknown job file type {path.suffix!r}; valid: .JBI")
    steps: dict[int, dict[str, list[int]]] = {}
    for r in rows:
        steps.setdefault(r["index"], {})[JOB_UNITS[r["robot"]]] = [int(v) for v in r["pulses"]]
    return pulse_job(path.stem, list(steps.values()), speed_pct, date or datetime.now(UTC))
