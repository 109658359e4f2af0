"""Fitting one arm of the cell: a :class:`~calibration.methods.fitter.Fitter` set up from the arm's cell entry.

Shared by the workflows that fit models (the demo, the simulated dual-cell validation, ``cellcal fit`` and
``compare``): the arm's nominal model, its link masses (for the joint compliance; the mass-free form when the
robot YAML has none) and its joint limits.
"""

from __future__ import annotations

import logging
from typing import Any

from calibration.errors import ModelError
from calibration.frames.check import framed
from calibration.frames.multiday import fit_days
from calibration.frames.policy import refuse_another_arms, refuse_repeated
from calibration.methods.fitter import Fitter
from calibration.methods.options import FitOptions
from calibration.models import ConstantModel
from calibration.physics.gravity import GravityModel

log = logging.getLogger("cellcal.app")


def gross_rows_warning(fitter: Any) -> str | None:
    """The warning line for the training rows ``fitter`` set aside as gross measurement errors (``Fitter.gross``),
    or None when it set none aside; ``fit``, ``compare`` and ``recalibrate`` give it the same way."""
    gross = getattr(fitter, "gross", None)
    return f"warning: {gross.message()}" if gross is not None and gross.message() else None


def fitter_for(robot: Any, train: Any, cpa: Any | None = None, options: Any | None = None) -> Any:
    """A Fitter for one arm of the cell: its nominal model, link masses and joint limits, on the training recording
    less its gross measurement errors (``Fitter.without_gross_rows``; ``fitter.gross`` names them).

    Args:
        robot: the arm's cell entry (:meth:`cell_config.loader.CellSpec.robot`).
        train: the training :class:`~calibration.data.recording.Recording`.
        cpa: the CPA sweeps recording, or None.
        options: :class:`~calibration.methods.options.FitOptions` (default options when None).
    """

    nominal = robot.model()
    try:
        gravity = GravityModel.from_spec(robot.robot, nominal)
    except ModelError as e:
        log.warning("%s: joint compliance takes the mass-free form: %s", robot.name, e)
        gravity = None
    fitter = Fitter(robot.name, nominal, train, options or FitOptions(), cpa, gravity,
                    (robot.robot.lower_rad, robot.robot.upper_rad))
    return fitter.without_gross_rows() if fitter.options.reject_gross_rows else fitter


def checked_fitter_for(robot: Any, train: Any, cpa: Any | None = None, options: Any | None = None
                       ) -> tuple[Any, Any]:
    """:func:`fitter_for` after a frame check of the training recording against the nominal arm.

    When the check finds a frame or tool-registration problem, the fitter fits the frame(s) at fault first and the
    kinematics after (:class:`calibration.frames.check.FramedFit`), and the check's message is logged. A recording that
    even the best frame fit leaves far off (:func:`refuse_unexplained`) is refused.

    Returns:
        The fitter and the :class:`calibration.frames.check.FrameCheck`.

    Raises:
        DataError: the training recording is not this arm's (:func:`refuse_unexplained`).
    """

    nominal = ConstantModel(robot.name, "nominal", robot.model(), 0, {})
    check = refuse_another_arms(robot, train)
    fitter, check = framed(lambda rec: fitter_for(robot, rec, cpa, options), nominal, train, check)
    if check.found:
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

    nominal = ConstantModel(robot.name, "nominal", robot.model(), 0, {})
    for rec in trains:
        refuse_another_arms(robot, rec)
    refuse_repeated([rec.source for rec in trains])
    return fit_days(lambda rec: fitter_for(robot, rec, cpa, options), nominal, trains)
