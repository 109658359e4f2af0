"""One definition of a safe plan, checked at every exit (issue 30, safety): every kind of defect a plan file can
carry is refused by every command that hands the plan's motion to a controller or a person.

A plan-dual plan of the rehearsal cell (it has a probe, so validate-dual's real path reaches its plan check) is
edited by hand the ways the reliability pass did; each edit must make export-targets and validate-dual exit 2 with
one line naming the waypoint (nothing written, nothing connected), and preview draw the page with the waypoint
marked in red and the reason said. A collection plan whose target is too near the floor is marked by preview and
refused by collect, as collect --dry-run refuses it.
"""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest

pytest.importorskip("casadi")

from app.cli.commands import main  # noqa: E402
from app.collection.plan_safety import MAX_DRIFT_MM, UnsafePlan, check_plan_safe, plan_defects  # noqa: E402
from app.collection.plans.reader import read_plan  # noqa: E402
from app.collection.rehearsal import write_rehearsal_cell  # noqa: E402
from app.collection.safety import CellSafety, SafetyConfig  # noqa: E402
from calibration.errors import UnsafeTarget  # noqa: E402
from cell_config.capsules import PROCESS_ZONE  # noqa: E402
from cell_config.loader import load_cell  # noqa: E402

N = 8  # waypoints of the plan every defect is made in


@pytest.fixture(scope="module")
def planned(tmp_path_factory):
    root = tmp_path_factory.mktemp("plan_safety")
    cell_path = write_rehearsal_cell(root)
    plan = root / "plan.json"
    assert main(["--cell", str(cell_path), "plan-dual", "--path", f"sweep:{N}", "--no-compile", "--out",
                 str(plan)]) == 0
    return cell_path, json.loads(plan.read_text())


def _floor(d):  # the reliability pass's case: R2's wrist 26 mm below the floor at every waypoint
    for w in d["waypoints"]:
        w["R2"] = [0, 1.2, -0.5, 0, 0, 0]
    return 0


def _jump(d):  # R1 jumps by 1.5 rad between waypoints 3 and 4 (and back)
    d["waypoints"][4]["R1"][0] += 1.5
    return 4


def _claimed_residual(d):  # converged: true with residual_mm: 50
    d["waypoints"][5]["residual_mm"] = 50.0
    return 5


def _moved_off_the_pose(d):  # the joints no longer hold the relative pose, the file still claims they do
    d["waypoints"][2]["R1"][5] += 0.05
    return 2


def _not_a_rotation(d):
    d["T_wp_gun"][0][0] = 2.0
    return "T_wp_gun"


def _reflection(d):
    d["T_wp_gun"] = (np.asarray(d["T_wp_gun"]) @ np.diag([1.0, 1.0, -1.0, 1.0])).tolist()
    return "T_wp_gun"


def _unknown_kind(d):
    d["models"]["R1"] = "banana"
    return "models.R1"


def _unsolved(d):
    d["waypoints"][6]["converged"] = False
    return 6


def _within_the_margin(d):  # a joint 1 deg inside its limit: beyond the planner's 2 deg margin
    d["waypoints"][3]["R2"][3] = float(load_cell().robot("R2").robot.lower_rad[3] + np.radians(1.0))
    return 3


DEFECTS = {f.__name__.strip("_"): f for f in (_floor, _jump, _claimed_residual, _moved_off_the_pose, _not_a_rotation,
                                              _reflection, _unknown_kind, _unsolved, _within_the_margin)}


def _named(where):
    """What the message must name: the waypoint, or the key of a plan-wide defect."""
    return where if isinstance(where, str) else f"waypoint {where}"


def _defective(planned, tmp_path, name):
    cell_path, base = planned
    d = copy.deepcopy(base)
    where = DEFECTS[name](d)
    path = tmp_path / f"{name}.json"
    path.write_text(json.dumps(d))
    return cell_path, path, where


def test_the_unedited_plan_is_safe_and_leaves_by_every_exit(planned, tmp_path, capsys):
    cell_path, base = planned
    path = tmp_path / "plan.json"
    path.write_text(json.dumps(base))
    assert plan_defects(load_cell(cell_path), read_plan(path)) == []
    assert main(["--cell", str(cell_path), "export-targets", "--plan", str(path), "--out", str(tmp_path / "t.csv")]) == 0
    assert main(["--cell", str(cell_path), "preview", "--plan", str(path), "--html", str(tmp_path / "p.html"),
                 "--json", str(tmp_path / "p.json")]) == 0
    summary = json.loads((tmp_path / "p.json").read_text())
    assert summary["safe"] and summary["unsafe"] == [] and "UNSAFE" not in capsys.readouterr().err


