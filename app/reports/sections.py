"""The sections of the comparison, evaluation and demo reports, and the functions that write those reports."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from app.reports import plots
from app.reports.acceptance import Tolerance, acceptance, iso_table
from app.reports.page import Image, Page, Section, Table, _f, recommendation_why, shown_series, write_html
from app.reports.provenance import provenance
from calibration.data.files import atomic_write_text, make_folders
from calibration.data.recording import Recording, welding_layout
from calibration.evaluation.comparison import Comparison, comparison_warnings
from calibration.evaluation.metrics import Errors, errors

PAPER_R1_TEST = {  # the paper's Table IV (R1 test set, position mean / std / max mm)
    "nominal": (1.29, 0.21, 1.72), "base": (0.53, 0.25, 1.27), "cpa": (0.44, 0.20, 0.99),
    "nls0": (0.41, 0.21, 0.99), "nls1": (0.92, 0.79, 3.46), "nearest": (0.32, 0.17, 0.81),
    "linear": (0.31, 0.17, 0.81), "cubic": (0.31, 0.17, 0.83), "rbf": (0.31, 0.17, 0.83),
    "fbf13": (0.31, 0.14, 0.74), "fbf7": (0.32, 0.16, 0.81), "nn": (0.34, 0.13, 0.78), "ae": (0.31, 0.14, 0.73),
}


#: The paper's column in a comparison table: its figures, on its own R1 test set (:func:`shows_paper`).
PAPER_COLUMN = "paper's Table IV on its R1 test set: pos mean / std / max mm"


def shows_paper(robot: str, test: Recording) -> bool:
    """Whether a comparison shows the paper's Table IV figures (:data:`PAPER_R1_TEST`) beside its own: only for R1
    tested on a recording in the Welding_Motoman layout, the paper's own cell's data. On a simulated recording, or
    any in the native CSV format, the paper's column stood beside the figures as if they were comparable."""

    return robot == "R1" and welding_layout(test.source) is not None


def comparison_table(cmp: Comparison, with_paper: bool = False) -> str:
    """Table IV as Markdown: test and train position/orientation statistics and fit time per method."""
    return "\n".join(comparison_rows(cmp, with_paper).markdown()[2:]).rstrip()


def comparison_rows(cmp: Comparison, with_paper: bool = False) -> Table:
    """Table IV: per method, parameters, fit time, test and train statistics (the paper's figures for R1)."""
    header = ["method", "params", "fit s", "test pos mean / std / max mm", "test ori mean / max deg",
              "train pos mean / max mm"] + ([PAPER_COLUMN] if with_paper else [])
    rows = []
    for m, model in cmp.models.items():
        te, tr = cmp.test_errors[m], cmp.train_errors[m]
        row = [m, str(model.n_parameters), _f(cmp.fit_seconds[m], ".3f"),
               f"{te.position_mm.mean():.3f} / {te.position_mm.std():.3f} / {te.position_mm.max():.3f}",
               f"{te.orientation_deg.mean():.3f} / {te.orientation_deg.max():.3f}",
               f"{tr.position_mm.mean():.3f} / {tr.position_mm.max():.3f}"]
        if with_paper:
            paper = PAPER_R1_TEST.get(m)
            row.append(" / ".join(f"{v:.2f}" for v in paper) if paper else "–")
        rows.append(row)
    for m, reason in cmp.skipped.items():
        rows.append([m, "–", "–", f"skipped: {reason}", "", ""] + ([""] if with_paper else []))
    return Table("Test and training errors per method (Table IV)", header, rows)


