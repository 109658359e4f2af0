"""The sign-off page of every report (issue 34): one verdict for the model put into service, every warning the
command gave among its conditions, why the model was chosen, the next step, all in the first screen; plots of at
most six series with the recommended one highlighted; titles once; the warnings collected structurally."""

from __future__ import annotations

import html as html_lib
import re
import sys
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pytest

from app.cli.commands import main
from app.reports.acceptance import Acceptance, Tolerance, iso_unavailable
from app.reports.command_warnings import collecting, warnings_so_far
from app.reports.page import MAX_SERIES, Page, Section, shown_series, write_html
from app.reports.verdict import ACCEPTED, CONDITIONAL, NOT_ACCEPTED, REMEDIES, Verdict, next_steps, verdict
from calibration.data.recording import write_recording
from tests.app.browser import screenshot_dom_pdf
from tests.app.reports.test_report import _Page
from tests.conftest import SIM_FAST, cluster_design, measure, write_backlash_case


@pytest.fixture(scope="module")
def recs(tmp_path_factory, synthetic_arm):
    """train.csv (joints within about +-45 deg), wide.csv (random poses to +-69 deg: outside the training range) and
    narrow.csv (four clusters of train: a training set that leaves parameter directions unseen)."""
    _, _, truth = synthetic_arm
    root = tmp_path_factory.mktemp("signoff")
    q, cluster = cluster_design(step_deg=20.0)
    write_recording(measure(truth.fk, q, 0.02, 0.01, 1, cluster), root / "train.csv")
    write_recording(measure(truth.fk, q[:28], 0.02, 0.01, 4, cluster[:28]), root / "narrow.csv")
    write_recording(measure(truth.fk, np.random.default_rng(3).uniform(-1.2, 1.2, (60, 6)), 0.02, 0.01, 2),
                    root / "wide.csv")
    return root


def _warnings(err: str) -> list[str]:
    return [" ".join(line[len("warning: "):].split()) for line in err.splitlines() if line.startswith("warning: ")]


def _conditions(html: Path) -> list[str]:
    text = html.read_text()
    box = re.search(r'<ul id="conditions">(.*?)</ul>', text, re.S)
    items = re.findall(r"<li>(.*?)</li>", box.group(1), re.S) if box else []
    import html as h

    return [" ".join(h.unescape(i).split()) for i in items]


def test_evaluate_report_carries_the_extrapolation_warning(written, recs):
    html, given = written("evaluate")
    assert any("outside the joint range" in w for w in given), given
    assert _conditions(html) == given  # each warning, once, in the order given
    page = _Page(html.read_text())
    assert "accepted with conditions" in page.all_text.lower() or "not accepted" in page.all_text.lower()
    steps = re.search(r'<ul class="next-step">(.*?)</ul>', html.read_text(), re.S).group(1)
    assert "cellcal select" in steps and str(recs / "wide.csv") in steps and str(recs / "train.csv") in steps


def test_compare_report_carries_the_comparison_warnings(written):
    html, given = written("compare")
    assert given, "the narrow training set gave no warning: this test checks nothing"
    conditions = _conditions(html)
    assert set(given) <= set(conditions) and len(conditions) == len(set(conditions))


def test_diagnose_report_carries_its_warnings(written):
    html, given = written("diagnose")
    assert set(given) <= set(_conditions(html))
    root = html.parent.parent
    assert f"--train {root / 'fit.csv'}" in html.read_text()  # the command line, not just "cellcal diagnose"
    headings = re.findall(r"<h[1-6][^>]*>(.*?)</h[1-6]>", html.read_text(), re.S)
    assert headings.count("Diagnosis: R1") == 1 and len(headings) == len(set(headings))  # every title once


