"""The acceptance report: one self-contained ``report.html`` per run (and ``report.md`` + PNGs for compare).

``compare``, ``evaluate``, ``diagnose``, ``recalibrate`` and ``demo`` write ``report.html`` into ``--report DIR``
from the jinja2 template ``templates/report.html.j2``. Its first screen (and printed page) is the sign-off: one
:class:`~app.analysis.verdict.Verdict` per arm or question on the model to put into service, its conditions being
every warning the command gave (:mod:`app.analysis.command_warnings`) and the section's own, the next step, and why
the model was chosen (:func:`recommendation_why`). Then, folded, a page holds for each arm or question:

- the tolerance (default 1 mm and 1 deg, cold spray) and pass/fail per model: a model passes when its largest
  position error and its largest orientation error on the evaluation poses are within the tolerance; the
  fraction of poses within both is shown next to it;
- ISO 9283 AP_p / RP_l per repeated pose (:mod:`calibration.iso9283`), or "not available" and why;
- the recommended model when one was chosen (:attr:`app.analysis.compare.Comparison.recommended`; this module
  never picks one);
- the date, the cellcal version and the sha256 of every input file (:func:`app.provenance.provenance`);
- tables, and the plots (:mod:`app.analysis.plots`) embedded as base64 PNG so the single file can be mailed.
"""

from __future__ import annotations

import base64
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from app.analysis import plots
from app.analysis.command_warnings import register_page, warnings_so_far
from app.analysis.compare import Comparison
from app.analysis.verdict import ACCEPTED, CONDITIONAL, default_next_steps, page_verdict, verdict
from calibration.errors import CellCalError
from calibration.files import atomic_write_text, make_folders, read_output_bytes
from calibration.iso9283 import RepeatedPose, accuracy_per_pose, repeated_poses
from calibration.metrics import Errors, errors, predict
from calibration.recording import Recording

PAPER_R1_TEST = {  # the paper's Table IV (R1 test set, position mean / std / max mm)
    "nominal": (1.29, 0.21, 1.72), "base": (0.53, 0.25, 1.27), "cpa": (0.44, 0.20, 0.99),
    "nls0": (0.41, 0.21, 0.99), "nls1": (0.92, 0.79, 3.46), "nearest": (0.32, 0.17, 0.81),
    "linear": (0.31, 0.17, 0.81), "cubic": (0.31, 0.17, 0.83), "rbf": (0.31, 0.17, 0.83),
    "fbf13": (0.31, 0.14, 0.74), "fbf7": (0.32, 0.16, 0.81), "nn": (0.34, 0.13, 0.78), "ae": (0.31, 0.14, 0.73),
}

#: The paper's column in a comparison table: its figures, on its own R1 test set (:func:`shows_paper`).
PAPER_COLUMN = "paper's Table IV on its R1 test set: pos mean / std / max mm"

REPORT_HTML = "report.html"


@dataclass(frozen=True)
class Tolerance:
    """The acceptance tolerance: largest position error [mm] and largest orientation error [deg]."""

    position_mm: float = 1.0
    orientation_deg: float = 1.0

    def __post_init__(self) -> None:
        for name, v in (("--tolerance-mm", self.position_mm), ("--tolerance-deg", self.orientation_deg)):
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise CellCalError(f"{name}: expected a positive finite number, got {v!r}")


@dataclass(frozen=True)
class Acceptance:
    """Pass/fail of one model on the evaluation poses.

    Attributes:
        model: row name.
        n_poses: evaluation poses.
        max_position_mm, max_orientation_deg: largest errors on them.
        within: fraction of poses with both errors within the tolerance; None when per-pose errors are not kept.
        passed: both largest errors within the tolerance.
    """

    model: str
    n_poses: int
    max_position_mm: float
    max_orientation_deg: float
    within: float | None
    passed: bool


def acceptance(name: str, e: Errors, tol: Tolerance) -> Acceptance:
    """Pass/fail of one model from its per-pose errors."""
    pos, ori = np.asarray(e.position_mm), np.asarray(e.orientation_deg)
    ok = (pos <= tol.position_mm) & (ori <= tol.orientation_deg)
    max_p, max_o = float(np.max(pos)), float(np.max(ori))
    return Acceptance(name, len(pos), max_p, max_o, float(np.mean(ok)),
                      bool(max_p <= tol.position_mm and max_o <= tol.orientation_deg))


