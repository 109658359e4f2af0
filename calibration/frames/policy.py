"""What a training set is refused for before a fit: repeated recordings, frames that differ beyond what the fit
explains, another arm's poses (the refusals :mod:`app.workflows.fit` applies)."""

from __future__ import annotations

from typing import Any

from calibration.arm import Arm
from calibration.data.recording import Recording
from calibration.errors import DataError
from calibration.frames.check import UNEXPLAINED_MM, FrameCheck, check_recording


def refuse_repeated(paths: list[Any]) -> None:
    """Refuse a recording given twice among several: it would be fitted (or compared) as two days that agree.

    Raises:
        DataError: naming the first path that names a recording already given (compared once resolved).
    """
    from pathlib import Path


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
        DataError: ``left_mm`` exceeds :data:`calibration.frames.check.UNEXPLAINED_MM` (the message names the recording,
            both figures and the likely causes).
    """

    if not left_mm <= UNEXPLAINED_MM:
        raise DataError(source, None, None,
                        f"not {robot}'s poses: even the best rigid fit of the base and tool frames leaves a mean "
                        f"position error of {left_mm:.1f} mm against {against} (from {before_mm:.1f} mm; an arm's own "
                        f"recordings leave under 1 mm, the limit is {UNEXPLAINED_MM:g} mm); the wrong --robot, or a "
                        "recording of another arm?")


def refuse_another_arms(arm: Arm, rec: Recording, subject: str = "training recording") -> FrameCheck:
    """The frame check of ``rec`` against ``arm``'s nominal model (:func:`calibration.frames.check.check_recording`),
    refused when not even the best rigid fit of both frames explains it (:func:`refuse_unexplained`): a check of
    rigid fits only, made before any method is fitted on or evaluated against the recording.

    Returns:
        The :class:`calibration.frames.check.FrameCheck`.

    Raises:
        DataError: ``rec`` is not this arm's (naming the recording and the arm).
    """

    check = check_recording(arm.nominal_model(), rec, subject)
    refuse_unexplained(rec.source, arm.name, f"{arm.name}'s nominal arm", check.mean_mm, check.left_mm)
    return check
