"""Recalibration: fit a new model, compare it with the one in service on fresh validation poses, swap if better.

The model folder holds the model in service as ``current.yaml``. A recalibration fits a candidate (from a
session collected now from a plan, or from an existing session), measures fresh validation poses, and
compares the position RMS error of both models on them. The candidate replaces ``current.yaml`` only when
its RMS is strictly lower; the replaced model is archived as ``previous/<timestamp>.yaml``. A candidate that
is not better is kept out of service and filed as ``rejected/<timestamp>.yaml`` for the record. A model in
service that fails validation (a NaN parameter, a matrix that is not a rotation, an unknown method) is never
kept: the decision reports why, and a valid candidate replaces it. A model of another robot there means the
wrong folder, and the recalibration stops before any motion.
"""

from __future__ import annotations

import logging
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from calibration.data.files import check_output_path
from calibration.data.recording import Recording
from calibration.errors import ConfigError, DataError, ModelError
from calibration.evaluation.metrics import error_stats, errors
from calibration.frames.rebase import rebase_auto, workspace_configurations
from calibration.kinematics.poe import PoeModel
from calibration.models import KinematicModel, load_model, save_model
from calibration.models.checks import check_model_for

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
        current_problem: why the model in service was unusable (then ``current`` is None and a valid candidate
            replaced it), or None.
        tolerance_mm: the acceptance tolerance the candidate was held to when nothing usable was in service
            [mm], or None.
        refused: the candidate was not installed although nothing usable was in service, because its position
            RMS on the validation poses exceeds ``tolerance_mm`` (it is filed in ``rejected/``).
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
    current_problem: str | None = None
    tolerance_mm: float | None = None
    refused: bool = False

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
                "decision": "replaced" if self.archived else "installed" if self.replaced else
                "refused" if self.refused else "kept",
                "validation_samples": self.validation_samples,
                "candidate": {"position_rms_mm": self.candidate_rms_mm, "validation": self.candidate},
                "current": None if self.current is None else {"position_rms_mm": self.current_rms_mm,
                                                              "validation": self.current},
                "current_path": str(self.current_path), "archived": str(self.archived) if self.archived else None,
                "rejected": str(self.rejected) if self.rejected else None,
                "current_problem": self.current_problem, "tolerance_mm": self.tolerance_mm}

    def summary(self) -> str:
        """One line saying what happened, with both figures."""
        new = f"candidate {self.method} {self.candidate_rms_mm:.4f} mm RMS"
        if self.refused:
            had = f"the unusable model in service ({self.current_problem}) stays" if self.current_problem else \
                "no model in service"
            return (f"{self.robot}: refused {new} on {self.validation_samples} validation poses: above "
                    f"--tolerance-mm {self.tolerance_mm:g} (the wrong robot or recording, or a failed fit?); "
                    f"{had}; candidate filed as {self.rejected}")
        if self.current_problem is not None:
            return (f"{self.robot}: replaced the unusable model in service ({self.current_problem}) with {new} on "
                    f"{self.validation_samples} validation poses")
        if self.current is None:
            return f"{self.robot}: no model in service; installed {new} on {self.validation_samples} validation poses"
        old = f"model in service {self.current_rms_mm:.4f} mm RMS"
        # the difference too: both rounded to 0.1 um read 'replaced: 0.1812 < 0.1812' (new-user run)
        by = f"{abs(self.current_rms_mm - self.candidate_rms_mm):.2g} mm"
        if self.replaced:
            return (f"{self.robot}: replaced: {new} < {old} (lower by {by}) on {self.validation_samples} validation "
                    "poses")
        return (f"{self.robot}: kept the model in service: {new} >= {old} (higher by {by}) on "
                f"{self.validation_samples} validation poses")


def _stamp(folder: Path) -> Path:
    """A new ``<timestamp>.yaml`` path in ``folder`` (suffixed when the second is taken)."""
    base = time.strftime("%Y%m%dT%H%M%S")
    path, k = folder / f"{base}.yaml", 1
    while path.exists():
        path, k = folder / f"{base}_{k}.yaml", k + 1
    return path


@dataclass(frozen=True)
class InService:
    """What the model folder's ``current.yaml`` holds.

    Attributes:
        model: the usable model in service, or None.
        problem: why the file in service cannot be used (a value not finite, a rotation that is not one, an
            unknown method, a malformed file), or None; an unusable model is replaced by any valid candidate.
    """

    model: KinematicModel | None
    problem: str | None = None


def model_in_service(model_dir: Path, robot: str, nominal: PoeModel | None = None) -> InService:
    """The model in service in ``model_dir``: usable, absent, or unusable with the reason.

    Args:
        model_dir: the model folder.
        robot: the arm being recalibrated.
        nominal: its nominal geometry (robot YAML), to refuse another robot type's model.

    Raises:
        DataError: ``current.yaml`` is a valid model of another robot (the wrong folder: nothing is touched).
        OutputError: ``current.yaml`` is a symlink, a folder or a device (it would have to be replaced).
    """
    path = Path(model_dir) / CURRENT
    if not path.exists() and not path.is_symlink():
        return InService(None)
    check_output_path(path)
    try:
        model = load_model(path)
    except DataError as e:
        return InService(None, f"{e.key}: {e.reason}" if getattr(e, "key", "") else e.reason)
    check_model_for(model, robot, nominal, path)
    return InService(model)