@pytest.mark.parametrize("name", sorted(DEFECTS))
def test_export_targets_refuses_every_defect_naming_the_waypoint_and_writes_nothing(planned, tmp_path, capsys, name):
    cell_path, path, where = _defective(planned, tmp_path, name)
    for out in (tmp_path / "t.csv", tmp_path / "t.json"):
        assert main(["--cell", str(cell_path), "export-targets", "--plan", str(path), "--out", str(out)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and _named(where) in err[0] and "nothing written" in err[0], err
        assert not out.exists()


@pytest.mark.parametrize("name", sorted(DEFECTS))
def test_validate_dual_refuses_every_defect_before_connecting(planned, tmp_path, capsys, name):
    cell_path, path, where = _defective(planned, tmp_path, name)
    json_out = tmp_path / "v.json"
    assert main(["--cell", str(cell_path), "validate-dual", "--plan", str(path), "--yes", "--json",
                 str(json_out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and _named(where) in err[0], err
    assert not json_out.exists()


@pytest.mark.parametrize("name", sorted(DEFECTS))
def test_preview_draws_every_defect_marked_in_red_with_its_reason(planned, tmp_path, capsys, name):
    from app.dual.preview.scene import UNSAFE_COLOR

    cell_path, path, where = _defective(planned, tmp_path, name)
    html, summary = tmp_path / "p.html", tmp_path / "p.json"
    assert main(["--cell", str(cell_path), "preview", "--plan", str(path), "--html", str(html), "--json",
                 str(summary)]) == 0
    s = json.loads(summary.read_text())
    at = None if isinstance(where, str) else where
    assert not s["safe"] and any(u["waypoint"] == at for u in s["unsafe"]), s["unsafe"]
    err = capsys.readouterr().err
    assert "UNSAFE" in err and _named(where) in err
    page = html.read_text()
    readout = json.loads(page.split('id="cellcal-readout">', 1)[1].split("</script>", 1)[0])
    frames = range(N) if at is None else [at]
    assert all(readout["converged"][f] is False for f in frames)  # the readout's status in red
    assert all("UNSAFE" in readout["note"][f] or "NOT converged" in readout["note"][f] for f in frames)
    assert f"{UNSAFE_COLOR:06x}" in _scene_colours(page)  # the red markers are in the scene


def _scene_colours(page: str) -> str:
    """Every colour (hex) of the scene's points: meshcat commands are embedded msgpack, base64 encoded."""
    import base64

    import umsgpack

    out = []
    for blob in page.split('fetch("data:application/octet-binary;base64,')[1:]:
        cmd = umsgpack.unpackb(base64.b64decode(blob.split('"', 1)[0]))
        for m in (cmd.get("object") or {}).get("materials", []):
            out.append(f"{m.get('color', 0):06x}")
    return " ".join(out)


def test_the_floor_case_is_what_the_cell_safety_refuses(planned):
    """The reliability pass's plan: CellSafety.check_dual_path refuses it, and so does the one definition, whose
    list names the floor (with no relative pose recorded, the floor is the first defect)."""
    cell_path, base = planned
    cell = load_cell(cell_path)
    d = copy.deepcopy(base)
    _floor(d)
    plan = read_plan(d)
    with pytest.raises(UnsafeTarget, match="floor"):
        CellSafety(cell, SafetyConfig(joint_margin_deg=2.0, process_zone=PROCESS_ZONE)).check_dual_path(plan.q())
    assert any("floor" in x.reason for x in plan_defects(cell, plan))
    d["T_wp_gun"] = None
    with pytest.raises(UnsafePlan, match="waypoint 0: R2: .*too close to the floor"):
        check_plan_safe(cell, read_plan(d))


def test_the_step_bound_separates_planned_sweeps_from_a_jump(planned):
    """sweep:8's moves keep the gun within a few mm of its relative pose; a 1.5 rad jump takes it metres off."""
    cell_path, base = planned
    cell = load_cell(cell_path)
    d = copy.deepcopy(base)
    _jump(d)
    reasons = [x for x in plan_defects(cell, read_plan(d)) if "step too large" in x.reason]
    assert [x.waypoint for x in reasons] == [4, 5] and all(f"at most {MAX_DRIFT_MM:g} mm" in x.reason for x in reasons)


def test_export_skip_failed_checks_the_moves_between_the_waypoints_it_keeps(planned, tmp_path, capsys):
    """Leaving an unsolved waypoint out is allowed; the move that then joins its neighbours is still checked."""
    cell_path, base = planned
    d = copy.deepcopy(base)
    _unsolved(d)
    path = tmp_path / "p.json"
    path.write_text(json.dumps(d))
    out = tmp_path / "t.csv"
    assert main(["--cell", str(cell_path), "export-targets", "--plan", str(path), "--out", str(out),
                 "--skip-failed"]) == 0
    assert len(out.read_text().splitlines()) == 1 + 2 * (N - 1)
    _jump(d)
    path.write_text(json.dumps(d))
    out.unlink()
    assert main(["--cell", str(cell_path), "export-targets", "--plan", str(path), "--out", str(out),
                 "--skip-failed"]) == 2
    assert "waypoint 4" in capsys.readouterr().err and not out.exists()


def _near_floor_collection_plan(cell) -> dict:
    """A collection plan of R1 whose third target brings its wrist 3.6 mm above the floor (the reliability pass's
    preview case): found by bisection on joint 2 from a safe pose."""
    from cell_config.capsules import FLOOR_CHECKED

    safety = CellSafety(cell, SafetyConfig(floor_clearance_mm=0.0))
    lo, hi = 0.0, np.radians(120.0)

    def gap(q2):
        q = np.radians([0.0, 0.0, -30.0, 0.0, 60.0, 0.0])
        q[1] = q2
        return float(safety.capsule_model.floor_gaps("R1", safety.capsules("R1", q), FLOOR_CHECKED).min()), q

    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if gap(mid)[0] > 3.6 else (lo, mid)
    g, q = gap(lo)
    assert 3.0 < g < 4.0
    safe = np.radians([0.0, 10.0, -10.0, 0.0, 30.0, 0.0])
    targets = [{"robot": "R1", "q_rad": list(map(float, t)), "cluster": i, "kind": "anchor"}
               for i, t in enumerate([safe, safe + 0.05, q, safe])]
    return {"schema": "cellcal.plan/1", "kind": "collection", "targets": targets, "params": {}}


def test_a_collection_target_near_the_floor_is_marked_by_preview_and_refused_by_collect(tmp_path, capsys):
    cell = load_cell()
    path = tmp_path / "c.json"
    path.write_text(json.dumps(_near_floor_collection_plan(cell)))
    summary = tmp_path / "s.json"
    assert main(["preview", "--plan", str(path), "--html", str(tmp_path / "p.html"), "--json", str(summary)]) == 0
    s = json.loads(summary.read_text())
    # target 2, and the move away from it (which starts there)
    assert not s["safe"] and [u["waypoint"] for u in s["unsafe"]] == [2, 3] and "floor" in s["unsafe"][0]["reason"]
    assert "target 2" in capsys.readouterr().err
    for dry in (["--dry-run"], []):
        session = tmp_path / f"session{len(dry)}"
        assert main(["collect", "--sim", "--robot", "R1", "--plan", str(path), "--session", str(session)] + dry) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert "target 2" in err[-1] and "floor" in err[-1], err


@pytest.mark.parametrize("edit, words", [
    (lambda d: d.update(models="constant"), "'models': expected the model kind per robot"),
    (lambda d: d.update(models={"R1": 3}), "'models': expected the model kind per robot"),
    (lambda d: d["waypoints"][1].update(residual_mm="small"), "waypoint 1: residual_mm must be a number"),
    (lambda d: d["waypoints"][1].update(clearance_mm=[1]), "waypoint 1: clearance_mm must be a number"),
    (lambda d: d["waypoints"][1].update(solve_ms=10**400), "waypoint 1: solve_ms must be a number"),
], ids=["models-text", "models-number", "residual-text", "clearance-list", "huge-int"])
def test_malformed_plan_claims_are_one_line_errors(planned, tmp_path, capsys, edit, words):
    """A plan file's models and recorded figures of the wrong type were a ValueError/TypeError traceback."""
    from tests.conftest import assert_bad_input

    cell_path, base = planned
    d = copy.deepcopy(base)
    edit(d)
    path, out = tmp_path / "p.json", tmp_path / "t.csv"
    path.write_text(json.dumps(d))
    assert_bad_input(capsys, ["--cell", str(cell_path), "export-targets", "--plan", str(path), "--out", str(out)],
                     words)
    assert not out.exists()


def test_validate_dual_sim_refuses_plan_models_it_would_not_use(tmp_path, capsys):
    from tests.conftest import assert_bad_input

    assert_bad_input(capsys, ["validate-dual", "--sim", "--plan-models", "R1=m.yaml", "--json", str(tmp_path / "v.json")],
                     "--plan-models: not used by validate-dual --sim")
    assert not (tmp_path / "v.json").exists()
