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

from app.analysis.plots import save_figure
from calibration.diagnosis import DiagnoseOptions, Diagnosis, diagnose
from calibration.errors import DataError, ModelError
from calibration.files import atomic_write_text, make_folders

log = logging.getLogger("cellcal.app")


def _without_gross_rows(robot: Any, rec: Any) -> tuple[Any, Any]:
    """The recording less its gross measurement errors, screened as ``fit`` screens its training recording
    (:meth:`calibration.methods.Fitter.without_gross_rows`, under the geometric fit): one marker swap of 50 mm would
    otherwise be explained by whatever effect fits it best. Warns naming the rows; returns the screening (None when
    it is turned off)."""
    from app.analysis.fitting import fitter_for

    screened = fitter_for(robot, rec)
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
        tolerance: the report's acceptance :class:`~app.analysis.report.Tolerance` (None: 1 mm and 1 deg).
        progress: show a progress bar over the diagnosis steps.
        added: recordings of extra poses joined to the one training recording as stand-alone poses
            (:func:`calibration.recording.with_added`; ``--add``), each with weight ``add_weight``.
        command: the command line the report shows.

    Returns:
        The diagnosis.

    Raises:
        CellCalError: bad input (unknown robot, unreadable data, unusable model); nothing is written.
    """
    from calibration.models import load_model, save_model
    from calibration.physics.gravity import GravityModel
    from calibration.recording import check_quaternion_order, read_recording, with_added
    from cell_config import load_cell

    cr = (load_cell(cell) if cell else load_cell()).robot(robot)
    spec = cr.robot
    nominal = cr.model()
    limits = (spec.lower_rad, spec.upper_rad)
    used = load_model(model, robot, nominal) if model is not None else None  # another robot's model: refused
    paths = [data] if isinstance(data, (str, Path)) else list(data)
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
    from app.analysis.fitting import refuse_another_arms

    gross = None
    if days is None:  # another arm's recording is refused, as fit does (several recordings: by _days)
        refuse_another_arms(cr, rec)
        rec, gross = _without_gross_rows(cr, rec)
    if ho is not None:
        refuse_another_arms(cr, ho, "test recording")
    try:
        gravity = GravityModel.from_spec(spec, nominal)
    except ModelError as e:
        log.warning("joint compliance cannot be tested: %s", e)
        gravity = None
    from app.progress import bar
    from calibration.diagnosis.core import DIAGNOSE_STEPS

    with bar(total=len(DIAGNOSE_STEPS), enabled=progress, desc=f"{robot} diagnose", unit="step") as steps:
        def step(name: str) -> None:  # the bar counts the steps done; its label names the one running
            steps.set_postfix_str(name, refresh=False)
            steps.update(DIAGNOSE_STEPS.index(name) - steps.n)

        result = diagnose(robot, nominal, rec, ho, used, gravity, limits, options, progress=step)
        steps.update(steps.total - steps.n)
    inputs = [*(("data", p) for p in paths), *(("add", p) for p in added), ("heldout", heldout), ("model", model)]
    if days is not None:
        result = replace(result, days=days)
    if model_out is not None:
        from app.provenance import provenance, with_provenance

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
    return result


def _days(robot: str, nominal: Any, paths: list[str | Path], limits: tuple[np.ndarray, np.ndarray]) -> tuple[Any, Any]:
    """Several recordings of one arm: what differs between them (:func:`calibration.daydiff.compare_days`), and
    the recordings pooled in the first one's frames (the others' frames taken out; the diagnosis runs on that).

    Raises:
        DataError: a recording given twice, unreadable, or not of ``robot``.
    """
    from app.analysis.fitting import refuse_repeated
    from calibration.daydiff import check_same_robot, compare_days, day_names
    from calibration.frames import put_in, take_out
    from calibration.multiday import pool
    from calibration.rebase import corrections
    from calibration.recording import check_quaternion_order, read_recording

    refuse_repeated(paths)
    recs = [read_recording(p, *limits) for p in paths]
    for r in recs:
        check_quaternion_order(r, nominal)
    check_same_robot(nominal, recs, robot)
    days = compare_days(nominal, recs, day_names([str(p) for p in paths]))
    first = corrections(days.deltas[0])  # every recording in the first one's frames (it stays as it is)
    return pool([recs[0]] + [put_in(take_out(r, *corrections(delta)), *first)
                             for r, delta in zip(recs[1:], days.deltas[1:])]), days


def markdown(result: Diagnosis) -> str:
    """The Markdown report (plots referenced by file name)."""
    j = result.to_json()
    b, f = result.baseline, result.final
    lines = [f"# Diagnosis: {result.robot}", "", f"**Verdict.** {result.verdict}", "",
             f"Samples: {result.n_fit} fit, {result.n_heldout} held out ({result.heldout_source}). "
             f"Noise floor {result.noise.floor_mm:.3f} mm (within clusters {result.noise.within_cluster_mm:.3f}, "
             f"fit residual {result.noise.fit_residual_mm:.3f}).", "",
             "| model | held-out RMS mm | max mm | RMS deg | max deg |", "|---|---:|---:|---:|---:|",
             f"| {b.model} (before) | {b.rms_mm:.4f} | {b.max_mm:.4f} | {b.rms_deg:.4f} | {b.max_deg:.4f} |",
             f"| {f.model} (after) | {f.rms_mm:.4f} | {f.max_mm:.4f} | {f.rms_deg:.4f} | {f.max_deg:.4f} |", ""]
    lines += ["## Effects found", ""]
    if result.effects:
        lines += ["| kind | on | parameters | delta BIC | held-out RMS before -> after mm |", "|---|---|---|---:|---|"]
        for e in result.effects:
            on = ", ".join(e.links) or ", ".join(map(str, e.joints)) or "-"
            ps = "; ".join(f"{k} = {v:.4g}" + (f" ± {e.uncertainty[k]:.2g}" if e.uncertainty.get(k) else "")
                           for k, v in e.parameters.items())
            lines.append(f"| {e.kind} | {on} | {ps} | {e.evidence.delta_bic:.1f} | "
                         f"{e.evidence.before.rms_mm:.4f} -> {e.evidence.after.rms_mm:.4f} |")
        lines += [""] + [f"- {e.explanation}" for e in result.effects]
    else:
        lines.append("None confirmed on the held-out data.")
    if result.rejected:
        lines += ["", "## Selected on the fit data but not confirmed on the held-out data", ""]
        lines += [f"- {e.kind} on {', '.join(e.links) or ', '.join(map(str, e.joints)) or '-'}: held-out RMS "
                  f"{e.evidence.before.rms_mm:.4f} -> {e.evidence.after.rms_mm:.4f} mm (z = {e.evidence.heldout_z:.1f}). "
                  f"{e.explanation}" for e in result.rejected]
    if result.days is not None:
        lines += ["", "## What differs between the recordings", "", "```", result.days.summary(), "```"]
    lines += ["", "## Where the model and the data disagree", "", "| driver | correlation | where |", "|---|---:|---|"]
    lines += [f"| {m['regressor']} | {m['correlation']:.3f} | {m['where']} |" for m in j["mismatch"]]
    lines += ["", "## Not identifiable from this data", ""]
    lines += [f"- {u.kind} on {u.label}: {u.reason}" for u in result.not_identifiable] or ["- none"]
    lines += ["", "## Not tested (missing data columns)", ""]
    lines += [f"- {u.kind} on {u.label}: {u.reason}" for u in result.untested] or ["- none"]
    if result.notes:
        lines += ["", "## Notes", ""] + [f"- {n}" for n in result.notes]
    lines += ["", "## Plots", "", "![residual against its strongest drivers](mismatch.png)", "",
              "![held-out error before and after](heldout.png)", ""]
    return "\n".join(lines)


def write_report(result: Diagnosis, out_dir: str | Path, tolerance: Any = None, heldout: Any = None,
                 models: dict[str, Any] | None = None, inputs: list[tuple[str, Any]] | tuple = (),
                 command: str = "cellcal diagnose") -> list[Path]:
    """Write ``report.md``, ``mismatch.png``, ``heldout.png`` and ``report.html`` into ``out_dir``; returns the files.

    Args:
        result: the diagnosis.
        out_dir: the report folder (created).
        tolerance: the acceptance :class:`~app.analysis.report.Tolerance` (None: 1 mm and 1 deg).
        heldout: the held-out recording when one was given (ISO 9283 needs its repeated poses), else None.
        models: the models to give ISO 9283 AP_p for (name -> model).
        inputs: (role, path) of the input files, for the provenance.
        command: the command line shown in the report.
    """
    from app.analysis.report import (
        Image,
        Page,
        Section,
        Table,
        Tolerance,
        acceptance_from_max,
        iso_table,
        iso_unavailable,
        write_html,
    )
    from app.provenance import provenance

    plt = _pyplot()
    tol = tolerance or Tolerance()
    out = Path(out_dir)
    make_folders(out)  # removed again when a staged set of outputs fails (calibration.files.staged_outputs)
    files, images = [], []
    pd = result.plots
    if pd is not None:
        names = [m.regressor for m in result.mismatch][:4]
        drv = {d.name: d for d in pd.drivers}
        shown = [drv[n] for n in names if n in drv] or list(pd.drivers[:1])
        fig, axes = plt.subplots(1, len(shown), figsize=(4 * len(shown), 3.6), squeeze=False)
        for ax, d in zip(axes[0], shown):
            ax.scatter(d.values, pd.fit_residual_mm, s=4, alpha=0.5)
            ax.set_xlabel(f"{d.name} [{d.unit}]")
            ax.set_ylabel("baseline position residual [mm]")
            ax.grid(alpha=0.3)
        files.append(save_figure(fig, out / "mismatch.png"))
        images.append(Image.from_file("baseline residual against its strongest drivers", files[-1]))
        fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 3.8))
        for values, label, style in ((pd.heldout_before_mm, f"before ({result.baseline.model})", "-"),
                                     (pd.heldout_after_mm, f"after ({result.final.model})", "--")):
            v = np.sort(values)
            a1.step(v, np.arange(1, len(v) + 1) / len(v), where="post", ls=style, lw=1.4, label=label)
        a1.axvline(result.noise.floor_mm, color="k", ls=":", lw=0.8, label="noise floor (RMS)")
        a1.axvline(tol.position_mm, color="r", ls="--", lw=0.8, label=f"tolerance {tol.position_mm:g} mm")
        a1.set_xlabel("held-out position error [mm]")
        a1.set_ylabel("fraction of held-out poses with a smaller error [-]")
        a1.legend(fontsize=7)
        bins = np.linspace(0, max(pd.heldout_before_mm.max(), pd.heldout_after_mm.max()), 40)
        a2.hist(pd.heldout_before_mm, bins, alpha=0.6, label="before")
        a2.hist(pd.heldout_after_mm, bins, alpha=0.6, label="after")
        a2.set_xlabel("held-out position error [mm]")
        a2.set_ylabel("held-out poses [count]")
        a2.legend(fontsize=7)
        files.append(save_figure(fig, out / "heldout.png"))
        images.append(Image.from_file("held-out position error before and after (CDF and histogram)", files[-1]))
    md = out / "report.md"
    atomic_write_text(md, markdown(result))
    files.append(md)
    b, f = result.baseline, result.final
    rows = [[f"{fit.model} ({when})", f"{fit.rms_mm:.4f}", f"{fit.max_mm:.4f}", f"{fit.rms_deg:.4f}", f"{fit.max_deg:.4f}"]
            for fit, when in ((b, "before"), (f, "after"))]
    effects = [[e.kind, ", ".join(e.links) or ", ".join(map(str, e.joints)) or "-", f"{e.evidence.delta_bic:.1f}",
                f"{e.evidence.before.rms_mm:.4f} -> {e.evidence.after.rms_mm:.4f}"] for e in result.effects]
    label = "the held-out recording"
    iso = iso_table(models or {}, heldout, label) if heldout is not None else iso_unavailable(
        label, "the held-out poses are clusters set aside from the data (no --test recording to look for repeats in)")
    section = Section(f"Diagnosis: {result.robot}",
                      [acceptance_from_max(f"{fit.model} ({when})", result.n_heldout, fit.max_mm, fit.max_deg, tol)
                       for fit, when in ((b, "before"), (f, "after"))],
                      f"the {result.n_heldout} held-out poses ({result.heldout_source})", iso, f"{f.model} (after)",
                      [f"Samples: {result.n_fit} fit, {result.n_heldout} held out. Noise floor "
                       f"{result.noise.floor_mm:.3f} mm. Details in report.md."],
                      [Table("Held-out accuracy", ["model", "RMS mm", "max mm", "RMS deg", "max deg"], rows),
                       Table("Effects found", ["kind", "on", "delta BIC", "held-out RMS before -> after mm"], effects,
                             [] if effects else ["None confirmed on the held-out data."]), *_days_tables(result)],
                      images, why=[result.verdict, *result.notes])
    files.append(write_html(Page(section.title, command, tol, provenance(inputs), [section]), out))
    return files


def _days_tables(result: Diagnosis) -> list[Any]:
    """With several recordings: each one against the first (frames, kinematics, named changes)."""
    from app.analysis.report import Table

    if result.days is None:
        return []
    rows = [[d.name, "differ" if d.frames_differ else "same", "differ" if d.kinematics_differ else "same",
             "; ".join(q.text() for q in d.named) or "-"] for d in result.days.days]
    return [Table(f"What differs between the recordings (against {result.days.reference})",
                  ["recording", "frames", "kinematics", "named changes"], rows, result.days.summary().splitlines())]


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt
