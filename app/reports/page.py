"""The acceptance report: one self-contained ``report.html`` per run (and ``report.md`` + PNGs for compare).

``compare``, ``evaluate``, ``diagnose``, ``recalibrate`` and ``demo`` write ``report.html`` into ``--report DIR``
from the jinja2 template ``templates/report.html.j2``. Its first screen (and printed page) is the sign-off: one
:class:`~app.reports.verdict.Verdict` per arm or question on the model to put into service, its conditions being
every warning the command gave (:mod:`app.reports.command_warnings`) and the section's own, the next step, and why
the model was chosen (:func:`recommendation_why`). Then, folded, a page holds for each arm or question:

- the tolerance (default 1 mm and 1 deg, cold spray) and pass/fail per model: a model passes when its largest
  position error and its largest orientation error on the evaluation poses are within the tolerance; the
  fraction of poses within both is shown next to it;
- ISO 9283 AP_p / RP_l per repeated pose (:mod:`calibration.evaluation.iso9283`), or "not available" and why;
- the recommended model when one was chosen (:attr:`calibration.evaluation.comparison.Comparison.recommended`; this module
  never picks one);
- the date, the cellcal version and the sha256 of every input file (:func:`app.reports.provenance.provenance`);
- tables, and the plots (:mod:`app.reports.plots`) embedded as base64 PNG so the single file can be mailed.
"""

from __future__ import annotations

import base64
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from app.reports.acceptance import Acceptance, IsoTable, Tolerance
from app.reports.command_warnings import register_page, warnings_so_far
from app.reports.verdict import ACCEPTED, CONDITIONAL, next_steps, page_verdict, verdict
from calibration.data.files import atomic_write_text, make_folders, read_output_bytes
from calibration.evaluation.comparison import Comparison

REPORT_HTML = "report.html"


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
    running command gave so far (:mod:`app.reports.command_warnings`)."""
    import jinja2

    given = warnings_so_far()
    verdicts = [verdict(s, page.tolerance, given) for s in page.sections]
    steps = [next_steps(v, s.next_steps) for s, v in zip(page.sections, verdicts)]
    env = jinja2.Environment(loader=jinja2.PackageLoader("app.reports", "templates"),
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
    make_folders(out)  # removed again when a staged set of outputs fails (calibration.data.files.staged_outputs)
    path = out / REPORT_HTML
    atomic_write_text(path, render_html(page))
    register_page(lambda: atomic_write_text(path, render_html(page)))
    return path


# -- what each command puts on the page ------------------------------------------------------------------------


def _f(v: float | None, fmt: str) -> str:
    return "–" if v is None else format(v, fmt)


#: Most series a plot draws (issue 34: 23 series of repeating colours could not be read).
MAX_SERIES = 6


def shown_series(names: list[str], recommended: str | None = None, best: str | None = None) -> list[str]:
    """The rows a plot draws, at most :data:`MAX_SERIES`: nominal, the paper's method (fbf13), nls1, the recommended
    and the best on held-out clusters, in the table's order; with none of these, the first rows."""
    wanted = {"nominal", "fbf13", "nls1", recommended, best} - {None}
    chosen = [n for n in names if n in wanted]
    return (chosen or list(names))[:MAX_SERIES]


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


