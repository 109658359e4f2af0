"""The acceptance report: report.html for compare/evaluate/diagnose/recalibrate/demo, pass/fail, ISO 9283,
provenance hashes, plot styles, and a real render in headless Chromium."""

from __future__ import annotations

import hashlib
import json
import re
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

from app.cli.commands import main
from app.reports.acceptance import Tolerance, acceptance
from app.reports.plots import METHOD_STYLES, styles_for
from calibration.data.recording import write_recording
from calibration.errors import CellCalError
from calibration.evaluation.metrics import Errors
from calibration.method_names import METHODS
from tests.app.browser import screenshot_and_dom
from tests.conftest import (
    R1_TEST,
    R1_TRAIN,
    SIM_FAST,
    assert_bad_input,
    cluster_design,
    measure,
    needs_shared_data,
    write_backlash_case,
)


@pytest.fixture(scope="module")
def data(tmp_path_factory, synthetic_arm):
    """train.csv; test.csv whose rows 0..9 are visited again at rows 100..109 and 110..119; random.csv (no repeat)."""
    _, _, truth = synthetic_arm
    root = tmp_path_factory.mktemp("report")
    q, cluster = cluster_design(step_deg=20.0)
    write_recording(measure(truth.fk, q, 0.02, 0.01, 1, cluster), root / "train.csv")
    q_test = np.random.default_rng(3).uniform(-0.8, 0.8, (150, 6))
    q_test[100:110] = q_test[:10]
    q_test[110:120] = q_test[:10]
    write_recording(measure(truth.fk, q_test, 0.02, 0.01, 2), root / "test.csv")
    write_recording(measure(truth.fk, np.random.default_rng(5).uniform(-0.8, 0.8, (40, 6)), 0.02, 0.01, 6),
                    root / "random.csv")
    return root


