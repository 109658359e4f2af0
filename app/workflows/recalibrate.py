"""Recalibration: fit a new model, compare it with the one in service on fresh validation poses, swap if better.

The model folder holds the model in service as ``current.yaml``. A recalibration fits a candidate (from a
session collected now from a plan, or from an existing session), measures fresh validation poses, and
compares the position RMS error of both models on them. The candidate replaces ``current.yaml`` only when
its RMS is strictly lower; the replaced model is archived as ``previous/<timestamp>.yaml``. A candidate that
is not better is kept out of service and filed as ``rejected/<timestamp>.yaml`` for the record. A model in
service that fails validation (a NaN parameter, a matrix that is not a rotation, an unknown method) is never
kept: the decision reports why, and a valid candidate replaces it. A model of another robot there means the
wrong folder, and the recalibration stops before any motion.

:func:`recalibrate` is the whole workflow of ``cellcal recalibrate`` (collect, fit or rebase, validate,
install): plain :class:`RecalibrationInputs` in, a :class:`RecalibrationResult` out; it prints nothing, its
lines and questions go through :class:`RecalibrationHooks`.
"""

from __future__ import annotations

import logging
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from app.collection.plans.reader import read_arm_plan
from app.collection.runtime.cell import Cell
from app.collection.session_store import require_session
from app.workflows.inputs import read_recording_for
from calibration.data.files import check_output_path
from calibration.data.recording import Recording
from calibration.errors import CellCalError, ConfigError, DataError, ModelError, ModelFileError
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
        current_rms_mm = self.current_rms_mm  # None exactly when no model was in service
        if current_rms_mm is None:
            return f"{self.robot}: no model in service; installed {new} on {self.validation_samples} validation poses"
        old = f"model in service {current_rms_mm:.4f} mm RMS"
        # the difference too: both rounded to 0.1 um read 'replaced: 0.1812 < 0.1812' (new-user run)
        by = f"{abs(current_rms_mm - self.candidate_rms_mm):.2g} mm"
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
        return InService(None, f"{e.key}: {e.reason}" if isinstance(e, ModelFileError) and e.key else e.reason)
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


@dataclass(frozen=True)
class RecalibrationInputs:
    """What ``cellcal recalibrate`` was asked, checked by the command before the workflow runs.

    Attributes:
        robot: the arm recalibrated (a name in the cell).
        model_dir: the model folder (checked by :func:`check_model_dir`).
        plan: the training plan to collect (a collection :class:`~app.collection.plans.collection.Plan`), or None
            with ``session``.
        session: an existing training session folder to reuse, or None with ``plan``.
        validation: how many fresh validation poses to measure (at least 1).
        validation_seed: the seed of the validation poses; None: from the clock.
        method: the candidate's fitting method (not used with ``rebase``).
        rebase: refit only the base and tool-marker frames of the model in service.
        added: the ``--add`` stand-alone pose files and their recordings (checked against the robot).
        add_weight: their weight in the fit (each added pose's rows repeated).
        tolerance: the acceptance :class:`~app.reports.acceptance.Tolerance`.
        dry_run: only check the plans from where the arm stands (no motion, nothing fitted).
        report: the HTML report's path, or None.
        command: the command line, for the report.
    """

    robot: str
    model_dir: Path
    plan: Any
    session: Path | None
    validation: int
    validation_seed: int | None
    method: str
    rebase: bool
    added: tuple[tuple[str, Recording], ...]
    add_weight: int
    tolerance: Any
    dry_run: bool = False
    report: str | None = None
    command: str = ""