def _validation_stats(model: KinematicModel, validation: Recording) -> dict[str, Any]:
    return error_stats(errors(model, validation))


def decide_and_install(model_dir: str | Path, candidate: KinematicModel, validation: Recording,
                       nominal: PoeModel | None = None, tolerance_mm: float | None = None) -> Decision:
    """Compare ``candidate`` with the model in service on ``validation``; install it only when it is better.

    Better means a strictly lower position RMS error [mm] on the validation poses. A model in service that is
    unusable (its file fails validation, or its validation errors are not finite) never counts as better:
    the problem is reported in the decision and a valid candidate replaces it (the old file is archived).

    With nothing usable in service there is no model to beat, so the candidate is held to the acceptance
    tolerance instead: a position RMS above ``tolerance_mm`` (the largest error allowed on a pose) means most
    poses fail acceptance, which no calibration engineer would put into service as the first model (R1's
    session fitted as R2 gives hundreds of mm). It is then refused: filed in ``rejected/``, nothing installed
    (``decision.refused``). A candidate within the tolerance whose largest error exceeds it is installed with a
    warning; so is one above the tolerance that beats a usable model in service (it is better than what runs).

    Args:
        model_dir: the model folder.
        candidate: the new model.
        validation: the fresh validation poses.
        nominal: the robot's nominal geometry, to refuse a model in service of another robot type.
        tolerance_mm: acceptance tolerance [mm] for a candidate with nothing usable in service; None: no check.

    Raises:
        DataError: the model in service is for another robot, or there are no validation poses.
        ModelError: the candidate's own validation errors are not finite (nothing is installed).
    """
    model_dir = Path(model_dir)
    if len(validation) == 0:
        raise DataError(validation.source, None, None, "no validation poses to compare the models on")
    service = model_in_service(model_dir, candidate.robot, nominal)
    cand_stats = _validation_stats(candidate, validation)
    if not math.isfinite(cand_stats["position_mm"]["rms"]):
        raise ModelError(f"the candidate {candidate.method} model gives non-finite errors on the validation poses; "
                         "nothing installed")
    cur_stats, problem = None, service.problem
    if service.model is not None:
        cur_stats = _validation_stats(service.model, validation)
        if not math.isfinite(cur_stats["position_mm"]["rms"]):
            cur_stats, problem = None, "its errors on the validation poses are not finite"
    cand_rms = cand_stats["position_mm"]["rms"]
    refused = cur_stats is None and tolerance_mm is not None and cand_rms > tolerance_mm
    better = not refused and (cur_stats is None or cand_rms < cur_stats["position_mm"]["rms"])
    current_path = model_dir / CURRENT
    archived = rejected = None
    if better:
        if current_path.exists():
            archived = _stamp(model_dir / "previous")
            archived.parent.mkdir(parents=True, exist_ok=True)
            os.replace(current_path, archived)
        save_model(candidate, current_path)
    else:
        rejected = _stamp(model_dir / "rejected")
        save_model(candidate, rejected)
    decision = Decision(candidate.robot, candidate.method, better, len(validation), cand_stats, cur_stats,
                        current_path, archived, rejected, problem, tolerance_mm, refused)
    log.info("%s", decision.summary())
    if better and tolerance_mm is not None and cand_stats["position_mm"]["max"] > tolerance_mm:
        log.warning("%s: the installed %s model exceeds the tolerance %g mm on some validation poses (largest "
                    "%.3f mm, RMS %.3f mm)", candidate.robot, candidate.method, tolerance_mm,
                    cand_stats["position_mm"]["max"], cand_rms)
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


def model_to_rebase(model_dir: str | Path, service: InService) -> KinematicModel:
    """The model in service, which ``recalibrate --rebase`` needs (checked before any motion).

    Raises:
        DataError: there is no usable model in service.
    """
    if service.model is None:
        reason = f"it is unusable ({service.problem})" if service.problem else "there is none"
        raise DataError(str(Path(model_dir) / CURRENT), None, None,
                        f"--rebase refits the frames of the model in service, but {reason}; fit one first "
                        "(recalibrate without --rebase)")
    return service.model


def rebase_candidate(model_dir: str | Path, service: InService, train: Recording,
                     joint_limits_rad: tuple[Any, Any] | None = None) -> tuple[KinematicModel, Any]:
    """The candidate of ``recalibrate --rebase``: the model in service with only its base and tool-marker frames
    refitted on ``train`` (a few clusters of the new day, :func:`calibration.frames.rebase.rebase_auto`, as ``cellcal
    rebase``: the candidate the held-out clusters confirm, checked over configurations within ``joint_limits_rad``
    (lower, upper) when given).

    Returns:
        The rebased model (kind ``rebased``) and the :class:`~calibration.frames.rebase.RebaseResult`.

    Raises:
        DataError: there is no usable model in service to rebase.
        ModelError: the frame fit did not converge (nothing is installed).
    """

    model = model_to_rebase(model_dir, service)
    workspace = None if joint_limits_rad is None else workspace_configurations(*joint_limits_rad)
    rebased, result, _ = rebase_auto(model, train, q_workspace=workspace)
    if not result.converged:
        raise ModelError(f"the rebase of the model in service on {train.source} did not converge "
                         f"({result.reason.value}); nothing installed")
    return rebased, result
