"""The ``diagnose`` workflow: read recordings, find the physics the model in use left out, write the report.

``run_diagnose`` is what ``cellcal diagnose`` calls. Everything is read and validated before anything is
written; the JSON report (``cellcal.diagnose/1``), the Markdown report with PNG plots and the fitted
physics model file are each written atomically.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from app.progress import bar
from app.reports.diagnosis import write_report
from app.reports.provenance import provenance, with_provenance
from calibration.data.files import atomic_write_text
from calibration.data.recording import check_quaternion_order, put_in, read_recording, take_out, with_added
from calibration.diagnosis import DiagnoseOptions, Diagnosis, diagnose
from calibration.diagnosis.core import DIAGNOSE_STEPS
from calibration.errors import DataError, ModelError
from calibration.frames.daydiff import check_same_robot, compare_days, day_names
from calibration.frames.multiday import pool
from calibration.frames.policy import refuse_another_arms, refuse_repeated
from calibration.frames.rebase import corrections
from calibration.methods.fitter import Fitter
from calibration.models import load_model, save_model
from calibration.physics.gravity import GravityModel
from cell_config import load_cell

log = logging.getLogger("cellcal.app")


def _without_gross_rows(robot: Any, rec: Any) -> tuple[Any, Any]:
    """The recording less its gross measurement errors, screened as ``fit`` screens its training recording
    (:meth:`calibration.methods.fitter.Fitter.without_gross_rows`, under the geometric fit): one marker swap of 50 mm would
    otherwise be explained by whatever effect fits it best. Warns naming the rows; returns the screening (None when
    it is turned off)."""

    screened = Fitter.for_arm(robot.arm(), rec)
    gross = screened.gross
    if gross is not None and (gross.rows or gross.too_many):
        log.warning("%s", gross.message())
    return (screened.train if gross is not None and gross.rows else rec), gross


def run_diagnose(robot: str, data: str | Path | Sequence[str | Path], heldout: str | Path | None = None, model: str | Path | None = None,
                 json_path: str | Path | None = None, report_dir: str | Path | None = None,
                 model_out: str | Path | None = None, cell: str | Path | None = None,
                 options: DiagnoseOptions | None = None, tolerance: Any = None, progress: bool = False,
                 added: Sequence[str | Path] = (), add_weight: int = 1,
                 command: str = "cellcal diagnose") -> Diagnosis:
    """Diagnose one robot's model against recordings and write the requested outputs.

    Args:
        robot: robot name in the cell (``R1``, ``R2``).
        data: recording CSV or Welding_Motoman folder to diagnose on; several (days of one arm): what differs
            between them is found first (``result.days``), and the diagnosis runs on them pooled in the first
            one's frames (a ``model`` in use is taken to be in those).
        heldout: recording for the before/after figures; None sets aside a fifth of the clusters of ``data``.
        model: model file in use (constant, physics, pi or cdc; a diagnosed file is refused: give its base); None fits the
            geometric NLS (``nls1``) on ``data``.
        json_path: write the ``cellcal.diagnose/1`` JSON report here.
        report_dir: write ``report.html``, ``report.md`` and PNG plots into this folder.
        model_out: write the refitted model (physics, pi, cdc or diagnosed, see
            :func:`calibration.diagnosis.result_model`) here (``.yaml``/``.json``).
        cell: cell YAML (default: the packaged Motoman cell).
        options: diagnosis settings.
        tolerance: the report's acceptance :class:`~app.reports.acceptance.Tolerance` (None: 1 mm and 1 deg).
        progress: show a progress bar over the diagnosis steps.
        added: recordings of extra poses joined to the one training recording as stand-alone poses
            (:func:`calibration.data.recording.with_added`; ``--add``), each with weight ``add_weight``.
        command: the command line the report shows.

    Returns:
        The diagnosis.

    Raises:
        CellCalError: bad input (unknown robot, unreadable data, unusable model); nothing is written.
    """

    cr = (load_cell(cell) if cell else load_cell()).robot(robot)
    spec = cr.robot
    nominal = cr.model()
    limits = (spec.lower_rad, spec.upper_rad)
    used = load_model(model, robot, nominal) if model is not None else None  # another robot's model: refused
    paths = [data] if isinstance(data, (str, Path)) else list(data)
    rec, days, ho, gross = _read_inputs(cr, robot, nominal, limits, paths, heldout, added, add_weight)
    gravity = _gravity(spec, nominal)

    with bar(total=len(DIAGNOSE_STEPS), enabled=progress, desc=f"{robot} diagnose", unit="step") as steps:
        def step(name: str) -> None:  # the bar counts the steps done; its label names the one running
            steps.set_postfix_str(name, refresh=False)
            steps.update(DIAGNOSE_STEPS.index(name) - steps.n)

        result = diagnose(robot, nominal, rec, ho, used, gravity, limits, options, progress=step)
        steps.update(steps.total - steps.n)
    warn_unobservable(cr, rec, gravity, options)  # once the data passed the diagnosis's checks: a refusal is one line
    inputs = [*(("data", p) for p in paths), *(("add", p) for p in added), ("heldout", heldout), ("model", model)]
    if days is not None:
        result = replace(result, days=days)
    _write_outputs(result, inputs, gross, used, ho, model_out, json_path, report_dir, tolerance, command)
    return result


def _read_inputs(cr: Any, robot: str, nominal: Any, limits: tuple[Any, Any], paths: list[str | Path],
                 heldout: str | Path | None, added: Sequence[str | Path],
                 add_weight: int) -> tuple[Any, Any, Any, Any]:
    """:func:`run_diagnose`'s recordings, checked: the training one (several days joined in the first one's frames,
    the added poses joined, gross rows taken out of a single day), the days' differences, the held-out recording and
    the gross rows taken out (None with several days).

    Raises:
        CellCalError: an unreadable recording, another arm's, quaternions in another order, ``added`` with days.
    """
    days = None
    if len(paths) > 1:
        rec, days = _days(robot, nominal, paths, limits)
    else:
        rec = read_recording(paths[0], *limits)
        check_quaternion_order(rec, nominal)
    if added:
        if days is not None:
            raise DataError(paths[0], None, None, f"--add joins the poses to one training recording; {len(paths)} "
                                                  "given (diagnose each day with its own --add)")
        extra = [read_recording(p, *limits) for p in added]
        for r in extra:
            check_quaternion_order(r, nominal)
        rec = with_added(rec, extra, weight=add_weight)
    ho = read_recording(heldout, *limits) if heldout is not None else None
    if ho is not None:
        check_quaternion_order(ho, nominal)

    gross = None
    if days is None:  # another arm's recording is refused, as fit does (several recordings: by _days)
        refuse_another_arms(cr.arm(), rec)
        rec, gross = _without_gross_rows(cr, rec)
    if ho is not None:
        refuse_another_arms(cr.arm(), ho, "test recording")
    return rec, days, ho, gross


def _gravity(spec: Any, nominal: Any) -> GravityModel | None:
    """The arm's gravity model from its YAML, or None (with a warning) when joint compliance cannot be tested."""
    try:
        return GravityModel.from_spec(spec, nominal)
    except ModelError as e:
        log.warning("joint compliance cannot be tested: %s", e)
        return None


