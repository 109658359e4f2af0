"""plan-dual, export-targets, preview and validate-dual end to end, and their bad-input paths."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("casadi")

from app.cli.commands import main  # noqa: E402
from calibration.interpolation.fourier import Fourier13Interpolator  # noqa: E402
from calibration.kinematics.parameterisation import MinimalParameterisation  # noqa: E402
from calibration.methods.cdc import geometric_cdc
from calibration.models import save_model  # noqa: E402
from calibration.models.cdc import CdcModel  # noqa: E402
from cell_config.loader import load_cell  # noqa: E402
from tests.conftest import assert_bad_input  # noqa: E402


@pytest.fixture(scope="module")
def planned(tmp_path_factory):
    root = tmp_path_factory.mktemp("dual")
    assert main(["plan-dual", "--path", "sweep:12", "--out", str(root / "plan.json"),
                 "--json", str(root / "summary.json")]) == 0
    return root


def test_plan_dual_export_and_preview(planned, tmp_path, capsys):
    summary = json.loads((planned / "summary.json").read_text())
    assert summary["converged"] and summary["waypoints"] == 12 and summary["failed"] == []
    assert summary["max_residual_mm"] < 1e-6
    plan = json.loads((planned / "plan.json").read_text())
    assert plan["schema"] == "cellcal.plan/1" and all(w["converged"] for w in plan["waypoints"])
    out = tmp_path / "targets.csv"
    assert main(["export-targets", "--plan", str(planned / "plan.json"), "--out", str(out)]) == 0
    assert len(out.read_text().splitlines()) == 1 + 24
    html = tmp_path / "p.html"
    assert main(["preview", "--cell", str(load_cell().path), "--plan", str(planned / "plan.json"),
                 "--html", str(html)]) == 0
    assert html.stat().st_size > 10_000 and "12 frames" in capsys.readouterr().out


@pytest.mark.parametrize("mode", ["auto", "wait", "off"])
def test_plan_dual_compile_modes_count_their_evaluations_and_leave_the_cache_as_documented(tmp_path, monkeypatch,
                                                                                           mode):
    """auto into an empty cache: a short plan ends before gcc, all interpreted, the build cancelled and nothing
    left behind; wait: all compiled, the library cached; off: all interpreted and no build."""
    cache = tmp_path / "cache"
    monkeypatch.setenv("CELLCAL_CACHE", str(cache))
    args = ["plan-dual", "--path", "sweep:3", "--json", str(tmp_path / "pd.json")]
    assert main(args + (["--no-compile"] if mode == "off" else ["--compile", mode])) == 0
    ev = json.loads((tmp_path / "pd.json").read_text())["evaluations"]
    libs = sorted(p.name for p in cache.glob("*")) if cache.exists() else []
    if mode == "wait":
        assert ev["interpreted"] == 0 and ev["compiled"] > 0 and len(libs) == 2  # the library and its stamp
    else:
        assert ev["compiled"] == 0 and ev["interpreted"] > 0 and libs == []


def test_plan_dual_with_model_files_pose_and_path_files(tmp_path):
    cell = load_cell()
    par = MinimalParameterisation(cell.robot("R2").model())
    rng = np.random.default_rng(2)
    x = rng.uniform(-1.0, 1.0, (30, 2))
    y = np.column_stack([0.2 * np.sin(x[:, 0] + k) for k in range(par.size)]) * np.r_[np.ones(12), np.full(12, 1e-3)]
    save_model(CdcModel("R2", "fbf13", *geometric_cdc(par), Fourier13Interpolator().fit(x, y)), tmp_path / "r2.json")
    ref = tmp_path / "ref.json"
    assert main(["plan-dual", "--path", "sweep:3", "--out", str(ref)]) == 0
    T = np.array(json.loads(ref.read_text())["T_wp_gun"])
    from calibration.kinematics import so3

    pose = list(T[:3, 3]) + list(so3.R_to_quat(T[:3, :3]))
    (tmp_path / "pose.json").write_text(json.dumps({"p_mm": pose[:3], "quat": pose[3:]}))
    from app.dual.paths import sweep_path
    from app.dual.planner import DualPlanner, PlannerOptions

    wp = sweep_path(DualPlanner(cell, options=PlannerOptions(compile="off")), 4)
    rows = ["x,y,z,qw,qx,qy,qz"] + [",".join(f"{v:.17g}" for v in np.r_[t[:3, 3], so3.R_to_quat(t[:3, :3])])
                                    for t in wp]
    (tmp_path / "path.csv").write_text("\n".join(rows) + "\n")
    out = tmp_path / "plan.json"
    assert main(["plan-dual", "--models", f"R2={tmp_path / 'r2.json'}", "--relative-pose", str(tmp_path / "pose.json"),
                 "--path", str(tmp_path / "path.csv"), "--out", str(out), "--json", str(tmp_path / "s.json")]) == 0
    s = json.loads((tmp_path / "s.json").read_text())
    assert s["models"] == {"R1": "constant", "R2": "cdc"} and s["waypoints"] == 4 and s["converged"]


def _diagnosed_r1(cell):
    """A diagnosed model of R1: a pi model plus gravity compliance (masses from the YAML), gear and offsets."""
    from calibration.models.diagnosed import DiagnosedModel
    from calibration.models.pi import PhysicsInformedModel
    from calibration.physics import GearTransmission, GravityModel, JointCompliance, JointOffset
    from calibration.physics.extended import ExtendedKinematics

    spec = cell.robot("R1")
    kin = ExtendedKinematics(MinimalParameterisation(spec.model(), fit_tool=True))
    theta = np.random.default_rng(11).normal(size=kin.size) * kin.scale() * 0.3
    pi = PhysicsInformedModel("R1", "pi", kin, theta, kin.size)
    effects = (JointCompliance(GravityModel.from_spec(spec.robot), (2, 3, 5), np.array([2e-6, 3e-6, 5e-6])),
               GearTransmission(((1, (1, 2)),), np.array([3e-4, -2e-4, 1e-4, 2e-4])),
               JointOffset((4, 6), np.array([1e-3, -1e-3])))
    return DiagnosedModel("R1", "diagnose", pi, effects)


def test_plan_dual_plans_a_diagnosed_model_exactly(tmp_path):
    """Through the model's own casadi expression (deflection a function of q, no frozen fixed point): the
    relative pose holds to 1e-6 mm under the model's own numpy pose."""
    from calibration.kinematics import so3
    from calibration.models import load_model

    cell = load_cell()
    model = _diagnosed_r1(cell)
    save_model(model, tmp_path / "r1.yaml")
    out, js = tmp_path / "plan.json", tmp_path / "s.json"
    assert main(["plan-dual", "--models", f"R1={tmp_path / 'r1.yaml'}", "--path", "sweep:8", "--out", str(out),
                 "--json", str(js)]) == 0
    s = json.loads(js.read_text())
    assert s["models"] == {"R1": "diagnosed", "R2": "constant"} and s["converged"] and s["max_residual_mm"] < 1e-6
    plan = json.loads(out.read_text())
    loaded = load_model(tmp_path / "r1.yaml")
    T_wp_gun = np.array(plan["T_wp_gun"])
    T = {n: cell.robot(n).T_cell_base for n in ("R1", "R2")}
    q1 = np.array([w["R1"] for w in plan["waypoints"]])
    q2 = np.array([w["R2"] for w in plan["waypoints"]])
    R1, p1 = loaded.fk(q1)
    R2, p2 = cell.robot("R2").model().fk(q2)
    R1, p1 = T["R1"][:3, :3] @ R1, p1 @ T["R1"][:3, :3].T + T["R1"][:3, 3]
    R2, p2 = T["R2"][:3, :3] @ R2, p2 @ T["R2"][:3, :3].T + T["R2"][:3, 3]
    res_mm = np.linalg.norm(np.einsum("nji,nj->ni", R2, p1 - p2) - T_wp_gun[:3, 3], axis=1)
    res_rad = np.linalg.norm(so3.log(T_wp_gun[:3, :3].T @ np.swapaxes(R2, 1, 2) @ R1), axis=1)
    assert res_mm.max() < 1e-6 and res_rad.max() < 1e-8
    frozen_mm = np.linalg.norm(model.fk(q1)[1] - model.base.fk(q1)[1], axis=1)
    assert frozen_mm.min() > 0.1  # the effects move the tool: a frozen or dropped deflection would show