def test_a_warning_given_after_the_page_was_written_still_reaches_it(tmp_path):
    """The page is written again when the command ends: the order of the code cannot drop a warning."""
    section = Section("Evaluation", [Acceptance("pi", 10, 0.2, 0.1, 1.0, True)], "the 10 poses",
                      iso_unavailable("x", "none"))
    page = Page("Evaluation", "cellcal evaluate", Tolerance(), {"created_utc": "", "cellcal_version": "",
                                                                "inputs": []}, [section])
    with collecting():
        print("warning: first", file=sys.stderr)
        html = write_html(page, tmp_path)
        print("warning: given after the page was written", file=sys.stderr)
        assert warnings_so_far() == ["first", "given after the page was written"]
    assert _conditions(html) == ["first", "given after the page was written"]
    assert 'data-status="accepted with conditions"' in html.read_text()


def test_logged_warnings_are_collected_too(tmp_path):
    import logging

    with collecting():
        logging.getLogger("cellcal.app").warning("joint compliance cannot be tested: %s", "no mass")
        logging.getLogger("other").warning("not ours")
        assert warnings_so_far() == ["joint compliance cannot be tested: no mass"]
    assert warnings_so_far() == []


@pytest.mark.parametrize("passed", [True, False])
@pytest.mark.parametrize("warned", [[], ["frames differ"]])
@pytest.mark.parametrize("recommended", [None, "b", "missing"])
def test_the_verdict_over_its_inputs(passed, warned, recommended):
    rows = [Acceptance("a", 5, 0.3, 0.1, 1.0, True), Acceptance("b", 5, 0.5 if passed else 1.5, 0.1, 0.8, passed)]
    section = Section("R1", rows, "the 5 poses", iso_unavailable("x", "none"), recommended,
                      conditions=["unstable"] if recommended == "b" else [])
    v = verdict(section, Tolerance(), warned)
    if recommended != "b":  # two models, none named: nothing to put into service
        assert v.status == NOT_ACCEPTED and v.model in (None, "missing")
        return
    conditions = [*warned, "unstable"]
    assert list(v.conditions) == conditions
    assert v.status == (NOT_ACCEPTED if not passed else CONDITIONAL if conditions else ACCEPTED)
    single = Section("R1", rows[1:], "the 5 poses", iso_unavailable("x", "none"))
    assert verdict(single, Tolerance(), []).status == (ACCEPTED if passed else NOT_ACCEPTED)


@pytest.mark.parametrize("seed", range(20))
def test_plots_draw_at_most_six_series_and_always_the_recommended(seed):
    from calibration.method_names import METHODS

    rng = np.random.default_rng(seed)
    names = [str(n) for n in rng.permutation(list(dict.fromkeys([*METHODS, "m (file)", "candidate"])))]
    names = names[: rng.integers(1, len(names) + 1)]
    recommended, best = (rng.choice(names) for _ in range(2))
    shown = shown_series(names, recommended, best)
    assert 1 <= len(shown) <= MAX_SERIES and len(set(shown)) == len(shown)
    assert recommended in shown and best in shown
    assert shown == [n for n in names if n in shown]  # the table's order


def test_the_cdf_highlights_the_recommended_and_keeps_colours_apart(recs):
    import matplotlib.pyplot as plt

    from app.reports import plots
    from calibration.data.recording import read_recording
    from calibration.evaluation.metrics import Errors
    from calibration.method_names import METHODS

    rec = read_recording(recs / "wide.csv")
    rng = np.random.default_rng(1)
    errs = {m: Errors(rng.uniform(0.01, 2, len(rec)), rng.uniform(0.01, 1, len(rec))) for m in METHODS}
    names = shown_series(list(errs), "pi+nn", "pi+ae")
    fig = plots.cdf_figure({n: errs[n] for n in names}, 1.0, 1.0, "pi+nn")
    lines = [ln for ln in fig.axes[0].get_lines() if not ln.get_label().startswith("tolerance")]
    assert len(lines) == len(names) <= MAX_SERIES
    assert len({ln.get_color() for ln in lines}) == len(lines)
    widths = {ln.get_label(): ln.get_linewidth() for ln in lines}
    assert widths["pi+nn (recommended)"] > max(w for n, w in widths.items() if n != "pi+nn (recommended)")
    assert not fig.axes[0].get_legend() and fig.legends  # one legend, below the panels, off the curves
    plt.close(fig)