def checked_inputs(robot: Any, model_dir: str | Path, plan: str | None, session: str | None, validation: int,
                   method: str, added: Sequence[str], **settings: Any) -> RecalibrationInputs:
    """recalibrate's arguments checked and its input files read, before any motion: the model folder
    (:func:`check_model_dir`), the validation count, the plan (one arm's, ``robot``'s), the session to reuse
    (``robot``'s, complete for ``method``) and the added poses.

    Args:
        robot: the arm's cell entry.
        settings: the other :class:`RecalibrationInputs` fields, as they are (``validation_seed``, ``rebase``,
            ``add_weight``, ``tolerance``, ``dry_run``, ``report``, ``command``).

    Raises:
        ConfigError: the model folder is a file; CellCalError: fewer than 1 validation pose; DataError: a plan,
            session or recording that is unreadable or not ``robot``'s, or an incomplete session.
    """
    folder = check_model_dir(model_dir)
    if validation < 1:
        raise CellCalError(f"--validation must be at least 1, got {validation}")
    plan_read = read_arm_plan(plan, robot.name) if plan else None
    if session:
        require_session(session, robot.name, ("anchor", "perturb", "cpa") if method == "cpa" else
                        ("anchor", "perturb"), purpose="recalibrate")
    poses = tuple((path, read_recording_for(path, robot)) for path in added)  # bad poses: refused before motion
    return RecalibrationInputs(robot=robot.name, model_dir=folder, plan=plan_read,
                               session=Path(session) if session else None, validation=validation, method=method,
                               added=poses, **settings)


@dataclass(frozen=True)
class RecalibrationHooks:
    """How the workflow talks to its caller (it prints nothing itself).

    Attributes:
        say: one line for the operator (the CLI prints it on stdout).
        warn: one warning line (the CLI prints it on stderr).
        confirm: asks before the first motion with this summary; raises to refuse.
        stop_hint: what an interruption from now on leaves behind (the CLI's Ctrl-C line).
        dry_run: checks a plan from where the arm stands (runtime, safety, plan, collect config) and returns the
            exit code, for ``inputs.dry_run``.
        progress: show progress bars while collecting.
        motion: the collection config and the safety checker (asked once the model folder is checked).
        epoch_progress: the neural interpolators' epoch bar (``FitOptions.epoch_progress``), or None.
    """

    say: Callable[[str], None]
    warn: Callable[[str], None]
    confirm: Callable[[str], None]
    stop_hint: Callable[[str], None]
    dry_run: Callable[[Any, Any, Any, Any], int]
    motion: Callable[[], tuple[Any, Any]]
    progress: bool = False
    epoch_progress: Any = None


@dataclass(frozen=True)
class RecalibrationResult:
    """What a recalibration did.

    Attributes:
        decision: the :class:`Decision` (None after a dry run).
        model: the candidate (with its provenance), or None after a dry run.
        in_service: the usable model that was in service before, or None.
        rebased: the :class:`~calibration.frames.rebase.RebaseResult` with ``rebase``, else None.
        validation: the fresh validation recording, or None after a dry run.
        record: the provenance of the inputs (taken before the decision moved the model in service).
        exit_code: the dry run's exit code (0 otherwise).
    """

    decision: Decision | None
    model: KinematicModel | None = None
    in_service: KinematicModel | None = None
    rebased: Any = None
    validation: Recording | None = None
    record: Any = None
    exit_code: int = 0

    def to_json(self) -> dict[str, Any]:
        """The ``--json`` of ``recalibrate``: the decision, and with ``--rebase`` the frame fit."""
        if self.decision is None:
            raise ValueError("a dry run decides nothing: it writes its own JSON")
        r = self.rebased
        return {**self.decision.to_json(), **({} if r is None else {"rebase": {
            "samples": r.n_samples, "fitted_directions": r.fitted, "held": list(r.held),
            "position_mean_mm": {"before": r.mean_before_mm, "after": r.mean_after_mm},
            "objective_rms": {"before": r.objective_before, "after": r.objective_after},
            "shrink": r.shrink}})}


@dataclass(frozen=True)
class _Work:
    """The run's folders and the service it started from."""

    service: InService
    work: Path
    session: Path
    cpa: bool