def test_plan_dual_bad_inputs_write_nothing(tmp_path, capsys):
    out = tmp_path / "never.json"
    model = tmp_path / "m.json"
    model.write_text(json.dumps({"schema": "cellcal.model/1", "kind": "spline", "robot": "R1", "method": "x"}))
    assert_bad_input(capsys, ["plan-dual", "--models", f"R1={model}", "--out", str(out)], "unknown model kind 'spline'", "valid:")
    assert_bad_input(capsys, ["plan-dual", "--models", "R7=x.yaml", "--out", str(out)], "bad model entry", "R1=FILE,R2=FILE")
    assert_bad_input(capsys, ["plan-dual", "--relative-pose", "1,2,3", "--out", str(out)], "7 numbers")
    assert_bad_input(capsys, ["plan-dual", "--relative-pose", "1,2,3,1,0,0,0.5", "--out", str(out)], "quaternion norm")
    assert_bad_input(capsys, ["plan-dual", "--path", "sweep:x", "--out", str(out)], "sweep:N")
    assert_bad_input(capsys, ["plan-dual", "--path", str(tmp_path / "none.csv"), "--out", str(out)], "path file not found")
    # the gun at the workpiece frame's origin puts the arms into each other: infeasible, reported, not written
    assert_bad_input(capsys, ["plan-dual", "--relative-pose", "0,0,100,1,0,0,0", "--path", "sweep:3", "--no-compile",
                  "--out", str(out)], "3 of 3 waypoints not solved (waypoints 0-2), nothing written to --out",
                     "waypoint 0:", "collision")
    assert not out.exists()


