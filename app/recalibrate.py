"""Recalibration: fit a new model, compare it with the one in service on fresh validation poses, swap if better.

The model folder holds the model in service as ``current.yaml``. A recalibration fits a candidate (from a
session collected now from a plan, or from an existing session), measures fresh validation poses, and
compares the position RMS error of both models on them. The candidate replaces ``current.yaml`` only when
its RMS is strictly lower; the replaced model is archived as ``previous/<timestamp>.yaml``. A candidate that
is not better is kept out of service and filed as ``rejected/<timestamp>.yaml`` for the record.
"""

from __future__ import annotations

import logging
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from calibration.errors import ConfigError, DataError
from calibration.metrics import error_stats, errors
from calibration.models import KinematicModel, load_model, save_model
from calibration.recording import Recording

log = logging.getLogger("cellcal.app")

CURRENT = "current.yaml"


@dataclass(frozen=True)
class Decision:
    """The outcome of a recalibration.

    Attributes:
        robot: robot name.
        method: the candidate's method.
        replaced: the candidate is now in service.
        validation_samples: fresh validation poses both models were judged on.
        candidate: the candidate's validation statistics (``compare`` JSON shape).
        current: the previous model's validation statistics, None when there was no model in service.
        current_path: ``current.yaml``.
        archived: where the replaced model went (``previous/<timestamp>.yaml``), or None.
        rejected: where a candidate that was not better went (``rejected/<timestamp>.yaml``), or None.
    """

    robot: str
    method: str
    replaced: bool
    validation_samples: int
    candidate: dict[str, Any]
    current: dict[str, Any] | None
    current_path: Path
    archived: Path | None
    rejected: Path | None

    @property
    def candidate_rms_mm(self) -> float:
        """Candidate's position RMS on the validation poses [mm]."""
        return float(self.candidate["position_mm"]["rms"])

    @property
    def current_rms_mm(self) -> float | None:
        """Previous model's position RMS on the validation poses [mm], None if there was none."""
        return None if self.current is None else float(self.current["position_mm"]["rms"])

    def to_json(self) -> dict[str, Any]:
        return {"robot": self.robot, "method": self.method, "replaced": self.replaced,
                "decision": "replaced" if self.replaced and self.current else "installed" if self.replaced else "kept",
                "validation_samples": self.validation_samples,
                "candidate": {"position_rms_mm": self.candidate_rms_mm, "validation": self.candidate},
                "current": None if self.current is None else {"position_rms_mm": self.current_rms_mm,
                                                              "validation": self.current},
                "current_path": str(self.current_path), "archived": str(self.archived) if self.archived else None,
                "rejected": str(self.rejected) if self.rejected else None}

    def summary(self) -> str:
        """One line saying what happened, with both figures."""
        new = f"candidate {self.method} {self.candidate_rms_mm:.4f} mm RMS"
        if self.current is None:
            return f"{self.robot}: no model in service; installed {new} on {self.validation_samples} validation poses"
        old = f"model in service {self.current_rms_mm:.4f} mm RMS"
        if self.replaced:
            return f"{self.robot}: replaced: {new} < {old} on {self.validation_samples} validation poses"
        return f"{self.robot}: kept the model in service: {new} >= {old} on {self.validation_samples} validation poses"


def _stamp(folder: Path) -> Path:
    """A new ``<timestamp>.yaml`` path in ``folder`` (suffixed when the second is taken)."""
    base = time.strftime("%Y%m%dT%H%M%S")
    path, k = folder / f"{base}.yaml", 1
    while path.exists():
        path, k = folder / f"{base}_{k}.yaml", k + 1
    return path


def current_model(model_dir: Path, robot: str) -> KinematicModel | None:
    """The model in service in ``model_dir`` (None when there is none).

    Raises:
        DataError: ``current.yaml`` is unreadable or belongs to another robot.
    """
    path = Path(model_dir) / CURRENT
    if not path.exists():
        return None
    model = load_model(path)
    if model.robot != robot:
        raise DataError(path, None, None, f"the model in service is for {model.robot}, not {robot}")
    return model


def decide_and_install(model_dir: str | Path, candidate: KinematicModel, validation: Recording) -> Decision:
    """Compare ``candidate`` with the model in service on ``validation``; install it only when it is better.

    Better means a strictly lower position RMS error [mm] on the validation poses.

    Raises:
        DataError: the model in service is unreadable or for another robot, or there are no validation poses.
    """
    model_dir = Path(model_dir)
    if len(validation) == 0:
        raise DataError(validation.source, None, None, "no validation poses to compare the models on")
    current = current_model(model_dir, candidate.robot)
    cand_stats = error_stats(errors(candidate, validation))
    cur_stats = None if current is None else error_stats(errors(current, validation))
    better = cur_stats is None or cand_stats["position_mm"]["rms"] < cur_stats["position_mm"]["rms"]
    current_path = model_dir / CURRENT
    archived = rejected = None
    if better:
        if current is not None:
            archived = _stamp(model_dir / "previous")
            archived.parent.mkdir(parents=True, exist_ok=True)
            os.replace(current_path, archived)
        save_model(candidate, current_path)
    else:
        rejected = _stamp(model_dir / "rejected")
        save_model(candidate, rejected)
    decision = Decision(candidate.robot, candidate.method, better, len(validation), cand_stats, cur_stats,
                        current_path, archived, rejected)
    log.info("%s", decision.summary())
    return decision


def check_model_dir(model_dir: str | Path) -> Path:
    """Validate the model folder before anything is collected or written.

    Raises:
        ConfigError: the path exists and is not a folder.
    """
    path = Path(model_dir)
    if path.exists() and not path.is_dir():
        raise ConfigError(path, "", "the model folder is a file; give a folder (current.yaml lives in it)")
    return path