def _write_outputs(result: Diagnosis, inputs: list[tuple[str, Any]], gross: Any, used: Any, ho: Any,
                   model_out: str | Path | None, json_path: str | Path | None, report_dir: str | Path | None,
                   tolerance: Any, command: str) -> None:
    """Write what :func:`run_diagnose` was asked for: the refitted model, the JSON report, the report folder."""
    if model_out is not None:
        save_model(with_provenance(result.model, provenance(inputs)), model_out)
    if json_path is not None:
        doc = result.to_json()
        if gross is not None:
            doc["gross_rows"] = gross.to_json()
        atomic_write_text(Path(json_path), json.dumps(doc, indent=1))
    if report_dir is not None:
        models = {f"{result.final.model} (after)": result.model}
        if used is not None:
            models = {f"{result.baseline.model} (before)": used, **models}
        write_report(result, report_dir, tolerance, ho, models, inputs, command)


def warn_unobservable(cr: Any, rec: Any, gravity: Any, options: Any) -> None:
    """Warn, as ``fit`` and ``compare`` do, when the training poses leave parameter directions of the geometry unseen
    (:meth:`calibration.methods.fitter.Fitter.observability`, the orientation weight of ``options``): the report's
    conditions carry it (it was only among the diagnosis's notes, under "why")."""
    from calibration.methods.fitter import Fitter
    from calibration.methods.options import FitOptions

    a = getattr(options, "a", None)
    fit_options = FitOptions() if a is None else FitOptions(a=a)
    text = Fitter(cr.name, cr.model(), rec, fit_options, None, gravity,
                  (cr.robot.lower_rad, cr.robot.upper_rad)).observability().summary()
    if text:
        log.warning("%s", text)


def _days(robot: str, nominal: Any, paths: list[str | Path], limits: tuple[np.ndarray, np.ndarray]) -> tuple[Any, Any]:
    """Several recordings of one arm: what differs between them (:func:`calibration.frames.daydiff.compare_days`), and
    the recordings pooled in the first one's frames (the others' frames taken out; the diagnosis runs on that).

    Raises:
        DataError: a recording given twice, unreadable, or not of ``robot``.
    """

    refuse_repeated(paths)
    recs = [read_recording(p, *limits) for p in paths]
    for r in recs:
        check_quaternion_order(r, nominal)
    check_same_robot(nominal, recs, robot)
    days = compare_days(nominal, recs, day_names([str(p) for p in paths]))
    first = corrections(days.deltas[0])  # every recording in the first one's frames (it stays as it is)
    return pool([recs[0]] + [put_in(take_out(r, *corrections(delta)), *first)
                             for r, delta in zip(recs[1:], days.deltas[1:])]), days