def test_plan_dual_with_some_waypoints_unsolved_names_them_and_writes_nothing(tmp_path, capsys):
    """Waypoints 1 and 2 of 5 out of reach: the plan is refused whole (no --out, no --json, nothing half-written)
    and the message says which waypoints failed, not only the first."""
    from app.dual.paths import sweep_path
    from app.dual.planner import DualPlanner, PlannerOptions
    from calibration.kinematics import so3

    wp = sweep_path(DualPlanner(load_cell(), options=PlannerOptions(compile="off")), 5)
    wp[1:3, :3, 3] += 1000.0  # the workpiece 1.7 m off the sweep: R1 cannot hold the gun to it
    rows = ["x,y,z,qw,qx,qy,qz"] + [",".join(f"{v:.17g}" for v in np.r_[t[:3, 3], so3.R_to_quat(t[:3, :3])])
                                    for t in wp]
    (tmp_path / "path.csv").write_text("\n".join(rows) + "\n")
    out, js = tmp_path / "plan.json", tmp_path / "s.json"
    assert_bad_input(capsys, ["plan-dual", "--path", str(tmp_path / "path.csv"), "--no-compile", "--out", str(out),
                              "--json", str(js)],
                     f"2 of 5 waypoints not solved (waypoints 1-2), nothing written to --out {out} or --json {js}; "
                     "first: waypoint 1: relative pose not reached")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["path.csv"]


def test_plan_dual_on_a_cell_file_with_six_digit_rotations_reports_the_residual_the_solver_holds(tmp_path):
    """A cell file whose R2 base rotation is printed to 6 decimals (orthonormal to ~1e-6, which the loader accepts):
    the solver holds the gun's pose exactly in the cell frame, but the check measured it in the workpiece frame
    through the transposed, not quite orthonormal rotation and reported every waypoint 'not reached' by its rounding
    times the gun's distance (~1e-4 mm against the 1e-6 mm tolerance)."""
    import re
    import shutil

    from calibration.kinematics import so3
    from calibration.models import ConstantModel
    from cell_config import DEFAULT_CELL

    shutil.copytree(DEFAULT_CELL.parent, tmp_path / "cell")
    path = tmp_path / "cell" / DEFAULT_CELL.name
    text = path.read_text()
    head, r2 = text.split("  R2:", 1)
    r2 = re.sub(r"-?0\.\d{9}", lambda m: f"{float(m.group(0)):.6f}", r2, count=9)  # the rotation's 9 entries
    path.write_text(head + "  R2:" + r2)
    cell = load_cell(path)
    Rb = cell.robot("R2").T_cell_base[:3, :3]
    assert 1e-7 < np.abs(Rb @ Rb.T - np.eye(3)).max() < 1e-5  # rounded, and still accepted
    out, js = tmp_path / "plan.json", tmp_path / "s.json"
    assert main(["plan-dual", "--cell", str(path), "--path", "sweep:4", "--no-compile", "--out", str(out),
                 "--json", str(js)]) == 0
    s = json.loads(js.read_text())
    assert s["converged"] and s["max_residual_mm"] < 1e-6
    plan = json.loads(out.read_text())
    T_wp_gun = np.array(plan["T_wp_gun"])
    pose = {}
    for name in ("R1", "R2"):  # the arms' poses in the cell frame, from the numpy models
        q = np.array([w[name] for w in plan["waypoints"]])
        R, p = ConstantModel(name, "nominal", cell.robot(name).model()).fk(q)
        T = cell.robot(name).T_cell_base
        pose[name] = (T[:3, :3] @ R, p @ T[:3, :3].T + T[:3, 3])
    (Rg, pg), (Rw, pw) = pose["R1"], pose["R2"]
    gun_mm = np.linalg.norm(pg - (pw + Rw @ T_wp_gun[:3, 3]), axis=1)  # where the gun is vs where it is asked
    gun_deg = np.degrees(np.linalg.norm(so3.log(np.swapaxes(Rw @ T_wp_gun[:3, :3], 1, 2) @ Rg), axis=1))
    assert gun_mm.max() < 1e-6 and gun_deg.max() < 1e-6
    np.testing.assert_allclose([w["residual_mm"] for w in plan["waypoints"]], gun_mm, atol=1e-9)