def analysis_tables(cmp: Comparison) -> list[Table]:
    """Observability, joint correlation (Table II), paired tests and the local parameter spread (Table V)."""
    a, tables = cmp.analysis, []
    if "observability" in a:
        o = a["observability"]
        tables.append(Table("Observability of the training set", [], [], [
            f"Condition number {o['condition_number']:.3g}; {o['rank']} of {o['parameters']} directions kept.",
            o["warning"] or "Every parameter direction is observable."] + [f"- {d}" for d in o["hidden_directions"]]))
    if "nominal_error_joint_correlation_test" in a:
        corr = a["nominal_error_joint_correlation_test"]
        tables.append(Table("Correlation of the nominal position error with each joint (test set, Table II)",
                            [f"q{j + 1}" for j in range(len(corr))], [[f"{c:.3f}" for c in corr]]))
    for key, title in (("paired_tests_vs_nominal", "the nominal model"), ("paired_tests_vs_fbf13", "the Fourier CDC")):
        if key in a:
            tables.append(Table(f"Paired tests against {title} (test position error, method minus reference)",
                                ["method", "mean difference mm", "t-test p", "Wilcoxon p"],
                                [[m, f"{t['mean_difference']:.3f}", f"{t['t_pvalue']:.2e}", f"{t['wilcoxon_pvalue']:.2e}"]
                                 for m, t in a[key].items()]))
    if "local_parameter_spread" in a:
        tables.append(Table("Spread of local parameters over clusters (Table V)", ["parameter", "mean", "std", "min", "max"],
                            [[n, f"{s['mean']:.4g}", f"{s['std']:.4g}", f"{s['min']:.4g}", f"{s['max']:.4g}"]
                             for n, s in a["local_parameter_spread"].items()]))
    return tables


def error_plots(errs: dict[str, Errors], rec: Recording, out: Path, tol: Tolerance, recommended: str | None = None,
                best: str | None = None) -> list[Image]:
    """Workspace map and CDFs of ``errs`` on ``rec`` (at most :data:`MAX_SERIES` rows: :func:`shown_series`, the
    recommended one highlighted), saved as PNG in ``out`` and returned for embedding."""
    names = shown_series(list(errs), recommended, best)
    shown = {n: errs[n] for n in names}
    left = len(errs) - len(names)
    more = f" ({left} more in the table)" if left else ""
    files = [(plots.save_figure(plots.workspace_figure(shown, rec.p, tol.position_mm, recommended),
                                out / "error_workspace.png"),
              f"position error over the workspace: measured tool x against height, coloured by error; "
              f"{', '.join(names)}{more}"),
             (plots.save_figure(plots.cdf_figure(shown, tol.position_mm, tol.orientation_deg, recommended),
                                out / "error_cdf.png"),
              f"cumulative distribution of the position and orientation errors, with the tolerance; "
              f"{', '.join(names)}{more}")]
    return [Image.from_file(caption, path) for path, caption in files]


def comparison_section(cmp: Comparison, test: Recording, out_dir: str | Path, tol: Tolerance,
                       with_paper: bool = False, title: str | None = None, test_label: str = "the test set",
                       paragraphs: list[str] | None = None) -> Section:
    """One arm's comparison: writes ``report.md`` and the PNG plots into ``out_dir`` and returns the section."""

    out = Path(out_dir)
    make_folders(out)  # removed again when a staged set of outputs fails (calibration.data.files.staged_outputs)
    best = (cmp.analysis.get("recommendation") or {}).get("best")
    images = error_plots(cmp.test_errors, test, out, tol, cmp.recommended, best)
    interp = cmp.models["fbf13"].interpolation() if cmp.recommended == "fbf13" else None
    if interp is not None:  # the Fourier model's own plots, only when it is the one put into service
        path = plots.save_figure(plots.singular_values_figure(np.asarray(interp.singular_values())),
                                 out / "fourier_singular_values.png")
        images.append(Image.from_file("singular values of the fbf13 coefficient matrix", path))
        if "nominal" in cmp.models:
            path = plots.save_figure(plots.correction_map_figure(cmp.models["fbf13"], cmp.models["nominal"], test.q,
                                                                 "fbf13 - nominal"), out / "fourier_correction_map.png")
            images.append(Image.from_file("position correction of the Fourier CDC over (q2, q3)", path))
    tables = [comparison_rows(cmp, with_paper)] + analysis_tables(cmp)
    why, why_table = recommendation_why(cmp, test_label)
    section = Section(title or f"Calibration comparison: {cmp.robot}",
                      [acceptance(m, e, tol) for m, e in cmp.test_errors.items()],
                      f"the {len(test)} poses of {test_label}", iso_table(cmp.models, test, test_label),
                      cmp.recommended, list(paragraphs or []), tables[:1], images, tables[1:], why, why_table,
                      comparison_warnings(cmp))
    md = [f"# {section.title}", ""] + acceptance_markdown(section, tol) + why + [""]
    for t in ([why_table] if why_table else []) + tables:
        md += t.markdown()
    md += ["## Plots", ""] + [f"![{im.caption}]({im.file})" for im in images] + [""]
    atomic_write_text(out / "report.md", "\n".join(md))
    return section


