"""The file-format pages (docs/formats/) against the code, where the comparison is mechanical.

Each field table a page marks with ``<!-- fields: NAME -->`` lists, in its first column, names in backticks
(```q1` … `q6``` stands for q1 to q6). The set of names must be exactly the set the code knows: a column, model kind,
key or position type added to the code without a row (or a row left for one removed) fails here, naming the page.
Also: no product message or docstring points to the old specs outside the repository, and every ``docs/...`` page
the product names exists.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
FORMATS = REPO / "docs" / "formats"
PRODUCT = ("app", "calibration", "drivers", "cell_config")

_MARK = re.compile(r"<!--\s*fields:\s*([\w-]+)\s*-->")
_RANGE = re.compile(r"`([A-Za-z_]*?)(\d+)([A-Za-z_]*)`\s*(?:…|\.\.\.?)\s*`([A-Za-z_]*?)(\d+)([A-Za-z_]*)`")


def _names(cell: str) -> list[str]:
    """The backticked names of a table's first cell, ranges (```q1` … `q6```) expanded."""
    out: list[str] = []
    for m in _RANGE.finditer(cell):
        pre, lo, post, pre2, hi, post2 = m.groups()
        if (pre, post) != (pre2, post2):
            raise ValueError(f"range {m.group(0)!r} mixes two names")
        out += [f"{pre}{i}{post}" for i in range(int(lo), int(hi) + 1)]
    out += re.findall(r"`([^`]+)`", _RANGE.sub("", cell))
    return out


def field_tables(page: str) -> dict[str, list[str]]:
    """Every marked table of ``docs/formats/PAGE``: mark name -> the names its rows list, in order."""
    lines = (FORMATS / page).read_text().splitlines()
    tables: dict[str, list[str]] = {}
    for i, line in enumerate(lines):
        m = _MARK.search(line)
        if not m:
            continue
        rows = []
        j = i + 1
        while j < len(lines) and not lines[j].startswith("|"):
            j += 1
        while j < len(lines) and lines[j].startswith("|"):
            rows.append(lines[j])
            j += 1
        assert len(rows) > 2, f"{page}: the table marked {m.group(1)!r} has no rows"
        names: list[str] = []
        for row in rows[2:]:  # header and separator
            names += _names(row.split("|")[1])
        tables[m.group(1)] = names
    return tables


def table(page: str, mark: str) -> list[str]:
    tables = field_tables(page)
    assert mark in tables, f"docs/formats/{page} has no table marked <!-- fields: {mark} -->"
    return tables[mark]


def assert_documents(page: str, mark: str, known: object) -> None:
    """The table ``mark`` of ``page`` lists each of ``known`` once and nothing else."""
    listed = table(page, mark)
    known = list(known)  # type: ignore[call-overload]
    twice = sorted({n for n in listed if listed.count(n) > 1})
    missing = [n for n in known if n not in listed]
    extra = [n for n in listed if n not in known]
    assert not (twice or missing or extra), (
        f"docs/formats/{page} ({mark}): undocumented {missing}, documented but unknown to the code {extra}, "
        f"listed twice {twice}")


def test_the_parser_reads_ranges_and_lists():
    assert _names("`q1` … `q6`") == ["q1", "q2", "q3", "q4", "q5", "q6"]
    assert _names("`x`, `y`, `z`") == ["x", "y", "z"]
    assert _names("`q1_deg` … `q3_deg`") == ["q1_deg", "q2_deg", "q3_deg"]
    assert _names("`pulse1` … `pulse2`, `x_mm`") == ["pulse1", "pulse2", "x_mm"]


def test_recording_columns_are_the_readers():
    from calibration.data.recording import KNOWN_OPTIONAL_COLUMNS, REQUIRED_COLUMNS

    assert_documents("recording.md", "recording", REQUIRED_COLUMNS + KNOWN_OPTIONAL_COLUMNS)


def test_model_kinds_and_common_keys_are_the_registrys():
    from calibration.models import ConstantModel
    from calibration.models.registry import KIND_MODULES as MODEL_KIND_MODULES
    from cell_config import load_cell

    assert_documents("model.md", "model-kinds", MODEL_KIND_MODULES)
    model = ConstantModel("R1", "nominal", load_cell().robot("R1").model(), 0, {})
    common = [k for k in model.to_dict() if k not in model._body()]
    assert_documents("model.md", "model-common", common)