def test_export_and_preview_bad_inputs(tmp_path, planned, capsys):
    plan = json.loads((planned / "plan.json").read_text())
    plan["waypoints"][1]["converged"] = False
    plan["waypoints"][1]["reason"] = "near singularity"
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(plan))
    out = tmp_path / "t.csv"
    assert_bad_input(capsys, ["export-targets", "--plan", str(bad), "--out", str(out)], "waypoint 1: not solved: near singularity")
    assert_bad_input(capsys, ["export-targets", "--plan", str(planned / "plan.json"), "--out", str(tmp_path / "t.txt")],
         "valid: .csv, .json")
    assert_bad_input(capsys, ["preview", "--plan", str(planned / "plan.json")], "--html OUT", "--serve")
    assert_bad_input(capsys, ["preview", "--plan", str(tmp_path / "missing.json"), "--html", str(tmp_path / "p.html")],
         "plan file not found")
    assert not out.exists() and not (tmp_path / "p.html").exists()


def test_export_targets_of_a_plan_with_nothing_to_export_writes_nothing(tmp_path, planned, capsys):
    """A plan with no waypoints (or, with --skip-failed, none solved) wrote a header-only target file, exit 0."""
    plan = json.loads((planned / "plan.json").read_text())
    empty, unsolved = tmp_path / "empty.json", tmp_path / "unsolved.json"
    empty.write_text(json.dumps({**plan, "waypoints": []}))
    unsolved.write_text(json.dumps({**plan, "waypoints": [{**w, "converged": False} for w in plan["waypoints"]]}))
    out = tmp_path / "t.csv"
    assert_bad_input(capsys, ["export-targets", "--plan", str(empty), "--out", str(out)],
                     f"{empty}: no targets to export: the plan has no waypoints")
    assert_bad_input(capsys, ["export-targets", "--plan", str(unsolved), "--out", str(out), "--skip-failed"],
                     f"{unsolved}: no targets to export: none of its 12 waypoints was solved")
    assert not out.exists()


def test_validate_dual_sim_json_and_bad_inputs(tmp_path, capsys):
    pytest.importorskip("can")
    out = tmp_path / "v.json"
    assert main(["validate-dual", "--sim", "--configurations", "3", "--methods", "nominal,fbf13",
                 "--json", str(out)]) == 0
    table = capsys.readouterr().out
    assert "nominal" in table and "fbf13" in table
    v = json.loads(out.read_text())
    assert v["configurations"] == 3 and set(v["models"]) == {"nominal", "fbf13"}
    assert v["models"]["fbf13"]["mean_mm"] < v["models"]["nominal"]["mean_mm"]
    never = tmp_path / "never.json"
    assert_bad_input(capsys, ["validate-dual", "--configurations", "3", "--json", str(never)], "needs --plan", "--sim")
    assert_bad_input(capsys, ["validate-dual", "--plan", str(never), "--json", str(never)], "no controller block",
                     "--sim")
    assert_bad_input(capsys, ["validate-dual", "--sim", "--configurations", "1", "--json", str(never)], ">= 2")
    assert_bad_input(capsys, ["validate-dual", "--sim", "--methods", "nominal,magic", "--json", str(never)],
         "unknown model set 'magic'")
    # both were accepted and ignored, while their help said they apply with --sim (new-user run)
    assert_bad_input(capsys, ["validate-dual", "--sim", "--speed", "0.5", "--json", str(never)],
                     "--speed: not used by validate-dual --sim", "leave it out")
    assert_bad_input(capsys, ["validate-dual", "--sim", "--time-scale", "5", "--speed", "0.5", "--json", str(never)],
                     "--time-scale and --speed: not used by validate-dual --sim", "leave them out")
    assert not never.exists()


def test_validate_dual_help_names_the_default_model_sets_it_accepts():
    import argparse
    import re

    from app.cli.commands import build_parser
    from app.dual.sim import SIM_METHODS
    from calibration.method_names import METHODS

    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    action = next(a for a in sub.choices["validate-dual"]._actions if "--methods" in a.option_strings)
    default = re.search(r"default ([a-z0-9+,]+)", action.help).group(1).split(",")
    assert tuple(default) == SIM_METHODS and set(default) <= set(METHODS), action.help


