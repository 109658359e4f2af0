"""Fitting one arm of the cell for ``cellcal fit`` and ``compare``: the training recordings refused when they are
not the arm's, then the frame check or the multi-day fit (:mod:`calibration.frames`) on the arm's
:meth:`~cell_config.loader.CellRobot.arm`, whose fitters are :meth:`calibration.methods.fitter.Fitter.for_arm`.
"""

from __future__ import annotations

import logging
from typing import Any

from calibration.frames.check import framed
from calibration.frames.multiday import fit_days
from calibration.frames.policy import refuse_another_arms, refuse_repeated

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
