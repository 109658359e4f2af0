"""Fitting one arm of the cell: a :class:`~calibration.methods.Fitter` set up from the arm's cell entry.

Shared by the workflows that fit models (the demo, the simulated dual-cell validation, ``cellcal fit`` and
``compare``): the arm's nominal model, its link masses (for the joint compliance; the mass-free form when the
robot YAML has none) and its joint limits.
"""

from __future__ import annotations

import logging
from typing import Any

log = logging.getLogger("cellcal.app")


def fitter_for(robot: Any, train: Any, cpa: Any | None = None, options: Any | None = None) -> Any:
    """A Fitter for one arm of the cell: its nominal model, link masses and joint limits, on the training recording
    less its gross measurement errors (``Fitter.without_gross_rows``; ``fitter.gross`` names them).

    Args:
        robot: the arm's cell entry (:meth:`cell_config.loader.CellSpec.robot`).
        train: the training :class:`~calibration.recording.Recording`.
        cpa: the CPA sweeps recording, or None.
        options: :class:`~calibration.methods.FitOptions` (default options when None).
    """
    from calibration.errors import ModelError
    from calibration.methods import FitOptions, Fitter
    from calibration.physics.gravity import GravityModel

    nominal = robot.model()
    try:
        gravity = GravityModel.from_spec(robot.robot, nominal)
    except ModelError as e:
        log.warning("%s: joint compliance takes the mass-free form: %s", robot.name, e)
        gravity = None
    fitter = Fitter(robot.name, nominal, train, options or FitOptions(), cpa, gravity,
                    (robot.robot.lower_rad, robot.robot.upper_rad))
    return fitter.without_gross_rows() if fitter.options.reject_gross_rows else fitter


def refuse_repeated(paths: list[Any]) -> None:
    """Refuse a recording given twice among several: it would be fitted (or compared) as two days that agree.

    Raises:
        DataError: naming the first path that names a recording already given (compared once resolved).
    """
    from pathlib import Path

    from calibration.errors import DataError

    seen: set[Path] = set()
    for p in paths:
        if Path(p).resolve() in seen:
            raise DataError(p, None, None, "given twice; give each recording (day) once")
        seen.add(Path(p).resolve())


def refuse_unexplained(source: str, robot: str, against: str, before_mm: float, left_mm: float) -> None:
    """Refuse a recording whose error even the best rigid fit of both frames does not explain.

    Args:
        source: the recording checked.
        robot: the arm it was read as (``--robot``, or the model's).
        against: what it was checked against (``R2's nominal arm``, ``the model model.yaml``).
        before_mm: its mean position error against that [mm].
        left_mm: what the best rigid fit of the base and tool frames leaves of it [mm].

    Raises:
        DataError: ``left_mm`` exceeds :data:`calibration.frames.UNEXPLAINED_MM` (the message names the recording,
            both figures and the likely causes).
    """
    from calibration.errors import DataError
    from calibration.frames import UNEXPLAINED_MM

    if not left_mm <= UNEXPLAINED_MM:
        raise DataError(source, None, None,
                        f"not {robot}'s poses: even the best rigid fit of the base and tool frames leaves a mean "
                        f"position error of {left_mm:.1f} mm against {against} (from {before_mm:.1f} mm; an arm's own "
                        f"recordings leave under 1 mm, the limit is {UNEXPLAINED_MM:g} mm); the wrong --robot, or a "
                        "recording of another arm?")


def refuse_another_arms(robot: Any, rec: Any, subject: str = "training recording") -> Any:
    """The frame check of ``rec`` against ``robot``'s nominal arm (:func:`calibration.frames.check_recording`),
    refused when not even the best rigid fit of both frames explains it (:func:`refuse_unexplained`): a check of
    rigid fits only, made before any method is fitted on or evaluated against the recording.

    Returns:
        The :class:`calibration.frames.FrameCheck`.

    Raises:
        DataError: ``rec`` is not this arm's (naming the recording and the arm).
    """
    from calibration.frames import check_recording
    from calibration.models import ConstantModel

    nominal = ConstantModel(robot.name, "nominal", robot.model(), 0, {})
    check = check_recording(nominal, rec, subject)
    refuse_unexplained(rec.source, robot.name, f"{robot.name}'s nominal arm", check.mean_mm, check.left_mm)
    return check


def checked_fitter_for(robot: Any, train: Any, cpa: Any | None = None, options: Any | None = None
                       ) -> tuple[Any, Any]:
    """:func:`fitter_for` after a frame check of the training recording against the nominal arm.

    When the check finds a frame or tool-registration problem, the fitter fits the frame(s) at fault first and the
    kinematics after (:class:`calibration.frames.FramedFit`), and the check's message is logged. A recording that
    even the best frame fit leaves far off (:func:`refuse_unexplained`) is refused.

    Returns:
        The fitter and the :class:`calibration.frames.FrameCheck`.

    Raises:
        DataError: the training recording is not this arm's (:func:`refuse_unexplained`).
    """
    from calibration.frames import framed
    from calibration.models import ConstantModel

    nominal = ConstantModel(robot.name, "nominal", robot.model(), 0, {})
    check = refuse_another_arms(robot, train)
    fitter, check = framed(lambda rec: fitter_for(robot, rec, cpa, options), nominal, train, check)
    if check.found:
        log.info("%s Fitting the %s frame%s first, then the kinematics.", check.message(), check.frame,
                 "s" if " and " in check.frame else "")
    return fitter, check


def days_fitter_for(robot: Any, trains: list[Any], cpa: Any | None = None, options: Any | None = None) -> Any:
    """Several training recordings in one fit: one arm, per-recording frames (:func:`calibration.multiday.fit_days`).

    Returns:
        The :class:`calibration.multiday.MultiDayFit` (its ``fitter`` fits any method).

    Raises:
        DataError: a training recording is not this arm's (:func:`refuse_unexplained`), or is given twice.
    """
    from calibration.models import ConstantModel
    from calibration.multiday import fit_days

    nominal = ConstantModel(robot.name, "nominal", robot.model(), 0, {})
    for rec in trains:
        refuse_another_arms(robot, rec)
    refuse_repeated([rec.source for rec in trains])
    return fit_days(lambda rec: fitter_for(robot, rec, cpa, options), nominal, trains)