def test_the_demo_folds_the_methods_it_skipped_for_one_reason_into_one_line():
    from app.workflows.demo import summary_table
    from calibration.method_names import METHODS

    stats = {"test": {"position_mm": {"mean": 0.3, "max": 0.9}, "orientation_deg": {"mean": 0.01}}}
    skipped = {m: "not requested" for m in list(METHODS)[3:]}
    skipped["cpa"] = "no single-joint sweep data given (--cpa DATA)"
    arm = {"methods": {m: stats for m in list(METHODS)[:3]}, "skipped_methods": skipped, "recommended": "nls1"}
    lines = summary_table({"robots": {"R1": arm, "R2": arm}}).splitlines()
    per_arm = [ln for ln in lines if ln.startswith("R1") and "skipped" in ln]
    assert len(per_arm) == 2, per_arm  # one line per reason, not one per method
    folded = next(ln for ln in per_arm if "not requested" in ln)
    assert all(m in folded for m in list(METHODS)[3:] if m != "cpa")
    assert sum("R2" in ln for ln in lines) == 3 + 2 + 1


def test_a_warning_over_several_lines_is_kept_whole():
    with collecting():
        print("warning: first line\nsecond line", file=sys.stderr)
        print("not a warning", file=sys.stderr)
        sys.stderr.write("progress 10%\rwarning: after a bar\n")
        assert warnings_so_far() == ["first line second line", "after a bar"]


# -- every report the product writes, rendered in headless Chromium: the first screen and the printed page ---------

REPORT_KINDS = ("evaluate", "compare", "diagnose", "recalibrate", "demo")
SCREEN = (1280, 800)


def _quiet_run(argv: list[str]) -> list[str]:
    """``cellcal argv`` (exit 0); the warnings it printed on stderr, in order."""
    import contextlib
    import io

    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        assert main(argv) == 0, err.getvalue()[-2000:]
    return _warnings(err.getvalue())


def _demo_page(root: Path, recs: Path) -> list[str]:
    """The demo's page (one section per arm) from two small comparisons, while the run warned once."""
    from app.reports.sections import write_demo_report
    from app.workflows.compare import run_comparison
    from calibration.data.recording import read_recording
    from calibration.methods.fitter import Fitter
    from cell_config import load_cell

    test = read_recording(recs / "wide.csv")
    cmp = run_comparison(Fitter.for_arm(load_cell().robot("R1").arm(), read_recording(recs / "train.csv")), test,
                         ["nominal", "nls1", "pi"])
    cmps = {"R1": cmp, "R2": cmp}  # the page's layout is under test: one comparison serves as both arms'
    arm = {"samples": 10, "targets": 10, "skipped_targets": 0, "train_samples": 5, "cpa_samples": 0,
           "test_samples": 5, "collect_seconds": 1.0}
    summary = {"robots": {"R1": arm, "R2": arm}, "mocap_frames_received": 100,
               "config": {"full": False, "seed": 0, "time_scale": 5.0, "mocap_rate_hz": 120.0, "anchor_step_deg": 10.0,
                          "validation_poses": 5},
               "planted": {"origin_std_mm": 0.5, "tilt_std_deg": 0.05, "compliance_rms_mm": 1.0, "mocap_noise_mm": 0.02}}
    with collecting():
        print("warning: R2's mocap lost 3 % of its frames", file=sys.stderr)
        write_demo_report(root, cmps, {"R1": test, "R2": test}, summary, report_dir=root / "rep")
        given = warnings_so_far()
    return given