def acceptance_markdown(section: Section, tol: Tolerance) -> list[str]:
    """The pass/fail table and the recommendation as Markdown."""
    lines = [f"## Acceptance: max position error <= {tol.position_mm:g} mm and max orientation error <= "
             f"{tol.orientation_deg:g} deg on {section.acceptance_data}", "",
             "| model | max pos mm | max ori deg | within tolerance | result |", "|---|---:|---:|---:|---|"]
    lines += [f"| {a.model} | {a.max_position_mm:.3f} | {a.max_orientation_deg:.4f} | "
              f"{'–' if a.within is None else f'{100 * a.within:.1f} %'} | {'PASS' if a.passed else 'FAIL'} |"
              for a in section.acceptance]
    rec = f"Recommended model: {section.recommended}" if section.recommended else "No recommendation made."
    iso = f"ISO 9283: not available: {section.iso.reason}." if section.iso.reason else \
        f"ISO 9283: {len(section.iso.poses)} repeated poses (see report.html)."
    return lines + ["", rec, "", iso, ""]


def write_report(cmp: Comparison, test: Recording, out_dir: str | Path, with_paper: bool = False,
                 tolerance: Tolerance = Tolerance(), inputs: Sequence[tuple[str, str | Path | None]] = (),
                 command: str = "cellcal compare") -> list[Path]:
    """``compare --report``: ``report.md``, the PNG plots and ``report.html``; returns the files (html last)."""

    out = Path(out_dir)
    section = comparison_section(cmp, test, out, tolerance, with_paper)
    html = write_html(Page(section.title, command, tolerance, provenance(inputs), [section]), out)
    return sorted(out.glob("*.png")) + [out / "report.md", html]


@dataclass(frozen=True)
class SigmaMap:
    """The predicted position uncertainty at each pose of the evaluated recording (``evaluate --given``).

    Attributes:
        sigma_mm: predicted position sigma (RMS of the error norm) per pose [mm], shape (N,).
        outside: poses outside the joint range of the poses the sigma was predicted from, shape (N,).
        gaussian_over_2_sigma: the share of poses beyond 2 sigma a Gaussian error of the predicted covariances gives.
        source: where the sigma comes from, in words.
    """

    sigma_mm: np.ndarray
    outside: np.ndarray
    gaussian_over_2_sigma: float
    source: str


def _runs_text(mask: np.ndarray, most: int = 6) -> str:
    """Row ranges of the runs of True in ``mask`` (1-based, as a spreadsheet counts), the first ``most`` of them."""
    runs = plots.mask_runs(mask)
    text = ", ".join(f"{a + 1}" if a == b else f"{a + 1}-{b + 1}" for a, b in runs[:most])
    return text + (f" and {len(runs) - most} more runs" if len(runs) > most else "")