def test_validate_dual_sim_dry_run_fits_and_measures_nothing(tmp_path, capsys):
    """--dry-run with --sim ran the whole simulated validation (fits, contacts, the table) as if it were not given."""
    out = tmp_path / "v.json"
    assert main(["validate-dual", "--sim", "--dry-run", "--configurations", "3", "--methods", "nominal,fbf13",
                 "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert printed.startswith("dry run, no motion") and "2 model set(s) to score (nominal, fbf13)" in printed
    assert "mean mm" not in printed
    assert json.loads(out.read_text()) == {"dry_run": True, "configurations": 3, "model_sets": ["nominal", "fbf13"]}
    assert_bad_input(capsys, ["validate-dual", "--sim", "--dry-run", "--methods", "nominal,magic"],
                     "unknown model set 'magic'")


def test_a_robot_given_twice_in_models_is_refused(tmp_path, capsys):
    """--models R1=a,R1=b planned (and validated) with b without a word; compensate-job already refuses it."""
    from calibration.models import ConstantModel

    cell = load_cell()
    a, b = tmp_path / "a.yaml", tmp_path / "b.yaml"
    for path in (a, b):
        save_model(ConstantModel("R1", "nominal", cell.robot("R1").model()), path)
    out = tmp_path / "plan.json"
    assert_bad_input(capsys, ["plan-dual", "--models", f"R1={a},R1={b}", "--path", "sweep:2", "--out", str(out)],
                     "--models", "R1 is given twice", "one model per robot")
    assert_bad_input(capsys, ["validate-dual", "--sim", "--models", f"R1={a},R1={b}", "--json", str(out)],
                     "R1 is given twice")
    assert not out.exists()


def test_validate_dual_sim_uses_its_seed_and_its_help_names_the_default(tmp_path):
    """--seed (help: 'seed of the simulated cell; --sim only (default 0)') was ignored: the validation cell is
    seeded 7 whatever was given."""
    import argparse
    import re

    from app.cli.commands import build_parser
    from app.dual.sim import VALIDATION_CELL

    pytest.importorskip("can")
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    action = next(a for a in sub.choices["validate-dual"]._actions if "--seed" in a.option_strings)
    assert int(re.search(r"default (\d+)", action.help).group(1)) == VALIDATION_CELL.seed, action.help
    means = {}
    for seed in (None, str(VALIDATION_CELL.seed), "3"):
        out = tmp_path / f"v{seed}.json"
        argv = ["validate-dual", "--sim", "--configurations", "3", "--methods", "nominal", "--json", str(out)]
        assert main(argv + (["--seed", seed] if seed else [])) == 0
        means[seed] = json.loads(out.read_text())["models"]["nominal"]["mean_mm"]
    assert means[None] == means[str(VALIDATION_CELL.seed)] != means["3"]


def test_a_plan_solved_with_a_model_leaves_only_with_that_model(tmp_path, capsys):
    """export-targets and preview recompute the relative pose from the models the plan was solved with: without
    them (the nominal model would be ~mm off) the plan is refused, naming the model to give; with them it leaves."""
    cell = load_cell()
    save_model(_diagnosed_r1(cell), tmp_path / "r1.yaml")
    plan, out = tmp_path / "plan.json", tmp_path / "t.csv"
    models = f"R1={tmp_path / 'r1.yaml'}"
    assert main(["plan-dual", "--models", models, "--path", "sweep:6", "--out", str(plan)]) == 0
    assert_bad_input(capsys, ["export-targets", "--plan", str(plan), "--out", str(out)],
                     "solved with a diagnosed model for R1", "--models R1=FILE")
    assert not out.exists()
    assert main(["export-targets", "--plan", str(plan), "--out", str(out), "--models", models]) == 0
    d = json.loads(plan.read_text())
    d["models"]["R1"] = "constant"  # the file now claims the nominal model: the recomputed pose is off
    plan.write_text(json.dumps(d))
    assert_bad_input(capsys, ["export-targets", "--plan", str(plan), "--out", str(tmp_path / "u.csv")],
                     "waypoint 0: relative pose not held", "R1 nominal")
    summary = tmp_path / "p.json"
    assert main(["preview", "--plan", str(plan), "--html", str(tmp_path / "p.html"), "--json", str(summary)]) == 0
    assert not json.loads(summary.read_text())["safe"]