def _write_report(kind: str, root: Path, recs: Path) -> list[str]:
    """Write ``kind``'s report.html into ``root/rep`` the way the command does; the warnings the run gave."""
    rep = str(root / "rep")
    if kind == "evaluate":  # test poses outside the training range: the extrapolation warning
        model = root / "m.yaml"
        _quiet_run(["fit", "--robot", "R1", "--train", str(recs / "train.csv"), "--method", "nls1", "--out", str(model)])
        return _quiet_run(["evaluate", "--model", str(model), "--test", str(recs / "wide.csv"), "--report", rep])
    if kind == "compare":  # a narrow training set: observability (and the methods' own warnings)
        return _quiet_run(["compare", "--robot", "R1", "--train", str(recs / "narrow.csv"), "--test",
                           str(recs / "wide.csv"), "--methods", "nominal,nls1,pi", "--report", rep])
    if kind == "diagnose":
        write_backlash_case(root)
        return _quiet_run(["diagnose", "--robot", "R1", "--train", str(root / "fit.csv"), "--test",
                           str(root / "ho.csv"), "--report", rep])
    if kind == "recalibrate":  # the simulated cell, a small grid plan
        plan = root / "plan.json"
        _quiet_run(["plan", "--robot", "R1", "--out", str(plan), "--design", "grid", "--q2-step", "35",
                    "--q3-step", "30"])
        return _quiet_run(["recalibrate", "--robot", "R1", "--plan", str(plan), "--model-dir", str(root / "models"),
                           "--method", "nls1", "--validation", "6", "--validation-seed", "2", "--sim", *SIM_FAST,
                           "--no-progress", "--report", rep])
    return _demo_page(root, recs)


@dataclass(frozen=True)
class Rendered:
    """One report as the browser showed and printed it."""

    html: Path
    given: list[str]  # the warnings the run printed
    shot: Path
    dom: str
    pdf_pages: list[str]  # the printed page's text, one string per page (pypdf)


def _flat(text: str) -> str:
    """Text to compare across renderings: ligatures unfolded (NFKC), case and every space and hyphen dropped (the
    PDF breaks a long path or word at any character)."""
    import unicodedata

    return re.sub(r"[\s\u00ad-]+", "", unicodedata.normalize("NFKC", html_lib.unescape(text))).lower()


@pytest.fixture(scope="module")
def written(tmp_path_factory, recs) -> Callable[[str], tuple[Path, list[str]]]:
    """Each report kind written once, on first use: its report.html and the warnings the run printed."""
    cache: dict[str, tuple[Path, list[str]]] = {}

    def get(kind: str) -> tuple[Path, list[str]]:
        if kind not in cache:
            root = tmp_path_factory.mktemp(kind)
            given = _write_report(kind, root, recs)
            cache[kind] = (root / "rep" / "report.html", given)
        return cache[kind]

    return get


@pytest.fixture(scope="module")
def rendered(written, chromium) -> Callable[[str], Rendered]:
    """Each report kind rendered once (screenshot, DOM and PDF from one page load), on first use."""
    pypdf = pytest.importorskip("pypdf", reason="pypdf (the dev extras) reads the printed pages")
    cache: dict[str, Rendered] = {}

    def get(kind: str) -> Rendered:
        if kind not in cache:
            html, given = written(kind)
            root = html.parent.parent
            shot, dom, pdf = screenshot_dom_pdf(chromium, root, html.as_uri(), f"{kind}_first_screen.png", SCREEN)
            pages = [p.extract_text() or "" for p in pypdf.PdfReader(pdf).pages]
            cache[kind] = Rendered(html, given, shot, dom, pages)
        return cache[kind]

    return get


#: The verdict box's border colour per status (the template's .verdict.accepted / .conditional / .rejected).
BORDER_RGB = {"accepted": (0x2A, 0x8A, 0x3A), "accepted with conditions": (0xC9, 0x8A, 0x00),
              "not accepted": (0xBB, 0x22, 0x22)}