def acceptance_from_max(name: str, n: int, max_mm: float, max_deg: float, tol: Tolerance) -> Acceptance:
    """Pass/fail from the largest errors alone (the fraction within is then not available)."""
    return Acceptance(name, n, float(max_mm), float(max_deg), None,
                      bool(max_mm <= tol.position_mm and max_deg <= tol.orientation_deg))


@dataclass(frozen=True)
class IsoTable:
    """ISO 9283 figures of one recording: the repeated poses with RP_l, and AP_p per model (or why not)."""

    source: str
    poses: list[RepeatedPose] = field(default_factory=list)
    ap_mm: dict[str, np.ndarray] = field(default_factory=dict)
    reason: str | None = None

    @property
    def min_visits(self) -> int:
        return min(r.n for r in self.poses)

    @property
    def max_visits(self) -> int:
        return max(r.n for r in self.poses)


def iso_table(models: dict[str, Any], rec: Recording, label: str) -> IsoTable:
    """ISO 9283 AP_p (per model) and RP_l on the poses ``rec`` repeats; ``label`` names the recording."""
    poses = repeated_poses(rec.q, rec.p)
    if not poses:
        return IsoTable(label, reason=f"no repeated poses (no two rows of {label} have identical joint values)")
    return IsoTable(label, poses, {n: accuracy_per_pose(poses, rec.p, predict(m, rec)[1]) for n, m in models.items()})


def iso_unavailable(label: str, reason: str) -> IsoTable:
    return IsoTable(label, reason=reason)


@dataclass(frozen=True)
class Table:
    """A captioned table (cells already formatted); rendered both in HTML and Markdown."""

    caption: str
    header: list[str]
    rows: list[list[str]]
    paragraphs: list[str] = field(default_factory=list)

    def markdown(self) -> list[str]:
        lines = [f"## {self.caption}", ""] + self.paragraphs + ([""] if self.paragraphs else [])
        if self.rows:
            lines += ["| " + " | ".join(self.header) + " |", "|" + "---|" * len(self.header)]
            lines += ["| " + " | ".join(r) + " |" for r in self.rows]
        return lines + [""]


@dataclass(frozen=True)
class Image:
    """A PNG plot embedded in the page."""

    caption: str
    png: bytes
    file: str = ""

    @property
    def data_uri(self) -> str:
        return "data:image/png;base64," + base64.b64encode(self.png).decode("ascii")

    @classmethod
    def from_file(cls, caption: str, path: Path) -> Image:
        return cls(caption, read_output_bytes(path), Path(path).name)  # a staged plot: under its temporary name


@dataclass
class Section:
    """One part of a page (one arm, or the one question a command answers)."""

    title: str
    acceptance: list[Acceptance]
    acceptance_data: str
    iso: IsoTable
    recommended: str | None = None
    paragraphs: list[str] = field(default_factory=list)
    tables: list[Table] = field(default_factory=list)
    images: list[Image] = field(default_factory=list)
    details: list[Table] = field(default_factory=list)  # after the plots
    why: list[str] = field(default_factory=list)  # why this model: the held-out figures, the test used
    why_table: Table | None = None
    conditions: list[str] = field(default_factory=list)  # this section's own warnings (beside the command's)
    next_steps: list[str] = field(default_factory=list)

    @property
    def recommended_acceptance(self) -> Acceptance | None:
        return next((a for a in self.acceptance if a.model == self.recommended), None)

    @property
    def in_service(self) -> str | None:
        """The model the page judges for service: the recommended one, or the only one evaluated."""
        if self.recommended is not None:
            return self.recommended
        return self.acceptance[0].model if len(self.acceptance) == 1 else None


@dataclass
class Page:
    """A whole ``report.html``."""

    title: str
    command: str
    tolerance: Tolerance
    provenance: dict[str, Any]
    sections: list[Section]
    notes: list[str] = field(default_factory=list)


def render_html(page: Page) -> str:
    """The page as one self-contained HTML document (jinja2, autoescaped); its verdicts carry every warning the
    running command gave so far (:mod:`app.analysis.command_warnings`)."""
    import jinja2

    given = warnings_so_far()
    verdicts = [verdict(s, page.tolerance, given) for s in page.sections]
    steps = [s.next_steps or default_next_steps(v) for s, v in zip(page.sections, verdicts)]
    env = jinja2.Environment(loader=jinja2.PackageLoader("app.analysis", "templates"),
                             autoescape=jinja2.select_autoescape(["html", "j2"]), undefined=jinja2.StrictUndefined,
                             trim_blocks=False)
    return env.get_template("report.html.j2").render(
        page=page, verdicts=verdicts, steps=steps, overall=page_verdict(verdicts),
        overall_css={ACCEPTED: "accepted", CONDITIONAL: "conditional"}.get(page_verdict(verdicts), "rejected"),
        conditions=list(dict.fromkeys([*given, *_section_conditions(page)])))