def test_cell_robot_tool_and_device_keys_are_the_loaders():
    from cell_config.devices import CONTROLLER_KEYS, MOCAP_KEYS, PROBE_KEYS, ZENOH_KEYS
    from cell_config.loader import CAPSULE_SEGMENTS, CELL_KEYS, ROBOT_ENTRY_KEYS, ROBOT_KEYS, TOOL_KEYS

    assert_documents("cell.md", "cell", CELL_KEYS)
    assert_documents("cell.md", "cell-robot", ROBOT_ENTRY_KEYS)
    assert_documents("cell.md", "cell-controller", CONTROLLER_KEYS)
    assert_documents("cell.md", "cell-mocap", MOCAP_KEYS)
    assert_documents("cell.md", "cell-probe", PROBE_KEYS)
    assert_documents("cell.md", "cell-zenoh", ZENOH_KEYS + ("roles",))
    assert_documents("robot-tool.md", "robot", ROBOT_KEYS)
    assert_documents("robot-tool.md", "tool", TOOL_KEYS)
    assert_documents("robot-tool.md", "capsules", CAPSULE_SEGMENTS)


def test_registration_keys_are_the_files():
    from cell_config.registration import _FIELDS

    assert_documents("registration.md", "registration", _FIELDS)


def test_plan_keys_and_target_kinds_are_the_plans():
    from app.collection.plans.collection import KINDS, Target
    from app.collection.plans.dual import PlanResult, WaypointResult

    target = Target("R1", np.zeros(6), 0, "anchor")
    assert_documents("plans.md", "plan-target", target.to_dict())
    assert_documents("plans.md", "plan-target-kinds", KINDS)
    waypoint = WaypointResult(np.zeros(6), np.zeros(6), 0.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1, True)
    plan = PlanResult((waypoint,), np.eye(4), {"R1": "constant", "R2": "constant"}).to_dict()
    assert_documents("plans.md", "plan-dual", plan)
    assert_documents("plans.md", "plan-waypoint", plan["waypoints"][0])


def test_session_tables_are_the_stores(tmp_path):
    from app.collection.plans.collection import Plan, Target
    from app.collection.session_store import _SAMPLE_COLUMNS, SessionStore

    assert_documents("session.md", "session-samples", _SAMPLE_COLUMNS)
    with SessionStore(tmp_path / "s", create=True) as store:
        store.init(Plan((Target("R1", np.zeros(6), 0, "anchor"),)), {"robot": "R1"})
        meta = [k for (k,) in store.conn.execute("SELECT key FROM meta ORDER BY rowid")]
    assert_documents("session.md", "session-meta", meta)


class _Days:
    """Stands for the several-days result, whose own keys are not this page's."""

    def to_json(self) -> dict:
        return {}


def test_diagnose_keys_and_effect_kinds_are_the_reports():
    from calibration.diagnosis.candidates import KINDS
    from calibration.diagnosis.noise import NoiseFloor
    from calibration.diagnosis.report import Accuracy, Diagnosis, EffectEvidence, FoundEffect

    assert_documents("diagnose-json.md", "diagnose-kinds", KINDS)
    acc = Accuracy("geometric", 0.3, 0.9, 0.04, 0.09)
    report = Diagnosis("R1", 10, 5, "split", NoiseFloor(0.08, 0.08, 0.1, 0.03, 0.03, 0.04), acc, acc, (), (), (), (),
                       "", None, days=_Days(), extrapolation={})  # type: ignore[arg-type]
    # every key, optional ones included; gross_rows is added by app.workflows.diagnose beside the report's own
    assert_documents("diagnose-json.md", "diagnose", [*report.to_json(), "gross_rows"])
    evidence = EffectEvidence(-10.0, 0.01, 3.0, acc, acc, 4.0)
    effect = FoundEffect("thermal_drift", (), ("p12",), {"k_per_s": 1.0}, {"k_per_s": 0.1}, evidence, "grows")
    assert_documents("diagnose-json.md", "diagnose-effect", effect.to_json())


def test_command_json_blocks_are_the_writers():
    from calibration.evaluation.comparison import Comparison
    from calibration.evaluation.metrics import stats

    assert_documents("command-json.md", "error-stats", stats(np.array([0.1, 0.2, 0.3])))
    assert_documents("command-json.md", "compare", Comparison("R1").to_json())