@pytest.mark.parametrize("kind", REPORT_KINDS)
def test_the_first_screen_holds_the_verdict_and_every_warning(kind, rendered):
    """A real render at 1280 x 800: the verdict and the conditions end within the first screen (their DOM positions
    in the headless run), every warning the run printed is on the page, and the shot shows the verdict's box in the
    colour of its status."""
    import matplotlib.image as mpimg

    r = rendered(kind)
    page = _Page(r.dom)
    text = " ".join(page.all_text.split())
    assert all(w in text for w in r.given), (r.given, kind)
    assert 0 < int(page.body_attrs["data-verdict-bottom"]) <= SCREEN[1]
    assert 0 < int(page.body_attrs["data-conditions-bottom"]) <= SCREEN[1]
    status = re.search(r'id="verdict" data-status="([^"]+)"', r.dom).group(1)
    img = mpimg.imread(r.shot)[..., :3]
    rgb = np.array(BORDER_RGB[status]) / 255
    border = (np.abs(img - rgb).max(axis=-1) < 0.05).sum()
    assert border > 500, (kind, status, border)
    if kind == "demo":  # one line per arm under the overall verdict
        arms = re.findall(r'<li class="(?:accepted|conditional|rejected)"><b>(R\d)</b>', r.dom)
        assert arms == ["R1", "R2"]


@pytest.mark.parametrize("kind", REPORT_KINDS)
def test_the_printed_first_page_is_the_sign_off_page(kind, rendered):
    """Printed by Chromium (the template's print stylesheet): page 1 holds the verdict, every condition, the next
    step and the signature lines; the method table and the plots start on page 2 or later."""
    r = rendered(kind)
    first, rest = _flat(r.pdf_pages[0]), [_flat(p) for p in r.pdf_pages[1:]]
    status = re.search(r'id="verdict" data-status="([^"]+)"', r.dom).group(1)
    assert _flat(status) in first, (kind, r.pdf_pages[0][:500])
    assert set(r.given) <= set(_conditions(r.html))
    assert all(_flat(c) in first for c in _conditions(r.html)), (kind, r.pdf_pages[0])
    assert _flat("Next step") in first and _flat("verdict signed") in first and _flat("signature") in first, (
        kind, r.pdf_pages[0][-800:])
    method_table = re.search(r'<details class="results">.*?<h3>(.*?)</h3>', r.dom, re.S).group(1)
    assert _flat(method_table) not in first, (kind, method_table)
    assert any(_flat(method_table) in p for p in rest), (kind, method_table)


def test_diagnose_warns_of_unseen_parameter_directions_and_its_report_carries_it(tmp_path, recs, capsys):
    """A training set that leaves directions unseen: fit and compare warn, and so does diagnose now (its report had
    the observability note only under "why", not among the conditions to sign)."""
    capsys.readouterr()
    assert main(["diagnose", "--robot", "R1", "--train", str(recs / "narrow.csv"), "--test", str(recs / "wide.csv"),
                 "--report", str(tmp_path / "rep")]) == 0
    err = " ".join(capsys.readouterr().err.split())
    unseen = [c for c in _conditions(tmp_path / "rep" / "report.html") if "parameter directions" in c]
    assert len(unseen) == 1 and unseen[0] in err, (unseen, err[-1500:])
    why = re.search(r'<div class="why-box".*?</div>', (tmp_path / "rep" / "report.html").read_text(), re.S).group(0)
    assert "parameter directions" not in why  # once, among the conditions (not again with another figure)


