"""The diagnosis report: its markdown and report files (:func:`write_report`)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from app.reports.acceptance import Tolerance, acceptance_from_max, iso_table, iso_unavailable
from app.reports.page import Image, Page, Section, Table, write_html
from app.reports.plots import save_figure
from app.reports.provenance import provenance
from calibration.data.files import atomic_write_text, make_folders
from calibration.data.recording import Recording
from calibration.diagnosis import Diagnosis


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


#: How :meth:`calibration.identification.observability.Observability.summary` opens: the diagnosis's own note on the
#: directions its geometry cannot see (on its damped basis) is left out of the report's why, where it stood beside the
#: condition :func:`app.workflows.diagnose.warn_unobservable` gives with another condition number.
UNSEEN = "The data cannot see "


def write_report(result: Diagnosis, out_dir: str | Path, tolerance: Tolerance | None = None,
                 heldout: Recording | None = None, models: dict[str, Any] | None = None,
                 inputs: Sequence[tuple[str, str | Path | None]] = (),
                 command: str = "cellcal diagnose") -> list[Path]:
    """Write ``report.md``, ``mismatch.png``, ``heldout.png`` and ``report.html`` into ``out_dir``; returns the files.

    Args:
        result: the diagnosis.
        out_dir: the report folder (created).
        tolerance: the acceptance :class:`~app.reports.acceptance.Tolerance` (None: 1 mm and 1 deg).
        heldout: the held-out recording when one was given (ISO 9283 needs its repeated poses), else None.
        models: the models to give ISO 9283 AP_p for (name -> model).
        inputs: (role, path) of the input files, for the provenance.
        command: the command line shown in the report.
    """

    plt = _pyplot()
    tol = tolerance or Tolerance()
    out = Path(out_dir)
    make_folders(out)  # removed again when a staged set of outputs fails (calibration.data.files.staged_outputs)
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
                      images, why=[_why(result, models or {}), result.verdict,
                                   *(n for n in result.notes if not n.startswith(UNSEEN))])
    files.append(write_html(Page(section.title, command, tol, provenance(inputs), [section]), out))
    return files


def _why(result: Diagnosis, models: dict[str, Any]) -> str:
    """The test that chose the effects and the parameter counts, before the diagnosis's own verdict."""
    counts = ", ".join(f"{name}: {m.n_parameters} parameters" for name, m in models.items())
    return (f"An effect is kept only when it lowers the BIC on the fit data and improves the held-out error ("
            f"{result.heldout_source}) beyond the noise floor; the held-out position RMS goes from "
            f"{result.baseline.rms_mm:.3f} mm ({result.baseline.model}) to {result.final.rms_mm:.3f} mm "
            f"({result.final.model}). {counts}.")


def _days_tables(result: Diagnosis) -> list[Any]:
    """With several recordings: each one against the first (frames, kinematics, named changes)."""

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