class _Page(HTMLParser):
    """The parts of report.html the tests read: table rows by table class, images, text."""

    def __init__(self, text: str) -> None:
        super().__init__()
        self.tables: dict[str, list[list[str]]] = {}
        self.images: list[str] = []
        self.body_attrs: dict[str, str] = {}
        self._table: str | None = None
        self._row: list[str] | None = None
        self._cell: list[str] | None = None
        self.text: list[str] = []
        self.feed(text)

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "table":
            self._table = a.get("class", "")
            self.tables.setdefault(self._table, [])
        elif tag == "tr":
            self._row = []
        elif tag in ("td", "th"):
            self._cell = []
        elif tag == "img":
            self.images.append(a.get("src", ""))
        elif tag == "body":
            self.body_attrs = {k: v or "" for k, v in attrs}

    def handle_endtag(self, tag):
        if tag in ("td", "th") and self._cell is not None and self._row is not None:
            self._row.append("".join(self._cell).strip())
            self._cell = None
        elif tag == "tr" and self._row is not None and self._table is not None:
            self.tables[self._table].append(self._row)
            self._row = None
        elif tag == "table":
            self._table = None

    def handle_data(self, d):
        if self._cell is not None:
            self._cell.append(d)
        self.text.append(d)

    def rows(self, cls: str) -> dict[str, list[str]]:
        """Rows of the first-found table of that class, by first cell (header row left out)."""
        return {r[0]: r[1:] for r in self.tables[cls][1:]}

    @property
    def all_text(self) -> str:
        return " ".join(" ".join(self.text).split())


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _check_common(html_path: Path, inputs: list[Path]) -> _Page:
    """A self-contained page: embedded PNGs that decode, provenance hashes of ``inputs``, version and date."""
    import base64
    import io

    import matplotlib.image as mpimg

    text = html_path.read_text()
    assert not re.search(r"<script[^>]+src=|<link[^>]+href=|<img[^>]+src=\"(?!data:)", text)  # nothing fetched
    page = _Page(text)
    assert page.images and all(src.startswith("data:image/png;base64,") for src in page.images)
    for src in page.images:
        img = mpimg.imread(io.BytesIO(base64.b64decode(src.split(",", 1)[1])), format="png")
        assert img.shape[0] > 100 and img.shape[1] > 100
    prov = page.tables["provenance"][1:]
    assert {(Path(r[1]), r[2]) for r in prov} == {(p, _sha(p)) for p in inputs}
    from app.reports.provenance import version

    assert f"cellcal {version()}" in page.all_text
    assert re.search(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ", page.all_text)
    return page


@pytest.fixture(scope="module")
def compare_report(tmp_path_factory, data):
    """``compare --report`` of three methods on the module's recordings: (the report folder, the --json file);
    read, never written, by the tests that check its content and its rendering."""
    work = tmp_path_factory.mktemp("compare_report")
    assert main(["compare", "--robot", "R1", "--train", str(data / "train.csv"), "--test", str(data / "test.csv"),
                 "--methods", "nominal,nls1,fbf13", "--json", str(work / "c.json"), "--report", str(work / "rep")]) == 0
    return work / "rep", work / "c.json"


def test_compare_report_pass_fail_iso_and_provenance(compare_report, data):
    report, cmp_json = compare_report
    page = _check_common(report / "report.html", [data / "train.csv", data / "test.csv"])
    cmp = json.loads(cmp_json.read_text())
    acc = page.rows("acceptance")
    assert set(acc) == {"nominal", "nls1", "fbf13"}
    for m, row in acc.items():
        test = cmp["methods"][m]["test"]
        expected = test["position_mm"]["max"] <= 1.0 and test["orientation_deg"]["max"] <= 1.0
        assert row[-1] == ("PASS" if expected else "FAIL")
        assert float(row[1]) == pytest.approx(test["position_mm"]["max"], abs=5e-4)
    assert acc["nominal"][-1] == "FAIL" and acc["nls1"][-1] == "PASS"  # planted errors of ~3 mm, recovered by nls1
    iso = page.tables["iso"][1:]
    assert [r[1] for r in iso] == ["3"] * 10  # the 10 configurations visited three times
    assert set(page.rows("iso-ap")) == {"nominal", "nls1", "fbf13"}
    # compare now recommends a model (chosen on held-out training clusters): the report names it and its verdict
    assert cmp["recommended"] in acc
    verdict = "passes" if acc[cmp["recommended"]][-1] == "PASS" else "does not pass"
    assert f"Recommended: {cmp['recommended']} — {verdict} the tolerance." in page.all_text
    assert "No recommendation made." not in page.all_text
    for name in ("report.md", "error_workspace.png", "error_cdf.png"):
        assert (report / name).stat().st_size > 0
    # the Fourier model's own plots only when it is the model put into service (issue 34)
    fourier = cmp["recommended"] == "fbf13"
    assert all((report / n).exists() == fourier for n in ("fourier_singular_values.png", "fourier_correction_map.png"))
    assert "error_along_path" not in (report / "report.md").read_text()


def test_a_tight_tolerance_fails_every_model_and_a_recommendation_is_shown(tmp_path, data, synthetic_arm):
    from app.reports.sections import write_report
    from app.workflows.compare import run_comparison
    from calibration.data.recording import read_recording
    from calibration.methods.fitter import Fitter
    from cell_config import load_cell

    robot = load_cell().robot("R1")
    test = read_recording(data / "random.csv")
    cmp = run_comparison(Fitter.for_arm(robot.arm(), read_recording(data / "train.csv")), test, ["nominal", "nls1"])
    cmp.recommended = "nls1"
    files = write_report(cmp, test, tmp_path, tolerance=Tolerance(0.001, 0.001), inputs=[("test", data / "random.csv")])
    page = _Page(files[-1].read_text())
    assert [r[-1] for r in page.rows("acceptance").values()] == ["FAIL", "FAIL"]
    assert "Recommended: nls1 — does not pass the tolerance." in page.all_text
    assert "Not available: no repeated poses" in page.all_text


def test_acceptance_counts_poses_within_both_tolerances():
    tol = Tolerance(1.0, 1.0)
    ok = acceptance("a", Errors(np.array([0.2, 1.0, 0.5]), np.array([0.1, 0.2, 1.0])), tol)
    assert ok.passed and ok.within == 1.0
    bad = acceptance("b", Errors(np.array([0.2, 1.01, 0.5, 0.1]), np.array([0.1, 0.2, 0.3, 1.5])), tol)
    assert not bad.passed and bad.within == 0.5 and bad.max_position_mm == 1.01
    with pytest.raises(CellCalError, match="--tolerance-mm"):
        Tolerance(0.0, 1.0)


def test_evaluate_report(tmp_path, data):
    model, report = tmp_path / "m.yaml", tmp_path / "rep"
    assert main(["fit", "--robot", "R1", "--train", str(data / "train.csv"), "--method", "nls1", "--out", str(model)]) == 0
    assert main(["evaluate", "--model", str(model), "--test", str(data / "test.csv"), "--report", str(report),
                 "--tolerance-mm", "0.05"]) == 0
    page = _check_common(report / "report.html", [model, data / "test.csv"])
    row = page.rows("acceptance")["nls1"]
    assert row[-1] == "FAIL" and float(row[1]) > 0.05  # the noise alone exceeds 50 um somewhere
    assert float(row[3].rstrip(" %")) > 50  # ... but most poses lie within it
    assert len(page.tables["iso"]) == 11


def test_bad_report_options_exit_2_and_write_nothing(tmp_path, data, capsys):
    model = tmp_path / "m.yaml"
    assert main(["fit", "--robot", "R1", "--train", str(data / "train.csv"), "--method", "base", "--out", str(model)]) == 0
    report = tmp_path / "rep"
    assert_bad_input(capsys, ["evaluate", "--model", str(model), "--test", str(data / "test.csv"), "--report", str(report),
                              "--tolerance-deg", "-1"], "--tolerance-deg", "positive finite")
    assert_bad_input(capsys, ["compare", "--robot", "R1", "--train", str(data / "train.csv"), "--test",
                              str(data / "test.csv"), "--report", str(report), "--tolerance-mm", "nan"], "--tolerance-mm")
    assert not report.exists()
    assert_bad_input(capsys, ["evaluate", "--model", str(model), "--test", str(data / "test.csv"), "--report", str(model)],
                     "--report must be a folder")
    demo = tmp_path / "demo"
    assert_bad_input(capsys, ["demo", "--out", str(demo), "--report", str(model)], "--report must be a folder")
    assert_bad_input(capsys, ["demo", "--out", str(demo), "--tolerance-mm", "0"], "--tolerance-mm")
    assert not demo.exists()


def test_diagnose_report(tmp_path):
    from app.workflows.diagnose import run_diagnose

    write_backlash_case(tmp_path)
    res = run_diagnose("R1", tmp_path / "fit.csv", tmp_path / "ho.csv", report_dir=tmp_path / "rep")
    page = _check_common(tmp_path / "rep" / "report.html", [tmp_path / "fit.csv", tmp_path / "ho.csv"])
    acc = page.rows("acceptance")
    assert list(acc) == [f"{res.baseline.model} (before)", f"{res.final.model} (after)"]
    # diagnose keeps no per-pose orientation errors: no "within tolerance: not available" beside PASS (issue 34)
    assert page.tables["acceptance"][0] == ["model", "poses", "max position error mm", "max orientation error deg",
                                            "result"]
    assert "not available" not in " ".join(sum(page.tables["acceptance"], []))
    assert float(acc[f"{res.final.model} (after)"][1]) == pytest.approx(res.final.max_mm, abs=5e-4)
    assert "Not available: no repeated poses" in page.all_text
    assert res.verdict.split(".")[0] in page.all_text


def test_recalibrate_report(tmp_path):
    plan, models, report = tmp_path / "plan.json", tmp_path / "models", tmp_path / "rep"
    assert main(["plan", "--robot", "R1", "--out", str(plan), "--design", "grid", "--q2-step", "35", "--q3-step", "30"]) == 0
    assert main(["recalibrate", "--robot", "R1", "--plan", str(plan), "--model-dir", str(models), "--method", "nls1",
                 "--validation", "6", "--validation-seed", "2", "--sim", *SIM_FAST, "--no-progress",
                 "--report", str(report)]) == 0
    work = next((models / "sessions").iterdir())
    page = _check_common(report / "report.html", [work / "train.csv", work / "validation.csv"])
    assert list(page.rows("acceptance")) == ["candidate nls1"]
    assert "installed candidate nls1" in page.all_text
    in_service = (models / "current.yaml").read_bytes()
    assert main(["recalibrate", "--robot", "R1", "--session", str(work / "train"), "--model-dir", str(models),
                 "--method", "base", "--validation", "6", "--validation-seed", "3", "--sim", *SIM_FAST, "--no-progress",
                 "--report", str(report)]) == 0
    page = _Page((report / "report.html").read_text())
    assert list(page.rows("acceptance")) == ["candidate base", "in service nls1"]
    # the verdict is on the model in service after the decision, not on a candidate that was turned down
    verdict_model = re.search(r'<div class="verdict [a-z]+" id="verdict" data-status="[^"]+">\s*<h2>.*?</span>: ([^<]+)</h2>',
                              (report / "report.html").read_text(), re.S).group(1)
    replaced = "R1: replaced" in page.all_text
    assert verdict_model == ("candidate base" if replaced else "in service nls1"), (verdict_model, replaced)
    served = [r for r in page.tables["provenance"][1:] if r[0] == "model in service"]
    assert [r[2] for r in served] == [hashlib.sha256(in_service).hexdigest()]  # hashed before it was archived


def test_demo_report_has_one_section_per_arm(tmp_path, data):
    from app.reports.sections import write_demo_report
    from app.workflows.compare import run_comparison
    from calibration.data.recording import read_recording
    from calibration.methods.fitter import Fitter
    from cell_config import load_cell

    robot = load_cell().robot("R1")
    test = read_recording(data / "test.csv")
    cmp = run_comparison(Fitter.for_arm(robot.arm(), read_recording(data / "train.csv")), test, ["nominal", "nls1"])
    arm = {"samples": 10, "targets": 10, "skipped_targets": 0, "train_samples": 5, "cpa_samples": 0,
           "test_samples": 5, "collect_seconds": 1.0}
    summary = {"robots": {"R1": arm}, "mocap_frames_received": 100,
               "config": {"full": False, "seed": 0, "time_scale": 5.0, "mocap_rate_hz": 120.0, "anchor_step_deg": 10.0,
                          "validation_poses": 5},
               "planted": {"origin_std_mm": 0.5, "tilt_std_deg": 0.05, "compliance_rms_mm": 1.0, "mocap_noise_mm": 0.02}}
    path = write_demo_report(tmp_path, {"R1": cmp}, {"R1": test}, summary, inputs=[("R1 test", data / "test.csv")])
    assert path == tmp_path / "report.html"
    page = _check_common(path, [data / "test.csv"])
    assert "cellcal demo --seed 0" in page.all_text and set(page.rows("acceptance")) == {"nominal", "nls1"}
    assert (tmp_path / "R1" / "report.md").exists() and (tmp_path / "R1" / "error_cdf.png").exists()


def test_every_method_has_its_own_style():
    assert set(METHOD_STYLES) == set(METHODS)
    assert len({s.color for s in METHOD_STYLES.values()}) == len(METHODS)
    assert len({(s.linestyle, s.marker) for s in METHOD_STYLES.values()}) == len(METHODS)
    assert METHOD_STYLES["nominal"].color != METHOD_STYLES["fbf7"].color
    extra = styles_for(["nls1", "m (file)", "candidate"])
    assert len({s.color for s in extra.values()}) == 3


def test_every_axis_of_the_plots_is_labelled_with_a_unit(data, synthetic_arm):
    from app.reports import plots
    from calibration.data.recording import read_recording
    from calibration.models import ConstantModel

    _, _, truth = synthetic_arm
    rec = read_recording(data / "test.csv")
    errs = {"nominal": Errors(np.linspace(1, 3, len(rec)), np.linspace(0.1, 0.3, len(rec))),
            "fbf7": Errors(np.linspace(0.01, 0.2, len(rec)), np.linspace(0.01, 0.03, len(rec)))}
    model = ConstantModel("R1", "nls1", truth, 27, {})
    figs = [plots.workspace_figure(errs, rec.p, 1.0), plots.cdf_figure(errs, 1.0, 1.0),
            plots.singular_values_figure(np.array([3.0, 2.0, 1.0])),
            plots.correction_map_figure(model, model, rec.q, "a - b")]
    import matplotlib.pyplot as plt

    for fig in figs:
        for ax in fig.axes:
            if ax.get_label() == "<colorbar>":
                assert re.search(r"\[[^\]]+\]", ax.get_ylabel() or ax.get_xlabel()), "colour bar without a unit"
        # panels sharing axes label only the outer ones: every label there is, carries a unit
        labelled_x = [ax.get_xlabel() for ax in fig.axes if ax.get_label() != "<colorbar>" and ax.get_xlabel()]
        labelled_y = [ax.get_ylabel() for ax in fig.axes if ax.get_label() != "<colorbar>" and ax.get_ylabel()]
        assert labelled_x and labelled_y
        assert all(re.search(r"\[[^\]]+\]", s) for s in labelled_x + labelled_y), labelled_x + labelled_y
        plt.close(fig)
    heat = figs[3]
    assert heat.axes[0].get_xlabel() == "q2 [deg]" and heat.axes[0].get_ylabel() == "q3 [deg]"


def test_report_renders_in_headless_chromium(tmp_path, data, compare_report, chromium):
    """A real render: the page is drawn (many colours), the tables and hashes are in the DOM, every image decoded."""
    import matplotlib.image as mpimg

    html = compare_report[0] / "report.html"
    shot, page = screenshot_and_dom(chromium, tmp_path, html.as_uri(), "report.png", size=(1280, 2400), budget_ms=3000)
    img = mpimg.imread(shot)[..., :3]
    assert img.shape == (2400, 1280, 3)
    rgb = (img * 255).astype(np.uint8).reshape(-1, 3).astype(np.uint32)
    # distinct colours as distinct 24-bit integers: the count np.unique(rows, axis=0) gives, without its 5 s
    # lexicographic sort of 3 million rows
    colours = len(np.unique(rgb[:, 0] << 16 | rgb[:, 1] << 8 | rgb[:, 2]))
    assert colours > 500, f"only {colours} distinct colours: the page was not drawn"
    # the verdict's box drawn (green border of "accepted", amber of "with conditions" or red of "not accepted");
    # the PASS/FAIL cells are folded below the sign-off page since issue 34
    box = ((np.abs(img[..., 0] - 0x2A / 255) < 0.05) & (np.abs(img[..., 1] - 0x8A / 255) < 0.05)
           & (np.abs(img[..., 2] - 0x3A / 255) < 0.05)).sum()
    box += ((np.abs(img[..., 0] - 0xC9 / 255) < 0.05) & (np.abs(img[..., 1] - 0x8A / 255) < 0.05)
            & (img[..., 2] < 0.1)).sum()
    box += ((np.abs(img[..., 0] - 0xBB / 255) < 0.06) & (img[..., 1] < 0.2) & (img[..., 2] < 0.2)).sum()
    assert box > 500, box
    dom = _Page(page)
    n = int(dom.body_attrs["data-images"])
    fourier = json.loads(compare_report[1].read_text())["recommended"] == "fbf13"
    assert n == html.read_text().count("<img ") == (4 if fourier else 2)  # workspace, CDFs (+ Fourier spectrum, map)
    assert dom.body_attrs["data-images-decoded"] == str(n)  # set by the page's script: naturalWidth > 0
    assert dom.rows("acceptance")["nominal"][-1] == "FAIL" and dom.rows("acceptance")["nls1"][-1] == "PASS"
    hashes = {r[2] for r in dom.tables["provenance"][1:]}
    assert hashes == {_sha(data / "train.csv"), _sha(data / "test.csv")}


@needs_shared_data()
def test_real_data_report_says_no_repeated_poses(tmp_path):
    report = tmp_path / "rep"
    assert main(["compare", "--robot", "R1", "--train", str(R1_TRAIN), "--test", str(R1_TEST), "--methods", "nominal,nls1",
                 "--report", str(report)]) == 0
    page = _Page((report / "report.html").read_text())
    assert "Not available: no repeated poses" in page.all_text
    assert {Path(r[1]).parent for r in page.tables["provenance"][1:]} == {R1_TRAIN, R1_TEST}