def sigma_parts(sigma: SigmaMap, model: str, e: Errors, out: Path, tol: Tolerance) -> tuple[str, Table, Image]:
    """The uncertainty map of one model: a visible paragraph (where 2 sigma is within the tolerance, where not,
    where the poses leave the training range, the share beyond 2 sigma against the Gaussian's), a table and the
    sigma-along-the-poses plot."""
    s, err = np.asarray(sigma.sigma_mm, dtype=float), np.asarray(e.position_mm, dtype=float)
    n = len(s)
    wide = 2 * s > tol.position_mm
    beyond = err > 2 * s
    text = (f"Predicted position uncertainty ({sigma.source}): 2 sigma is within the {tol.position_mm:g} mm tolerance "
            f"on {n - int(wide.sum())} of the {n} poses, where the prediction can be trusted"
            + (f"; beyond it on {int(wide.sum())} (rows {_runs_text(wide)})" if wide.any() else "")
            + (f". {int(sigma.outside.sum())} poses lie outside the training joint range, where the model extrapolates "
               f"(rows {_runs_text(sigma.outside)})" if sigma.outside.any() else ". Every pose lies inside the "
               "training joint range")
            + f". Measured: {100 * beyond.mean():.1f} % of the poses err by more than 2 sigma ({model}); a Gaussian "
              f"error of the predicted covariances would put {100 * sigma.gaussian_over_2_sigma:.1f} % there.")
    inside = ~sigma.outside
    rows = []
    for name, m in (("every pose", np.ones(n, dtype=bool)), ("inside the training range", inside),
                    ("outside the training range", sigma.outside)):
        if m.any():
            rows.append([name, str(int(m.sum())), f"{s[m].mean():.3f}", f"{s[m].max():.3f}", f"{err[m].mean():.3f}",
                         f"{err[m].max():.3f}", f"{100 * np.mean(wide[m]):.1f} %", f"{100 * np.mean(beyond[m]):.1f} %"])
    table = Table(f"Predicted uncertainty of {model} ({sigma.source})",
                  ["poses", "count", "sigma mean mm", "sigma max mm", "error mean mm", "error max mm",
                   "2 sigma over tolerance", "error over 2 sigma"], rows,
                  [f"sigma is the RMS of the position error norm predicted at each pose; a Gaussian error of the "
                   f"predicted covariances exceeds 2 sigma on {100 * sigma.gaussian_over_2_sigma:.1f} % of the poses "
                   f"(0.7 % for an isotropic 3-D error, 4.6 % for one along a single axis)."])
    path = plots.save_figure(plots.sigma_along_task_figure(s, err, sigma.outside, tol.position_mm, model),
                             out / "sigma_along_task.png")
    image = Image.from_file(f"predicted 2 sigma and the measured error of {model} along the poses, in their order; "
                            f"shaded: outside the training joint range", path)
    return text, table, image


def evaluation_section(title: str, models: dict[str, Any], rec: Recording, out_dir: str | Path, tol: Tolerance,
                       label: str, paragraphs: list[str] | None = None, recommended: str | None = None,
                       why: list[str] | None = None, next_steps: list[str] | None = None,
                       sigma: SigmaMap | None = None) -> Section:
    """Models evaluated on one recording (``evaluate``, ``recalibrate``): statistics, pass/fail, ISO, plots; with
    ``sigma``, the uncertainty map of the first model (:func:`sigma_parts`)."""
    from calibration.evaluation.metrics import error_stats

    errs = {n: errors(m, rec) for n, m in models.items()}
    rows = []
    for n, e in errs.items():
        s = error_stats(e)
        p, o = s["position_mm"], s["orientation_deg"]
        rows.append([n, models[n].method, str(models[n].n_parameters), f"{p['mean']:.3f}", f"{p['std']:.3f}",
                     f"{p['rms']:.3f}", f"{p['max']:.3f}", f"{o['mean']:.4f}", f"{o['max']:.4f}"])
    table = Table(f"Errors on {label}", ["model", "method", "params", "pos mean mm", "pos std mm", "pos RMS mm",
                                         "pos max mm", "ori mean deg", "ori max deg"], rows)
    paragraphs, tables, images = list(paragraphs or []), [table], error_plots(errs, rec, Path(out_dir), tol, recommended)
    if sigma is not None:
        first = next(iter(errs))
        text, sigma_table, sigma_image = sigma_parts(sigma, first, errs[first], Path(out_dir), tol)
        paragraphs.append(text)
        tables.append(sigma_table)
        images.append(sigma_image)
    return Section(title, [acceptance(n, e, tol) for n, e in errs.items()], f"the {len(rec)} poses of {label}",
                   iso_table(models, rec, label), recommended, paragraphs, tables, images, why=list(why or []),
                   next_steps=list(next_steps or []))