@pytest.mark.parametrize("kind", REPORT_KINDS)
def test_the_sign_off_page_says_why_with_the_parameter_count_and_the_test(kind, rendered):
    """Every report's why box names the parameter count of the model it judges (the count in its method table's row)
    and the test that decided: evaluate and recalibrate had no count, evaluate no why at all, diagnose no count."""
    r = rendered(kind)
    boxes = re.findall(r'<div class="why-box"[^>]*>(.*?)</div>', r.dom, re.S)
    assert boxes, kind
    why = " ".join(html_lib.unescape(re.sub(r"<[^>]+>", " ", b)) for b in boxes)
    why = " ".join(why.split())
    page = _Page(r.dom)
    judged = re.search(r'data-status="[^"]+">\s*<h2><span class="status">[^<]+</span>: ([^<]+)</h2>', r.dom)
    names = [judged.group(1)] if judged else re.findall(r"— (\S+): largest errors", page.all_text)
    counts = [row[table[0].index("params")] for table in page.tables.values() if table and "params" in table[0]
              for row in table[1:] if row[0] in names]  # the judged model's row in the method table
    counts = [c for c in counts if c.isdigit()]  # (_Page runs the rows of a page's unclassed tables together)
    assert counts or kind == "diagnose", (kind, names)  # diagnose's tables have no params column
    assert all(f"{c} parameters" in why for c in counts), (kind, counts, why)
    assert re.search(r"\d+ parameters", why), (kind, why)
    test_used = {"evaluate": "tolerance", "compare": "t-test", "diagnose": "held-out", "recalibrate": "validation poses",
                 "demo": "t-test"}[kind]
    assert test_used in why, (kind, why)


@pytest.mark.parametrize("kind", REPORT_KINDS)
def test_every_report_prints_each_title_once_and_no_empty_within_column(kind, rendered):
    """Within each part of the page (the sign-off page, each arm's section) no heading or fold title is repeated and
    none repeats the page's title; the acceptance table shows "within tolerance" only with a figure in every row
    (the diagnose report had "not available" beside PASS); the plots name at most MAX_SERIES rows; the recommended
    model's row is highlighted."""
    r = rendered(kind)
    dom = r.dom.split("<script>")[0]
    title = " ".join(re.search(r"<h1>(.*?)</h1>", dom, re.S).group(1).split())
    parts = dom.split('<section class="report-section">')
    for part in parts:
        heads = [" ".join(html_lib.unescape(re.sub(r"<[^>]+>", "", h)).split())
                 for h in re.findall(r"<(?:h[1-6]|summary)[^>]*>(.*?)</(?:h[1-6]|summary)>", part, re.S)]
        assert len(heads) == len(set(heads)), (kind, heads)
        assert part is parts[0] or title not in heads, (kind, title)
    page = _Page(r.dom)
    acc = page.tables.get("acceptance", [])
    assert acc, kind
    header = [h for h in acc if h and h[0] == "model"][0]
    if "within tolerance" in header:
        col = header.index("within tolerance")
        assert all(re.fullmatch(r"\d+\.\d %", row[col]) for row in acc if row[0] != "model"), (kind, acc)
    assert not re.search(r"not available[^<]{0,80}</td>\s*<td class=\"(?:pass|fail)\"", r.dom), kind
    for caption in re.findall(r"<figcaption>(.*?)</figcaption>", r.dom):
        if "; " in caption:  # the error plots name their rows after the last "; "
            rows = caption.rsplit("; ", 1)[1].split(" (")[0].split(", ")
            assert len(rows) <= MAX_SERIES, (kind, caption)
    recommended = re.findall(r'<tr class="recommended-row"><td>([^<]+)</td>', r.dom)
    assert recommended, kind


def test_recalibrate_warns_as_fit_does_and_its_report_carries_it(rendered):
    """recalibrate fitted without a word about the parameter directions its (grid) training poses leave unseen, which
    fit warns of on the same data; the warning is now given and among the report's conditions."""
    r = rendered("recalibrate")
    unseen = [w for w in r.given if "parameter directions" in w]
    assert len(unseen) == 1 and unseen[0] in _conditions(r.html), r.given
    assert 'data-status="accepted with conditions"' in r.dom or 'data-status="not accepted"' in r.dom


