"""Fitting one arm of the cell for ``cellcal fit`` and ``compare``: the training recordings refused when they are
not the arm's, then the frame check or the multi-day fit (:mod:`calibration.frames`) on the arm's
:meth:`~cell_config.loader.CellRobot.arm`, whose fitters are :meth:`calibration.methods.fitter.Fitter.for_arm`.

:func:`fit_model` is the workflow of ``cellcal fit``: plain :class:`FitInputs` in, a :class:`FitResult` out; it prints
nothing, its warning lines go to the caller's ``warn``. :func:`trained_fitter` (shared with ``compare``) reads and
checks the training recordings and returns the fitter with what the checks found (:class:`TrainedFitter`).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from app.reports.provenance import provenance, with_provenance
from app.workflows.inputs import read_recording_for, with_added_poses
from calibration.data.recording import DEFAULT_ADD_WEIGHT
from calibration.errors import CellCalError
from calibration.frames.check import FrameCheck, framed
from calibration.frames.multiday import MultiDayFit, fit_days
from calibration.frames.policy import refuse_another_arms, refuse_repeated
from calibration.methods.options import FitOptions
from calibration.models import KinematicModel, save_model

log = logging.getLogger("cellcal.app")


def gross_rows_warning(fitter: Any) -> str | None:
    """The warning line for the training rows ``fitter`` set aside as gross measurement errors (``Fitter.gross``),
    or None when it set none aside; ``fit``, ``compare`` and ``recalibrate`` give it the same way."""
    gross = getattr(fitter, "gross", None)
    return f"warning: {gross.message()}" if gross is not None and gross.message() else None


def checked_fitter_for(robot: Any, train: Any, cpa: Any | None = None, options: Any | None = None
                       ) -> tuple[Any, Any]:
    """:meth:`Fitter.for_arm` of the arm after a frame check of the training recording against its nominal model.

    When the check finds a frame or tool-registration problem, the fitter fits the frame(s) at fault first and the
    kinematics after (:class:`calibration.frames.check.FramedFit`), and the check's message is logged. A recording that
    even the best frame fit leaves far off (:func:`refuse_unexplained`) is refused.

    Returns:
        The fitter and the :class:`calibration.frames.check.FrameCheck`.

    Raises:
        DataError: the training recording is not this arm's (:func:`refuse_unexplained`).
    """

    arm = robot.arm()
    fitter, check = framed(arm, train, refuse_another_arms(arm, train), cpa, options)
    if check.frame is not None:  # check.found
        log.info("%s Fitting the %s frame%s first, then the kinematics.", check.message(), check.frame,
                 "s" if check.frame is not None and " and " in check.frame else "")
    return fitter, check


def days_fitter_for(robot: Any, trains: list[Any], cpa: Any | None = None, options: Any | None = None) -> Any:
    """Several training recordings in one fit: one arm, per-recording frames (:func:`calibration.frames.multiday.fit_days`).

    Returns:
        The :class:`calibration.frames.multiday.MultiDayFit` (its ``fitter`` fits any method).

    Raises:
        DataError: a training recording is not this arm's (:func:`refuse_unexplained`), or is given twice.
    """

    arm = robot.arm()
    for rec in trains:
        refuse_another_arms(arm, rec)
    refuse_repeated([rec.source for rec in trains])
    return fit_days(arm, trains, cpa=cpa, options=options)


@dataclass(frozen=True)
class TrainingInputs:
    """One arm's training data as the command names it; read and checked by :func:`trained_fitter`.

    Attributes:
        robot: the arm (a robot name in the cell).
        train: training recordings (CSV or Welding_Motoman folders); several are fitted as one arm with a pair of
            frames per recording (days).
        cpa: the single-joint sweep recording for circular point analysis, or None.
        added: stand-alone pose files joined to the one training recording (``--add``).
        add_weight: each added pose's weight against one training pose.
        a: the orientation weight (1641: 1 mm ~ 1 deg).
        epoch_progress: the neural interpolators' epoch bar (``FitOptions.epoch_progress``), or None.
    """

    robot: str
    train: tuple[str, ...]
    cpa: str | None = None
    added: tuple[str, ...] = ()
    add_weight: int = DEFAULT_ADD_WEIGHT
    a: float = 1641.0
    epoch_progress: Any = None


@dataclass(frozen=True)
class TrainedFitter:
    """A fitter on an arm's training recordings, and what checking those found.

    Attributes:
        fitter: the :class:`~calibration.methods.fitter.Fitter` (fits any method).
        robot: the arm's cell entry.
        frame_check: the training recording's :class:`~calibration.frames.check.FrameCheck`; None with several.
        days: the :class:`~calibration.frames.multiday.MultiDayFit` of several recordings; None with one.
    """

    fitter: Any
    robot: Any
    frame_check: FrameCheck | None
    days: MultiDayFit | None

    def gross_rows(self) -> dict[str, Any] | None:
        """The training rows set aside as gross measurement errors (JSON), or None."""
        return None if self.fitter.gross is None else self.fitter.gross.to_json()


def trained_fitter(cell: Any, inputs: TrainingInputs, warn: Callable[[str], None]) -> TrainedFitter:
    """Read and check the training recordings and set up the fitter (:func:`checked_fitter_for`, or
    :func:`days_fitter_for` for several); what the checks found is told through ``warn``, one line each.

    Raises:
        CellCalError: an unreadable recording, another arm's, quaternions in another order, poses added to days.
    """
    robot = cell.robot(inputs.robot)
    trains = [read_recording_for(path, robot) for path in inputs.train]
    trains[0] = with_added_poses(trains, inputs.added, inputs.add_weight, robot)
    cpa = read_recording_for(inputs.cpa, robot) if inputs.cpa else None
    options = FitOptions(a=inputs.a, epoch_progress=inputs.epoch_progress)
    if len(trains) > 1:
        days = days_fitter_for(robot, trains, cpa, options)
        warn(days.summary())
        _warn_gross_rows(days.fitter, warn)
        return TrainedFitter(days.fitter, robot, None, days)
    fitter, check = checked_fitter_for(robot, trains[0], cpa, options)
    if check.found:
        frame = check.frame
        warn(f"warning: {check.message()} The {frame} frame{'s are' if ' and ' in frame else ' is'} fitted first, "
             "then the kinematics.")
    _warn_gross_rows(fitter, warn)
    return TrainedFitter(fitter, robot, check, None)


def _warn_gross_rows(fitter: Any, warn: Callable[[str], None]) -> None:
    """Tell the training rows the fitter set aside as gross measurement errors, if any (:func:`gross_rows_warning`)."""
    warning = gross_rows_warning(fitter)
    if warning:
        warn(warning)


@dataclass(frozen=True)
class FitInputs:
    """What ``cellcal fit`` was asked.

    Attributes:
        training: the training data.
        method: the fitting method.
        out: the model file to write.

    Raises:
        CellCalError: ``method`` is ``cpa`` and ``training`` has no sweep recording (refused at construction, before
            any file is read).
    """

    training: TrainingInputs
    method: str
    out: str

    def __post_init__(self) -> None:
        if self.method == "cpa" and self.training.cpa is None:  # nothing to fit it from
            raise CellCalError("--method cpa needs --cpa SWEEPS: a single-joint sweep recording (one cluster id per "
                               "sweep; cellcal plan --cpa adds such sweeps to a plan)")


@dataclass(frozen=True)
class FitResult:
    """A fitted model, written to ``inputs.out`` with its provenance.

    Attributes:
        inputs: what was asked.
        trained: the fitter and what the training checks found.
        model: the model written (with its provenance, and the days' frames and figures with several recordings).
        seconds: the fit's wall time [s].
    """

    inputs: FitInputs
    trained: TrainedFitter
    model: KinematicModel
    seconds: float

    def line(self) -> str:
        """The line ``fit`` prints."""
        return (f"{self.inputs.method}: {self.model.n_parameters} parameters fitted on {len(self.trained.fitter.train)} "
                f"samples in {self.seconds:.3f} s -> {self.inputs.out}")

    def to_json(self) -> dict[str, Any]:
        """The ``--json`` of ``fit``."""
        return {"robot": self.inputs.training.robot, "method": self.inputs.method,
                "n_parameters": self.model.n_parameters, "samples": len(self.trained.fitter.train),
                "fit_seconds": self.seconds, "out": str(self.inputs.out),
                "warning": self.model.info.get("warning") or "", "gross_rows": self.trained.gross_rows()}


def fit_model(cell: Any, inputs: FitInputs, warn: Callable[[str], None]) -> FitResult:
    """Fit ``inputs.method`` on the training data and write the model with its provenance to ``inputs.out``.

    Args:
        cell: the cell description.
        inputs: what was asked.
        warn: takes each warning line (the training checks', the fit's).

    Raises:
        CellCalError: bad training data (:func:`trained_fitter`), or the fit failed.
    """
    trained = trained_fitter(cell, inputs.training, warn)
    model, seconds = trained.fitter.fit(inputs.method)
    if trained.days is not None:
        model.info["days"] = trained.days.to_json()  # the recordings' frames and figures, kept with the model
    if model.info.get("warning"):
        warn(f"warning: {model.info['warning']}")
    training = inputs.training
    model = with_provenance(model, provenance([*(("train", t) for t in training.train), ("cpa", training.cpa)]))
    save_model(model, inputs.out)
    return FitResult(inputs, trained, model, seconds)