def test_fit_and_evaluate_json_keys_are_the_commands(tmp_path):
    """The two command outputs assembled in the CLI, from a run on a small synthetic recording (about 0.5 s)."""
    import json

    from app.cli import main
    from calibration.data.recording import write_recording
    from cell_config import load_cell
    from tests.conftest import cluster_design, measure

    q, cluster = cluster_design(30.0)
    write_recording(measure(load_cell().robot("R1").model().fk, q, 0.05, 0.01, 0, cluster), tmp_path / "r.csv")
    fit = ["fit", "--robot", "R1", "--train", str(tmp_path / "r.csv"), "--method", "nls1"]
    assert main(fit + ["--out", str(tmp_path / "m.yaml"), "--json", str(tmp_path / "fit.json")]) == 0
    assert main(["evaluate", "--model", str(tmp_path / "m.yaml"), "--test", str(tmp_path / "r.csv"),
                 "--json", str(tmp_path / "evaluate.json")]) == 0
    assert_documents("command-json.md", "fit", json.loads((tmp_path / "fit.json").read_text()))
    assert_documents("command-json.md", "evaluate", json.loads((tmp_path / "evaluate.json").read_text()))


def test_targets_columns_are_the_writers(tmp_path):
    from app.dual.export_targets import write_targets

    write_targets([], tmp_path / "t.csv")
    header = (tmp_path / "t.csv").read_text().splitlines()[0].split(",")
    assert_documents("targets.md", "targets", header)


def test_jbi_position_types_urdf_names_and_motive_units_are_the_codes():
    from app.collection.motive_import import LENGTH_UNITS_MM, WINDOW_COLUMNS
    from app.jobs.jbi import JOB_POSTYPES
    from calibration.data.recording import JOINT_COLUMNS
    from calibration.models import urdf

    assert_documents("jbi.md", "jbi-postypes", JOB_POSTYPES)
    names = urdf.ROS_JOINTS + urdf.ROS_LINKS + (urdf.BASE_LINK, urdf.ROBOT_FRAME_LINK, urdf.TOOL0_LINK,
                                                urdf.FLANGE_LINK, urdf.TOOL_LINK)
    assert_documents("urdf.md", "urdf", names)
    assert_documents("motive-import.md", "motive-units", LENGTH_UNITS_MM)
    assert_documents("motive-import.md", "motive-joints",
                     JOINT_COLUMNS + tuple(f"{c}_deg" for c in JOINT_COLUMNS) + WINDOW_COLUMNS)


def test_every_format_page_is_listed_and_its_links_resolve():
    index = (FORMATS / "index.md").read_text()
    for page in sorted(FORMATS.glob("*.md")):
        text = page.read_text()
        if page.name != "index.md":
            assert f"]({page.name})" in index, f"docs/formats/index.md does not list {page.name}"
        for target in re.findall(r"\]\(([^)#:\s]+\.md)(?:#[^)]*)?\)", text):
            assert (page.parent / target).resolve().is_file(), f"{page.name} links to {target}, which does not exist"


def _product_files() -> list[Path]:
    return [p for folder in PRODUCT for p in sorted((REPO / folder).rglob("*.py"))]


def test_no_product_text_points_outside_the_repository():
    """Messages and docstrings named ../shared/spec/*.md, which a user of the repository does not have."""
    offenders = [f"{p.relative_to(REPO)}:{n}" for p in _product_files()
                 for n, line in enumerate(p.read_text().splitlines(), 1) if "shared/spec" in line]
    assert not offenders, f"product text points to ../shared/spec (use docs/formats/): {offenders}"


@pytest.mark.parametrize("folder", PRODUCT)
def test_every_docs_page_the_product_names_exists(folder):
    named = {m for p in (REPO / folder).rglob("*.py") for m in re.findall(r"docs/[\w./-]+\.md", p.read_text())}
    missing = sorted(m for m in named if not (REPO / m).is_file())
    assert not missing, f"{folder}/ names docs pages that do not exist: {missing}"


def test_every_repository_path_the_pages_name_exists():
    """The format pages and tutorials name the modules that read and write each file (``calibration/data/recording.py``);
    a module moved or renamed (issue 32's restructure) leaves a page pointing nowhere: this names the page and path."""
    pattern = re.compile(r"`((?:app|calibration|drivers|cell_config|tests|scripts|docs)/[\w/.-]+?)(?:::\w+)?`")
    pages = sorted(FORMATS.glob("*.md")) + sorted((REPO / "docs" / "tutorials").glob("*.md"))
    stale = sorted({f"{page.relative_to(REPO)}: {path}" for page in pages for path in pattern.findall(page.read_text())
                    if not (REPO / path).exists()})
    assert not stale, f"pages name paths that do not exist: {stale}"