def _section_conditions(page: Page) -> list[str]:
    """The sections' own warnings (those no command printed: the demo's comparisons), named by section when several."""
    several = len(page.sections) > 1
    return [" ".join((f"{s.title}: {c}" if several else c).split()) for s in page.sections for c in s.conditions]


def write_html(page: Page, out_dir: str | Path) -> Path:
    """Write ``out_dir/report.html`` atomically (the folder is created); returns its path. A warning the command
    gives after this is written still reaches the page: it is written again when the command ends."""
    out = Path(out_dir)
    make_folders(out)  # removed again when a staged set of outputs fails (calibration.files.staged_outputs)
    path = out / REPORT_HTML
    atomic_write_text(path, render_html(page))
    register_page(lambda: atomic_write_text(path, render_html(page)))
    return path


# -- what each command puts on the page ------------------------------------------------------------------------


def _f(v: float | None, fmt: str) -> str:
    return "–" if v is None else format(v, fmt)


def shows_paper(robot: str, test: Recording) -> bool:
    """Whether a comparison shows the paper's Table IV figures (:data:`PAPER_R1_TEST`) beside its own: only for R1
    tested on a recording in the Welding_Motoman layout, the paper's own cell's data. On a simulated recording, or
    any in the native CSV format, the paper's column stood beside the figures as if they were comparable."""
    from calibration.recording import welding_layout

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


#: Most series a plot draws (issue 34: 23 series of repeating colours could not be read).
MAX_SERIES = 6


def shown_series(names: list[str], recommended: str | None = None, best: str | None = None) -> list[str]:
    """The rows a plot draws, at most :data:`MAX_SERIES`: nominal, the paper's method (fbf13), nls1, the recommended
    and the best on held-out clusters, in the table's order; with none of these, the first rows."""
    wanted = {"nominal", "fbf13", "nls1", recommended, best} - {None}
    chosen = [n for n in names if n in wanted]
    return (chosen or list(names))[:MAX_SERIES]


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


def _p(p: float) -> str:
    """A p-value as stored (rounded to 4 decimals): "< 0.0001" rather than "0"."""
    return "< 0.0001" if p < 1e-4 else f"= {p:.2g}"


def recommendation_why(cmp: Comparison, test_label: str) -> tuple[list[str], Table | None]:
    """Why ``cmp`` recommends its model: the rule, the held-out figures that decided, and the test figures beside
    them (which played no part); a table of the recommended model, the best and the cheaper candidates."""
    rec = cmp.analysis.get("recommendation")
    if not rec or cmp.recommended is None:
        return ["No recommendation made."], None
    cands, m, best = rec["candidates"], rec["method"], rec["best"]
    c = cands[m]
    text = [f"{m} ({c['n_parameters']} parameters) is recommended by the rule: {rec['rule']}. It was chosen on the "
            f"training data alone (k-fold over whole clusters); {test_label} played no part."]
    if m == best:
        text.append(f"{m} has the smallest held-out position RMS: {c['heldout_rms_mm']:.3f} mm.")
    else:
        b = cands[best]
        text.append(f"Held-out RMS {c['heldout_rms_mm']:.3f} mm, tied with the best, {best} ({b['heldout_rms_mm']:.3f} "
                    f"mm, {b['n_parameters']} parameters; p = {c['p_worse_than_best']:.2f} that {m} is worse).")
    cheaper = sorted((n for n, v in cands.items() if v["n_parameters"] < c["n_parameters"]),
                     key=lambda n: -cands[n]["n_parameters"])[:4]
    if cheaper:  # their figures are in the table
        text.append(f"The models with fewer parameters ({', '.join(cheaper)}) were worse than the best on held-out "
                    "clusters (one-sided p below 5 %), so the rule passed over them.")
    rows = []
    for n in dict.fromkeys([m, best, *cheaper]):
        v = cands[n]
        te = cmp.test_errors.get(n)
        role = "recommended" if n == m else "best held-out" if n == best else "fewer parameters"
        p = _p(v["p_worse_than_best"]).removeprefix("= ")
        rows.append([n, role, str(v["n_parameters"]), f"{v['heldout_rms_mm']:.3f}", p,
                     "tied" if v["tied"] else "worse", "–" if te is None else
                     f"{float(np.sqrt(np.mean(np.asarray(te.position_mm) ** 2))):.3f}"])
    table = Table("The held-out figures that decided", ["model", "role", "params", "held-out RMS mm",
                                                        "p worse than best", "against the best",
                                                        f"RMS on {test_label} mm (not used)"], rows)
    return text, table