#: One warning of each kind a command gives (the texts of the messages that give them), and what its step names.
CONDITION_KINDS = {
    "extrapolation": ("1500 of 1500 poses lie outside the joint range of the pi model's training data (by up to 92.0 "
                      "deg)", "cellcal select"),
    "unseen directions": ("The data cannot see 16 of 27 parameter directions (condition number 2.96e+03); they mostly "
                          "involve joints 1, 4, 5, 6.", "--design optimal"),
    "instability": ("fbf13 may be unstable: at 2% of 625 probe configurations within 10 deg of the anchors' (q2, q3) "
                    "box its raw parameters leave the local fits' range", "--method pi"),
    "frames": ("The R1 recording is off by a frame, not by kinematics: the base is off (2.1 mm)", "cellcal register"),
    "outliers": ("3 of 200 training rows of train.csv rejected as gross measurement errors (beyond 5 mm / 1 deg)",
                 "remeasure"),
    "measurement shift": ("the training recording has 12 of 300 poses whose measured position jumps by 0.40 mm along "
                          "one direction (+0.1, +0.9, +0.0, base frame)", "mocap calibration"),
    "other": ("R2's mocap lost 3 % of its frames", "state on this page why"),
}
SIGN = ["models_r1/current.yaml now holds the nls1 candidate; sign below to accept it."]  # recalibrate's own step


@pytest.mark.parametrize("kind", list(CONDITION_KINDS))
def test_a_conditional_verdicts_next_step_says_what_to_do_about_each_kind_of_condition(kind):
    """recalibrate's next step was only "sign below" under conditions; every kind of condition now gets its remedy,
    before the command's own step, whatever that step is."""
    text, named = CONDITION_KINDS[kind]
    v = Verdict("Recalibration of R1", "candidate nls1", CONDITIONAL, "within the tolerance", (text,))
    for given in (SIGN, []):
        steps = next_steps(v, given)
        assert any(named in s for s in steps[:-1]), (kind, steps)  # before the last (the sign-off) step
        assert steps[-len(given):] == given if given else steps[-1].startswith("With the conditions resolved")
    assert next_steps(replace(v, status=ACCEPTED, conditions=()), SIGN) == SIGN  # no conditions: nothing to resolve


def test_a_remedy_the_command_gave_already_is_not_repeated_and_each_kind_comes_once():
    texts = [CONDITION_KINDS["extrapolation"][0], CONDITION_KINDS["extrapolation"][0].replace("1500", "12"),
             CONDITION_KINDS["unseen directions"][0]]
    v = Verdict("R1", "pi", CONDITIONAL, "within the tolerance", tuple(texts))
    evaluate_step = ["... Collect poses that cover the task and refit: cellcal select --robot R1 --data C.csv ..."]
    steps = next_steps(v, evaluate_step)
    assert sum("cellcal select" in s for s in steps) == 1 and sum("--design optimal" in s for s in steps) == 1, steps


@pytest.mark.parametrize("kind", REPORT_KINDS)
def test_every_reports_next_step_answers_its_conditions(kind, written):
    """On the page: a report accepted with conditions names, among its next steps, what to do about each kind of
    condition it lists (recalibrate on a grid plan: unseen directions -> cellcal plan --design optimal)."""
    html, _ = written(kind)
    text = html.read_text()
    if 'data-status="accepted with conditions"' not in text:
        assert kind != "recalibrate", "the grid plan's unseen directions no longer make it conditional: check nothing"
        return
    steps = " ".join(html_lib.unescape(re.search(r'<ul class="next-step">(.*?)</ul>', text, re.S).group(1)).split())
    conditions = _conditions(html)
    assert conditions, kind
    answered = [r for r in REMEDIES if any(re.search(r.pattern, c) for c in conditions)]
    for r in answered:
        assert CONDITION_KINDS[r.kind][1] in steps, (kind, r.kind, steps)
    assert answered or CONDITION_KINDS["other"][1] in steps, (kind, steps)
    if kind == "recalibrate":
        assert "--design optimal" in steps, steps