def recalibrate(cell: Any, runtime: Cell, inputs: RecalibrationInputs, hooks: RecalibrationHooks) -> RecalibrationResult:
    """Collect (or reuse) a training session and fresh validation poses, fit (or rebase) a candidate, and install
    it only when it beats the model in service on them (:func:`decide_and_install`); write the report if asked.

    Args:
        cell: the cell description.
        runtime: the cell at run time (a SimCell or RealCell, not yet entered).
        inputs: what was asked.
        hooks: the caller's output, confirmation, interruption and motion hooks.

    Raises:
        DataError: the model in service is another robot's, or ``rebase`` has none to refit.
        ModelError: the candidate failed (a rebase that did not converge, non-finite errors).
    """
    robot = cell.robot(inputs.robot)
    service = model_in_service(inputs.model_dir, inputs.robot, robot.model())  # another robot's: stop before motion
    if inputs.rebase:
        model_to_rebase(inputs.model_dir, service)  # nothing to rebase: stop before motion
    if service.problem:
        log.warning("the model in service %s is unusable (%s); a valid candidate will replace it",
                    inputs.model_dir / CURRENT, service.problem)
    work = inputs.model_dir / "sessions" / time.strftime("%Y%m%dT%H%M%S")
    run = _Work(service, work, inputs.session if inputs.session else work / "train", inputs.method == "cpa")
    code = _collect(robot, runtime, inputs, hooks, hooks.motion(), run)
    if code is not None:
        return RecalibrationResult(None, exit_code=code)
    return _fit_and_decide(robot, inputs, hooks, run)


def _collect(robot: Any, runtime: Cell, inputs: RecalibrationInputs, hooks: RecalibrationHooks,
             motion: tuple[Any, Any], run: _Work) -> int | None:
    """Measure the training plan (if any) and the fresh validation poses; the dry run's exit code, else None."""
    from app.collection import collect
    from app.collection.plans.session import validation_plan
    from calibration.models import ConstantModel

    config, safety = motion
    seed = inputs.validation_seed if inputs.validation_seed is not None else int(time.time()) % 100_000
    in_use, in_use_name = ((run.service.model, "the model in service") if run.service.model is not None else
                           (ConstantModel(robot.name, "nominal", robot.model(), 0, {}),
                            f"the nominal {inputs.robot}"))  # what -v's line per target compares with
    plan, session = inputs.plan, run.session
    with runtime as rt:
        parked = {n: d.read_joints().q for n, d in rt.others(inputs.robot).items()}
        val_plan = validation_plan(inputs.robot, safety, parked, inputs.validation, seed=seed)
        if inputs.dry_run:
            from app.collection.plans.collection import Plan

            both = Plan((plan.targets if plan is not None else ()) + val_plan.targets, val_plan.params)
            return hooks.dry_run(rt, safety, both, config)
        hooks.confirm(f"{inputs.robot} will visit {len(plan) if plan is not None else 0} training and "
                      f"{len(val_plan)} validation targets at {config.speed_fraction:g} of full speed")
        if plan is not None:  # what Ctrl-C says (app.cli.commands.main): recalibrate itself has no --resume
            hooks.stop_hint(f" (nothing installed; the training session so far is {session}: finish it with "
                            f"cellcal collect --robot {inputs.robot} --session {session} --resume, then "
                            f"recalibrate --session {session})")
            collect.collect_arm(rt, safety, inputs.robot, plan, session, config, progress=hooks.progress,
                                model=in_use, model_name=in_use_name)
        hooks.stop_hint(f" (nothing installed; recalibrate --session {session} reuses the training session)")
        collect.collect_arm(rt, safety, inputs.robot, val_plan, run.work / "validation", config,
                            progress=hooks.progress, model=in_use, model_name=in_use_name)
    return None


def _fit_and_decide(robot: Any, inputs: RecalibrationInputs, hooks: RecalibrationHooks,
                    run: _Work) -> RecalibrationResult:
    """Export the recordings, fit (or rebase) the candidate, judge it on the validation poses, report."""
    from app.collection.collect import export
    from app.reports.provenance import provenance, with_provenance
    from calibration.data.recording import read_recording, with_added

    limits = (robot.robot.lower_rad, robot.robot.upper_rad)
    work = run.work
    export(run.session, work / "train.csv", kinds=("anchor", "perturb"))
    cpa = None
    if run.cpa:
        export(run.session, work / "cpa.csv", kinds=("cpa",))
        cpa = read_recording(work / "cpa.csv", *limits)
    export(work / "validation", work / "validation.csv")
    train = with_added(read_recording(work / "train.csv", *limits), [r for _, r in inputs.added],
                       weight=inputs.add_weight)  # --add: stand-alone poses
    model, rebased = _fit_candidate(robot, inputs, hooks, run.service, train, cpa)
    sources: list[tuple[str, str | Path | None]] = [("train", work / "train.csv"), *(("add", a) for a, _ in inputs.added),
               ("cpa", work / "cpa.csv" if cpa else None), ("validation", work / "validation.csv")]
    if inputs.rebase:
        sources.append(("model rebased", inputs.model_dir / CURRENT))
    model = with_provenance(model, provenance(sources))
    validation = read_recording(work / "validation.csv", *limits)
    in_service = run.service.model
    record = provenance(sources + ([("model in service", inputs.model_dir / CURRENT)] if in_service is not None
                                   else []))  # before the decision moves the model in service to previous/
    hooks.stop_hint("")
    decision = decide_and_install(inputs.model_dir, model, validation, robot.model(), inputs.tolerance.position_mm)
    return RecalibrationResult(decision, model, in_service, rebased, validation, record)