def comparison_section(cmp: Comparison, test: Recording, out_dir: str | Path, tol: Tolerance,
                       with_paper: bool = False, title: str | None = None, test_label: str = "the test set",
                       paragraphs: list[str] | None = None) -> Section:
    """One arm's comparison: writes ``report.md`` and the PNG plots into ``out_dir`` and returns the section."""
    from app.analysis.compare import comparison_warnings

    out = Path(out_dir)
    make_folders(out)  # removed again when a staged set of outputs fails (calibration.files.staged_outputs)
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
                 tolerance: Tolerance = Tolerance(), inputs: list[tuple[str, Any]] | tuple = (),
                 command: str = "cellcal compare") -> list[Path]:
    """``compare --report``: ``report.md``, the PNG plots and ``report.html``; returns the files (html last)."""
    from app.provenance import provenance

    out = Path(out_dir)
    section = comparison_section(cmp, test, out, tolerance, with_paper)
    html = write_html(Page(section.title, command, tolerance, provenance(inputs), [section]), out)
    return sorted(out.glob("*.png")) + [out / "report.md", html]


def evaluation_section(title: str, models: dict[str, Any], rec: Recording, out_dir: str | Path, tol: Tolerance,
                       label: str, paragraphs: list[str] | None = None, recommended: str | None = None,
                       why: list[str] | None = None, next_steps: list[str] | None = None) -> Section:
    """Models evaluated on one recording (``evaluate``, ``recalibrate``): statistics, pass/fail, ISO, plots."""
    from calibration.metrics import error_stats

    errs = {n: errors(m, rec) for n, m in models.items()}
    rows = []
    for n, e in errs.items():
        s = error_stats(e)
        p, o = s["position_mm"], s["orientation_deg"]
        rows.append([n, models[n].method, str(models[n].n_parameters), f"{p['mean']:.3f}", f"{p['std']:.3f}",
                     f"{p['rms']:.3f}", f"{p['max']:.3f}", f"{o['mean']:.4f}", f"{o['max']:.4f}"])
    table = Table(f"Errors on {label}", ["model", "method", "params", "pos mean mm", "pos std mm", "pos RMS mm",
                                         "pos max mm", "ori mean deg", "ori max deg"], rows)
    return Section(title, [acceptance(n, e, tol) for n, e in errs.items()], f"the {len(rec)} poses of {label}",
                   iso_table(models, rec, label), recommended, list(paragraphs or []), [table],
                   error_plots(errs, rec, Path(out_dir), tol, recommended), why=list(why or []),
                   next_steps=list(next_steps or []))


def write_evaluation_report(title: str, command: str, models: dict[str, Any], rec: Recording, out_dir: str | Path,
                            tol: Tolerance, inputs: list[tuple[str, Any]], label: str,
                            paragraphs: list[str] | None = None, next_steps: list[str] | None = None) -> Path:
    """``evaluate``/``recalibrate --report``: ``report.html`` (+ its PNGs) in ``out_dir``; returns the page."""
    from app.provenance import provenance

    out = Path(out_dir)
    make_folders(out)  # removed again when a staged set of outputs fails (calibration.files.staged_outputs)
    record = provenance(inputs)
    section = evaluation_section(title, models, rec, out, tol, label, paragraphs, next_steps=next_steps)
    return write_html(Page(title, command, tol, record, [section]), out)


def write_demo_report(out_dir: Path, comparisons: dict[str, Comparison], tests: dict[str, Recording],
                      summary: dict[str, Any], tolerance: Tolerance | None = None, report_dir: Path | None = None,
                      inputs: list[tuple[str, Any]] | tuple = ()) -> Path:
    """The demo's ``report.html`` (in ``report_dir``, default ``out_dir``): one section per arm.

    Each arm's ``report.md`` and PNG plots go to ``out_dir/<robot>/``.
    """
    from app.provenance import provenance

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