def write_evaluation_report(title: str, command: str, models: dict[str, Any], rec: Recording, out_dir: str | Path,
                            tol: Tolerance, inputs: Sequence[tuple[str, str | Path | None]], label: str,
                            paragraphs: list[str] | None = None, next_steps: list[str] | None = None,
                            why: list[str] | None = None, sigma: SigmaMap | None = None) -> Path:
    """``evaluate``/``recalibrate --report``: ``report.html`` (+ its PNGs) in ``out_dir``; returns the page; with
    ``sigma`` (``evaluate --given``) the uncertainty map along the poses."""
    from app.reports.provenance import provenance

    out = Path(out_dir)
    make_folders(out)  # removed again when a staged set of outputs fails (calibration.data.files.staged_outputs)
    record = provenance(inputs)
    section = evaluation_section(title, models, rec, out, tol, label, paragraphs, why=why, next_steps=next_steps,
                                 sigma=sigma)
    return write_html(Page(title, command, tol, record, [section]), out)


def write_demo_report(out_dir: Path, comparisons: dict[str, Comparison], tests: dict[str, Recording],
                      summary: dict[str, Any], tolerance: Tolerance | None = None, report_dir: Path | None = None,
                      inputs: Sequence[tuple[str, str | Path | None]] = ()) -> Path:
    """The demo's ``report.html`` (in ``report_dir``, default ``out_dir``): one section per arm.

    Each arm's ``report.md`` and PNG plots go to ``out_dir/<robot>/``.
    """

    tolerance = tolerance or Tolerance()
    cfg, planted = summary["config"], summary["planted"]
    intro = (f"Both arms simulated with planted geometric errors (joint origins sigma {planted['origin_std_mm']} mm, "
             f"axis tilts sigma {planted['tilt_std_deg']} deg) and a gravity joint compliance "
             f"({planted['compliance_rms_mm']} mm RMS); mocap noise {planted['mocap_noise_mm']} mm per axis per frame, "
             f"{cfg['mocap_rate_hz']:g} Hz, carried over Zenoh on loopback ({summary['mocap_frames_received']} frames "
             f"received). Anchor grid step {cfg['anchor_step_deg']:g} deg, {cfg['validation_poses']} random validation "
             f"poses per arm as the test set. Seed {cfg['seed']}, simulated time x{cfg['time_scale']:g}.")
    sections = []
    for robot, cmp in comparisons.items():
        r = summary["robots"][robot]
        text = (f"{r['samples']} samples measured of {r['targets']} targets ({r['skipped_targets']} skipped): "
                f"{r['train_samples']} training, {r['cpa_samples']} CPA sweep, {r['test_samples']} test; collection "
                f"took {r['collect_seconds']:.1f} s. Recordings {robot}/train.csv, {robot}/cpa.csv, {robot}/test.csv; "
                f"models in {robot}/models/.")
        sections.append(comparison_section(cmp, tests[robot], Path(out_dir) / robot, tolerance, False, robot,
                                           f"{robot}'s validation poses", [text]))
    page = Page("cellcal demo: calibration of the simulated cell", f"cellcal demo --seed {cfg['seed']}"
                + (" --full" if cfg["full"] else ""), tolerance, provenance(inputs), sections, [intro])
    return write_html(page, report_dir or out_dir)