def _fit_candidate(robot: Any, inputs: RecalibrationInputs, hooks: RecalibrationHooks, service: InService,
                   train: Recording, cpa: Recording | None) -> tuple[KinematicModel, Any]:
    """The candidate: the model in service rebased on ``train``, or a new ``inputs.method`` fit of it."""
    if inputs.rebase:
        model, rebased = rebase_candidate(inputs.model_dir, service, train,
                                          (robot.robot.lower_rad, robot.robot.upper_rad))
        hooks.say(rebased.summary())
        return model, rebased
    from app.workflows.fit import gross_rows_warning
    from calibration.methods.fitter import Fitter
    from calibration.methods.options import FitOptions

    fitter = Fitter.for_arm(robot.arm(), train, cpa, FitOptions(epoch_progress=hooks.epoch_progress))
    warning = gross_rows_warning(fitter)  # the rows are in the model's info too
    if warning:
        hooks.warn(warning)
    model, _ = fitter.fit(inputs.method)
    if model.info.get("warning"):  # as fit warns (the directions the training poses leave unseen)
        hooks.warn(f"warning: {model.info['warning']}")
    return model, None


def recalibration_rule(candidate: Any, in_service: Any, tolerance: Any) -> str:
    """The report's why for a recalibration: the models' parameter counts and the test that decided."""
    new = f"The candidate {candidate.method} has {candidate.n_parameters} parameters, fitted on the training poses"
    if in_service is None:
        return (f"{new}. With no model in service, the rule is the tolerance: it is installed when its position RMS "
                f"on the fresh validation poses (measured after the fit, not used by it) is at most "
                f"{tolerance.position_mm:g} mm.")
    return (f"{new}; the model in service ({in_service.method}) has {in_service.n_parameters}. The rule: the candidate "
            "replaces it only when its position RMS on the fresh validation poses (measured after the fit, used by "
            "neither) is lower.")


def write_report(result: RecalibrationResult, inputs: RecalibrationInputs) -> Any:
    """The recalibration's HTML report: candidate and model in service on the validation poses, the decision."""
    from app.reports.page import Page, write_html
    from app.reports.sections import evaluation_section

    model, in_service, decision, tolerance = result.model, result.in_service, result.decision, inputs.tolerance
    if model is None or decision is None or result.validation is None or inputs.report is None:
        raise ValueError("a report needs a decision (not a dry run) and a report path")
    models = {f"candidate {model.method}": model}
    if in_service is not None:
        models[f"in service {in_service.method}"] = in_service
    archived = f" (the previous model archived as {decision.archived})" if decision.archived else ""
    section = evaluation_section(f"Recalibration of {inputs.robot}", models, result.validation, inputs.report,
                                 tolerance, "the fresh validation recording",  # the model in service after the decision
                                 recommended=f"candidate {model.method}" if decision.replaced or in_service is None
                                 else f"in service {in_service.method}",
                                 why=[decision.summary(), recalibration_rule(model, in_service, tolerance)],
                                 next_steps=[f"{decision.current_path} now holds the {model.method} candidate"
                                             + archived + "; sign below to accept it."
                                             if decision.replaced or in_service is None else
                                             f"Nothing to install: {decision.current_path} still holds the model "
                                             "in service; sign below to accept that it stays."])
    return write_html(Page(section.title, inputs.command, tolerance, result.record, [section]), inputs.report)
