"""The sign-off page of every report (issue 34): one verdict for the model put into service, every warning the
command gave among its conditions, why the model was chosen, the next step, all in the first screen; plots of at
most six series with the recommended one highlighted; titles once; the warnings collected structurally."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np
import pytest

from app.cli.commands import main
from app.reports.acceptance import Acceptance, Tolerance, iso_unavailable
from app.reports.command_warnings import collecting, warnings_so_far
from app.reports.page import MAX_SERIES, Page, Section, shown_series, write_html
from app.reports.verdict import ACCEPTED, CONDITIONAL, NOT_ACCEPTED, verdict
from calibration.data.recording import write_recording
from tests.app.browser import browser_or_skip, screenshot_and_dom
from tests.app.reports.test_report import _Page
from tests.conftest import cluster_design, measure, write_backlash_case


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


def _run(capsys, argv: list[str]) -> list[str]:
    capsys.readouterr()
    assert main(argv) == 0
    return _warnings(capsys.readouterr().err)


def test_evaluate_report_carries_the_extrapolation_warning(tmp_path, recs, capsys):
    model = tmp_path / "m.yaml"
    assert main(["fit", "--robot", "R1", "--train", str(recs / "train.csv"), "--method", "nls1", "--out", str(model)]) == 0
    given = _run(capsys, ["evaluate", "--model", str(model), "--test", str(recs / "wide.csv"), "--report",
                          str(tmp_path / "rep")])
    assert any("outside the joint range" in w for w in given), given
    html = tmp_path / "rep" / "report.html"
    assert _conditions(html) == given  # each warning, once, in the order given
    page = _Page(html.read_text())
    assert "accepted with conditions" in page.all_text.lower() or "not accepted" in page.all_text.lower()
    steps = re.search(r'<ul class="next-step">(.*?)</ul>', html.read_text(), re.S).group(1)
    assert "cellcal select" in steps and str(recs / "wide.csv") in steps and str(recs / "train.csv") in steps


def test_compare_report_carries_the_comparison_warnings(tmp_path, recs, capsys):
    given = _run(capsys, ["compare", "--robot", "R1", "--train", str(recs / "narrow.csv"), "--test",
                          str(recs / "wide.csv"), "--methods", "nominal,nls1,pi", "--report",
                          str(tmp_path / "rep")])
    assert given, "the narrow training set gave no warning: this test checks nothing"
    conditions = _conditions(tmp_path / "rep" / "report.html")
    assert set(given) <= set(conditions) and len(conditions) == len(set(conditions))


def test_diagnose_report_carries_its_warnings(tmp_path, capsys):
    write_backlash_case(tmp_path)
    given = _run(capsys, ["diagnose", "--robot", "R1", "--train", str(tmp_path / "fit.csv"), "--test",
                          str(tmp_path / "ho.csv"), "--report", str(tmp_path / "rep")])
    html = tmp_path / "rep" / "report.html"
    assert set(given) <= set(_conditions(html))
    assert f"--train {tmp_path / 'fit.csv'}" in html.read_text()  # the command line, not just "cellcal diagnose"
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


def test_the_first_screen_holds_the_verdict_and_the_warnings_in_chromium(tmp_path, recs, capsys):
    """A real render of an evaluate report whose run warned: the verdict and the conditions end within the first
    1280 x 900 screen (their DOM positions in the headless run), and the screenshot shows the verdict's box."""
    import matplotlib.image as mpimg

    browser_or_skip()
    model = tmp_path / "m.yaml"
    assert main(["fit", "--robot", "R1", "--train", str(recs / "train.csv"), "--method", "nls1", "--out", str(model)]) == 0
    given = _run(capsys, ["evaluate", "--model", str(model), "--test", str(recs / "wide.csv"), "--report",
                          str(tmp_path / "rep")])
    html = tmp_path / "rep" / "report.html"
    shot, dom = screenshot_and_dom(tmp_path, html.as_uri(), "report_first_screen.png", size=(1280, 900),
                                   budget_ms=3000)
    page = _Page(dom)
    assert given and all(w in " ".join(page.all_text.split()) for w in given)
    assert 0 < int(page.body_attrs["data-verdict-bottom"]) <= 900
    assert 0 < int(page.body_attrs["data-conditions-bottom"]) <= 900
    img = mpimg.imread(shot)[..., :3]
    amber = ((np.abs(img[..., 0] - 0xC9 / 255) < 0.05) & (np.abs(img[..., 1] - 0x8A / 255) < 0.05)
             & (img[..., 2] < 0.1)).sum()  # the "with conditions" border (or the red of "not accepted")
    red = ((np.abs(img[..., 0] - 0xBB / 255) < 0.06) & (img[..., 1] < 0.2) & (img[..., 2] < 0.2)).sum()
    assert amber + red > 500, (amber, red)


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


def test_a_two_arm_demo_page_holds_both_verdicts_and_the_warnings_in_the_first_screen(tmp_path, recs):
    """The demo's page (one section per arm): the overall verdict, each arm's line and every warning given end within
    the first 1280 x 900 screen, though each arm also explains its choice below them."""
    from app.reports.sections import write_demo_report
    from app.workflows.compare import run_comparison
    from app.workflows.fit import fitter_for
    from calibration.data.recording import read_recording
    from cell_config import load_cell

    browser_or_skip()
    test = read_recording(recs / "wide.csv")
    cmps = {r: run_comparison(fitter_for(load_cell().robot("R1"), read_recording(recs / "train.csv")), test,
                              ["nominal", "nls1", "pi"]) for r in ("R1", "R2")}
    arm = {"samples": 10, "targets": 10, "skipped_targets": 0, "train_samples": 5, "cpa_samples": 0,
           "test_samples": 5, "collect_seconds": 1.0}
    summary = {"robots": {"R1": arm, "R2": arm}, "mocap_frames_received": 100,
               "config": {"full": False, "seed": 0, "time_scale": 5.0, "mocap_rate_hz": 120.0, "anchor_step_deg": 10.0,
                          "validation_poses": 5},
               "planted": {"origin_std_mm": 0.5, "tilt_std_deg": 0.05, "compliance_rms_mm": 1.0, "mocap_noise_mm": 0.02}}
    with collecting():
        print("warning: R2's mocap lost 3 % of its frames", file=sys.stderr)
        path = write_demo_report(tmp_path, cmps, {"R1": test, "R2": test}, summary)
    _, dom = screenshot_and_dom(tmp_path, path.as_uri(), "demo_first_screen.png", size=(1280, 900), budget_ms=3000)
    page = _Page(dom)
    text = " ".join(page.all_text.split())
    assert "R2's mocap lost 3 % of its frames" in text
    arms = re.findall(r'<li class="(accepted|conditional|rejected)"><b>(R\d)</b>', dom)
    assert [a for _, a in arms] == ["R1", "R2"] and all(c == "conditional" or c == "rejected" for c, _ in arms)
    assert 0 < int(page.body_attrs["data-conditions-bottom"]) <= 900


def test_a_warning_over_several_lines_is_kept_whole():
    with collecting():
        print("warning: first line\nsecond line", file=sys.stderr)
        print("not a warning", file=sys.stderr)
        sys.stderr.write("progress 10%\rwarning: after a bar\n")
        assert warnings_so_far() == ["first line second line", "after a bar"]
