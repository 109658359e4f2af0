"""The ``cellcal`` command line: one function per subcommand.

Exit codes: 0 success, 2 bad input (one clear line on stderr, nothing written), 1 unexpected failure.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path
from typing import Any, Callable

from calibration.errors import CellCalError

log = logging.getLogger("cellcal.app")


def _cell(args: argparse.Namespace) -> Any:
    from cell_config import load_cell

    return load_cell(args.cell) if args.cell else load_cell()


def _read(path: str, robot: Any | None = None) -> Any:
    from calibration.recording import read_recording

    if robot is None:
        return read_recording(path)
    return read_recording(path, robot.robot.lower_rad, robot.robot.upper_rad)


def _fitter(args: argparse.Namespace) -> Any:
    from calibration.methods import FitOptions, Fitter

    robot = _cell(args).robot(args.robot)
    train = _read(args.train, robot)
    cpa = _read(args.cpa, robot) if args.cpa else None
    return Fitter(args.robot, robot.model(), train, FitOptions(a=args.a), cpa), robot


def _write_json(path: str | None, data: dict[str, Any]) -> None:
    if path:
        from calibration.files import atomic_write_text

        atomic_write_text(path, json.dumps(data, indent=1))


def cmd_fit(args: argparse.Namespace) -> int:
    from calibration.models import save_model

    fitter, _ = _fitter(args)
    model, seconds = fitter.fit(args.method)
    if model.info.get("warning"):
        print(f"warning: {model.info['warning']}", file=sys.stderr)
    save_model(model, args.out)
    print(f"{args.method}: {model.n_parameters} parameters fitted on {len(fitter.train)} samples in {seconds:.3f} s "
          f"-> {args.out}")
    return 0


def cmd_predict(args: argparse.Namespace) -> int:
    from calibration import so3
    from calibration.models import load_model
    from calibration.recording import read_joints, write_table

    model = load_model(args.model)
    q = read_joints(args.joints)
    outside = model.out_of_range(q)
    if outside.any():
        print(f"warning: {int(outside.sum())} of {len(q)} configurations lie outside the region the "
              f"{model.method} model was fitted on; its parameters there are extrapolated", file=sys.stderr)
    R, p = model.fk(q)
    quat = so3.R_to_quat(R)
    write_table(args.out, {"x": p[:, 0], "y": p[:, 1], "z": p[:, 2], "qw": quat[:, 0], "qx": quat[:, 1],
                           "qy": quat[:, 2], "qz": quat[:, 3]})
    print(f"{len(q)} poses -> {args.out}")
    return 0


def cmd_evaluate(args: argparse.Namespace) -> int:
    from calibration.metrics import error_stats, errors
    from calibration.models import load_model

    model = load_model(args.model)
    test = _read(args.test)
    result = {"robot": model.robot, "method": model.method, "samples": len(test),
              "test": error_stats(errors(model, test))}
    pos, ori = result["test"]["position_mm"], result["test"]["orientation_deg"]
    print(f"{model.method} on {len(test)} samples: position mean {pos['mean']:.3f} std {pos['std']:.3f} "
          f"max {pos['max']:.3f} mm; orientation mean {ori['mean']:.3f} max {ori['max']:.3f} deg")
    _write_json(args.json, result)
    return 0


def cmd_compare(args: argparse.Namespace) -> int:
    from app.compare import parse_methods, run_comparison
    from app.report import comparison_table, write_report

    methods = parse_methods(args.methods)
    fitter, robot = _fitter(args)
    test = _read(args.test, robot)
    cmp = run_comparison(fitter, test, methods)
    warning = cmp.analysis["observability"]["warning"]
    if warning:
        print(f"warning: {warning}", file=sys.stderr)
    print(comparison_table(cmp, with_paper=args.robot == "R1"))
    _write_json(args.json, cmp.to_json())
    if args.report:
        files = write_report(cmp, test, args.report, with_paper=args.robot == "R1")
        print(f"report: {files[-1]}")
    return 0


# -- dual-robot planning, validation, preview, export ----------------------------------------------------------


def _model_pair(spec: str | None, where: str) -> dict[str, Any]:
    """``R1=a.yaml,R2=b.yaml`` -> {robot: model}; robots not named stay nominal (absent from the dict)."""
    from calibration.errors import DataError
    from calibration.models import load_model

    models: dict[str, Any] = {}
    for item in filter(None, (spec or "").split(",")):
        robot, sep, path = item.partition("=")
        if not sep or robot.strip() not in ("R1", "R2") or not path.strip():
            raise DataError(where, None, None, f"bad model entry {item!r}; expected R1=FILE,R2=FILE")
        models[robot.strip()] = load_model(path.strip())
    return models


def cmd_plan_dual(args: argparse.Namespace) -> int:
    import numpy as np

    from app.dual_paths import Q_REF_DEG, read_path, read_pose, relative_pose
    from app.dual_plan import DualPlanner, PlannerOptions
    from app.plan_result import save_plan
    from calibration.errors import ModelError

    models = _model_pair(args.models, "--models")
    T_rel = read_pose(args.relative_pose) if args.relative_pose else None
    planner = DualPlanner(_cell(args), models.get("R1"), models.get("R2"), PlannerOptions(compile=not args.no_compile))
    path = read_path(args.path, planner)
    q0 = np.radians(Q_REF_DEG)
    plan = planner.plan(path, relative_pose(planner, q0) if T_rel is None else T_rel, q0)
    ms = [w.solve_ms for w in plan.waypoints]
    summary = {"waypoints": len(plan.waypoints), "converged": plan.converged, "failed": plan.failed,
               "models": plan.models, "solve_ms_median": float(np.median(ms)),
               "max_residual_mm": max(w.residual_mm for w in plan.waypoints),
               "max_residual_deg": max(w.residual_deg for w in plan.waypoints),
               "min_clearance_mm": min(w.clearance_mm for w in plan.waypoints), "out": args.out}
    if not plan.converged:
        i = plan.failed[0]
        raise ModelError(f"{len(plan.failed)} of {len(plan.waypoints)} waypoints not solved, nothing written; "
                         f"first: waypoint {i}: {plan.waypoints[i].reason}")
    if args.out:
        save_plan(plan, args.out)
    _write_json(args.json, summary)
    print(f"{len(plan.waypoints)} waypoints solved ({plan.models['R1']}/{plan.models['R2']}), median "
          f"{summary['solve_ms_median']:.2f} ms, residual <= {summary['max_residual_mm']:.1e} mm, clearance >= "
          f"{summary['min_clearance_mm']:.0f} mm" + (f" -> {args.out}" if args.out else ""))
    return 0


def _model_sets(specs: list[str] | None, cell: Any) -> dict[str, dict[str, Any]]:
    """``[LABEL:]R1=a,R2=b`` per entry -> {label: {R1, R2}} (label: the models' method by default)."""
    from calibration.models import ConstantModel

    out: dict[str, dict[str, Any]] = {}
    for spec in specs or []:
        label, sep, rest = spec.partition(":")
        if not sep or "=" in label:
            label, rest = "", spec
        pair = _model_pair(rest, "--models")
        if not label:
            label = "/".join(sorted({m.method for m in pair.values()})) or "nominal"
        for robot in ("R1", "R2"):
            pair.setdefault(robot, ConstantModel(robot, "nominal", cell.robot(robot).model()))
        out[label] = pair
    return out


def cmd_validate_dual(args: argparse.Namespace) -> int:
    from app.validate_dual import run_sim_validation
    from calibration.errors import ConfigError, ModelError

    if not args.sim:
        raise ConfigError(args.cell if getattr(args, "cell", None) else "cell.yaml", "probe",
                          "no robot drivers or CAN contact probe are configured for a real-cell validation; "
                          "use --sim for the simulated cell")
    if args.configurations < 2:
        raise ModelError(f"--configurations must be >= 2, got {args.configurations}")
    methods = tuple(m.strip() for m in args.methods.split(",") if m.strip()) if args.methods else None
    cell = _cell(args)
    result = run_sim_validation(cell, args.configurations, _model_sets(args.models, cell) or None, methods)
    print(result.table())
    _write_json(args.json, result.to_json())
    return 0


def cmd_preview(args: argparse.Namespace) -> int:
    from app.preview import preview
    from calibration.errors import ModelError

    if not args.html and not args.serve:
        raise ModelError("preview needs --html OUT (a static page) or --serve (a live viewer)")
    result = preview(_cell(args), args.plan, html_out=args.html, serve=args.serve)
    if result.html_path:
        print(f"{result.n_frames} frames -> {result.html_path}")
    if result.url:
        print(f"live viewer at {result.url}; press Enter to stop", flush=True)
        try:
            input()
        except (EOFError, KeyboardInterrupt):
            pass
    return 0


def cmd_export_targets(args: argparse.Namespace) -> int:
    from app.export_targets import export_targets

    n = export_targets(args.plan, _cell(args), args.out, args.frame, args.skip_failed)
    print(f"{n} targets ({args.frame} frame) -> {args.out}")
    return 0


def _add_dual_parsers(add: Callable[..., argparse.ArgumentParser]) -> None:
    def cell_arg(p: argparse.ArgumentParser) -> None:  # also accepted after the subcommand
        p.add_argument("--cell", default=argparse.SUPPRESS, help="cell.yaml (default: the packaged Motoman cell)")

    p = add("plan-dual", cmd_plan_dual, "plan both arms holding a relative tool pose along a workpiece path")
    cell_arg(p)
    p.add_argument("--models", help="R1=FILE,R2=FILE (a robot left out uses its nominal model)")
    p.add_argument("--relative-pose", help="gun pose in the workpiece frame: a file (JSON {p_mm, quat} or CSV) or "
                                           "inline x,y,z,qw,qx,qy,qz [mm]; default: the reference pose")
    p.add_argument("--path", default="sweep:200", help="CSV/JSON of workpiece poses in the cell frame "
                                                       "(x,y,z,qw,qx,qy,qz [mm]) or sweep:N (default sweep:200)")
    p.add_argument("--out", help="write the plan file (JSON)")
    p.add_argument("--json", help="write a summary as JSON")
    p.add_argument("--no-compile", action="store_true", help="interpreted casadi function (no C compiler)")
    p = add("validate-dual", cmd_validate_dual, "contact validation of model sets (the paper's dual-robot check)")
    cell_arg(p)
    p.add_argument("--sim", action="store_true", help="run on the simulated cell (twins, simulated arms and probe)")
    p.add_argument("--configurations", type=int, default=20, help="contact configurations, inward to outstretched")
    p.add_argument("--models", action="append", help="[LABEL:]R1=FILE,R2=FILE, repeatable; with --sim and none, "
                                                     "the model sets are fitted on twin data")
    p.add_argument("--methods", help="model sets to fit with --sim (default nominal,cpa,fbf13,ae,physics)")
    p.add_argument("--json", help="write the statistics as JSON")
    p = add("preview", cmd_preview, "meshcat preview of a plan (static HTML page or live viewer)")
    cell_arg(p)
    p.add_argument("--plan", required=True, help="plan file (dual or collection)")
    p.add_argument("--html", help="write a self-contained HTML page")
    p.add_argument("--serve", action="store_true", help="start a live meshcat viewer and wait for Enter")
    p = add("export-targets", cmd_export_targets, "controller targets (rad, pulses, poses) from a dual plan")
    cell_arg(p)
    p.add_argument("--plan", required=True, help="plan file written by plan-dual")
    p.add_argument("--out", required=True, help="targets file (.csv or .json)")
    p.add_argument("--frame", choices=("flange", "tool"), default="flange", help="pose frame of the targets")
    p.add_argument("--skip-failed", action="store_true", help="leave out unsolved waypoints instead of refusing")
_NO_HARDWARE = ("no real robot controller or mocap is configured for {robot} in {cell} (only the simulated devices "
                "exist so far); run with --sim to use the simulated arm and mocap over Zenoh")


def _require_sim(args: argparse.Namespace, cell: Any) -> None:
    if not args.sim:
        raise CellCalError(_NO_HARDWARE.format(robot=args.robot, cell=cell.path.name))


def _load_plan(path: str, robot: str) -> Any:
    from app.planning import Plan
    from calibration.errors import DataError

    plan = Plan.load(path)
    if plan.robots != (robot,):
        raise DataError(path, None, "targets", f"the plan moves {', '.join(plan.robots) or 'nothing'}, "
                                               f"expected {robot} only")
    return plan


def _require_session(path: str) -> None:
    from app.session_store import SessionStore

    SessionStore(path).close()  # raises DataError when there is no session


def _sim_config(args: argparse.Namespace) -> Any:
    from app.cell_runtime import SimCellConfig

    return SimCellConfig(time_scale=args.time_scale, seed=args.seed)


def cmd_plan(args: argparse.Namespace) -> int:
    from app.cell_runtime import park_q
    from app.safety import CellSafety
    from app.session_plan import PlanSpec, session_plan

    cell = _cell(args)
    cell.robot(args.robot)
    others = {n: park_q(n) for n in cell.robots if n != args.robot}
    spec = PlanSpec(q2_step_deg=args.q2_step, q3_step_deg=args.q3_step, cpa=args.cpa,
                    n_validation=args.validation, seed=args.seed)
    plan = session_plan(args.robot, CellSafety(cell), others, spec, park_q(args.robot))
    plan.save(args.out)
    kinds: dict[str, int] = {}
    for t in plan.targets:
        kinds[t.kind] = kinds.get(t.kind, 0) + 1
    print(f"{args.robot}: {len(plan)} targets ({', '.join(f'{v} {k}' for k, v in kinds.items())}), checked safe "
          f"with the other arms parked -> {args.out}")
    return 0


def cmd_collect(args: argparse.Namespace) -> int:
    from app.cell_runtime import SimCell
    from app.demo import DEMO_COLLECT, collect_arm
    from app.safety import CellSafety

    cell = _cell(args)
    cell.robot(args.robot)
    _require_sim(args, cell)
    if args.resume:
        _require_session(args.session)
    elif not args.plan:
        raise CellCalError("a new session needs --plan PLAN (or --resume an existing one)")
    elif (Path(args.session) / "session.sqlite").exists():
        raise CellCalError(f"{args.session} already holds a session; pass --resume or choose a new folder")
    plan = _load_plan(args.plan, args.robot) if args.plan else None
    with SimCell(cell, _sim_config(args)) as sim:
        result = collect_arm(sim, CellSafety(cell), args.robot, plan, Path(args.session), DEMO_COLLECT,
                             resume=args.resume, progress=not args.no_progress)
        frames = sim.frames_received
    print(f"{args.robot}: {result.n_ok} of {result.n_targets} targets measured, {result.n_skipped} skipped, "
          f"{result.n_new} new this run in {result.elapsed_s:.1f} s ({frames} mocap frames over zenoh) -> "
          f"{args.session}")
    for index, reason in result.skipped:
        print(f"  skipped target {index}: {reason}")
    _write_json(args.json, {"robot": args.robot, "session": str(args.session), "targets": result.n_targets,
                            "measured": result.n_ok, "skipped": [list(s) for s in result.skipped],
                            "new": result.n_new, "complete": result.complete, "seconds": result.elapsed_s,
                            "mocap_frames_received": frames})
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    from app.collect import export
    from app.planning import KINDS

    kinds = None
    if args.kinds:
        kinds = [k.strip() for k in args.kinds.split(",") if k.strip()]
        bad = [k for k in kinds if k not in KINDS]
        if bad or not kinds:
            raise CellCalError(f"unknown target kind {bad[0] if bad else args.kinds!r}; valid: {', '.join(KINDS)}")
    n = export(args.session, args.out, kinds)
    print(f"{n} samples -> {args.out}")
    return 0


def cmd_recalibrate(args: argparse.Namespace) -> int:
    import time as _time

    from app.cell_runtime import SimCell
    from app.collect import export
    from app.demo import DEMO_COLLECT, collect_arm
    from app.recalibrate import check_model_dir, current_model, decide_and_install
    from app.safety import CellSafety
    from app.session_plan import validation_plan
    from calibration.methods import Fitter
    from calibration.recording import read_recording

    cell = _cell(args)
    robot = cell.robot(args.robot)
    model_dir = check_model_dir(args.model_dir)
    if args.validation < 1:
        raise CellCalError(f"--validation must be at least 1, got {args.validation}")
    plan = _load_plan(args.plan, args.robot) if args.plan else None
    if args.session:
        _require_session(args.session)
    current_model(model_dir, args.robot)  # unreadable or foreign model in service: stop before any motion
    _require_sim(args, cell)
    stamp = _time.strftime("%Y%m%dT%H%M%S")
    work = model_dir / "sessions" / stamp
    seed = args.validation_seed if args.validation_seed is not None else int(_time.time()) % 100_000
    safety = CellSafety(cell)
    with SimCell(cell, _sim_config(args)) as sim:
        session = Path(args.session) if args.session else work / "train"
        if plan is not None:
            collect_arm(sim, safety, args.robot, plan, session, DEMO_COLLECT, progress=not args.no_progress)
        parked = {n: d.read_joints().q for n, d in sim.others(args.robot).items()}
        val_plan = validation_plan(args.robot, safety, parked, args.validation, seed=seed)
        collect_arm(sim, safety, args.robot, val_plan, work / "validation", DEMO_COLLECT,
                    progress=not args.no_progress)
    read = lambda p: read_recording(p, robot.robot.lower_rad, robot.robot.upper_rad)  # noqa: E731
    export(session, work / "train.csv", kinds=("anchor", "perturb"))
    cpa = None
    if args.method == "cpa":
        export(session, work / "cpa.csv", kinds=("cpa",))
        cpa = read(work / "cpa.csv")
    export(work / "validation", work / "validation.csv")
    fitter = Fitter(args.robot, robot.model(), read(work / "train.csv"), cpa_data=cpa)
    model, _ = fitter.fit(args.method)
    decision = decide_and_install(model_dir, model, read(work / "validation.csv"))
    print(decision.summary())
    print(f"model in service: {decision.current_path}" + (f"; previous one archived as {decision.archived}"
                                                           if decision.archived else ""))
    _write_json(args.json, decision.to_json())
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    from app.demo import DemoConfig, run_demo, summary_table

    result = run_demo(args.out, _cell(args), DemoConfig(full=args.full, seed=args.seed,
                                                        progress=not args.no_progress))
    print(summary_table(result.summary))
    print(f"demo finished in {result.seconds:.1f} s; {result.summary['mocap_frames_received']} mocap frames "
          f"received over zenoh")
    print(f"summary: {result.out_dir / 'summary.json'}")
    print(f"report: {result.report}")
    return 0


def cmd_diagnose(args: argparse.Namespace) -> int:
    from app.diagnose import run_diagnose

    result = run_diagnose(args.robot, args.data, heldout=args.heldout, model=args.model, json_path=args.json,
                          report_dir=args.report, model_out=args.out, cell=args.cell)
    print(result.verdict)
    return 0


def _add_fit_inputs(p: argparse.ArgumentParser) -> None:
    p.add_argument("--robot", required=True, help="robot name in the cell (R1, R2)")
    p.add_argument("--train", required=True, help="training recording CSV or Welding_Motoman folder")
    p.add_argument("--cpa", help="single-joint sweep recording for circular point analysis")
    p.add_argument("--a", type=float, default=1641.0, help="orientation weight (1641: 1 mm ~ 1 deg)")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="cellcal", description=__doc__.splitlines()[0])
    parser.add_argument("--cell", help="cell.yaml (default: the packaged Motoman cell)")
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress")
    sub = parser.add_subparsers(dest="command", required=True)

    def add(name: str, func: Callable[[argparse.Namespace], int], help_text: str) -> argparse.ArgumentParser:
        p = sub.add_parser(name, help=help_text)
        p.set_defaults(func=func)
        return p

    from calibration.methods import METHODS

    p = add("fit", cmd_fit, "fit one method and save the model")
    _add_fit_inputs(p)
    p.add_argument("--method", required=True, choices=METHODS)
    p.add_argument("--out", required=True, help="model file (.yaml or .json)")
    p = add("predict", cmd_predict, "tool poses of a model for joint angles")
    p.add_argument("--model", required=True)
    p.add_argument("--joints", required=True, help="CSV with q1..q6 [rad] (header) or 6 headerless columns")
    p.add_argument("--out", required=True)
    p = add("evaluate", cmd_evaluate, "accuracy of a model on a recording")
    p.add_argument("--model", required=True)
    p.add_argument("--test", required=True)
    p.add_argument("--json", help="write the statistics as JSON")
    p = add("compare", cmd_compare, "the paper's comparison table for every method")
    _add_fit_inputs(p)
    p.add_argument("--test", required=True)
    p.add_argument("--methods", default="all", help="all, or a comma-separated list")
    p.add_argument("--json", help="write the comparison as JSON")
    p.add_argument("--report", help="write Markdown tables and PNG plots into this folder")
    p = add("diagnose", cmd_diagnose, "find the physics the model in use left out, model it, show the fit improve")
    p.add_argument("--robot", required=True, help="robot name in the cell (R1, R2)")
    p.add_argument("--data", required=True, help="recording CSV or Welding_Motoman folder to fit on")
    p.add_argument("--heldout", help="recording the selection never fits on (default: held-out clusters of --data)")
    p.add_argument("--model", help="model in use (default: the geometric NLS fit of --data)")
    p.add_argument("--json", help="write the report (schema cellcal.diagnose/1)")
    p.add_argument("--report", help="write the report as Markdown with plots into this folder")
    p.add_argument("--out", help="save the refitted geometry + physics model")
    _add_dual_parsers(add)
    p = add("plan", cmd_plan, "make a collection plan for one arm (anchor grid, CPA sweeps, validation poses)")
    p.add_argument("--robot", required=True, help="robot name in the cell (R1, R2)")
    p.add_argument("--out", required=True, help="plan file (JSON)")
    p.add_argument("--q2-step", type=float, default=5.0, help="anchor grid q2 step [deg] (5: the paper's design)")
    p.add_argument("--q3-step", type=float, default=5.0, help="anchor grid q3 step [deg]")
    p.add_argument("--cpa", action="store_true", help="add single-joint sweeps (needed by the cpa method)")
    p.add_argument("--validation", type=int, default=0, help="random validation poses to add (the test set)")
    p.add_argument("--seed", type=int, default=0, help="seed of the validation poses")

    def add_sim(p: argparse.ArgumentParser) -> None:
        p.add_argument("--sim", action="store_true",
                       help="use the simulated arm and mocap (over Zenoh on loopback); required for now: no real "
                            "controller or mocap is configured in cell.yaml")
        p.add_argument("--seed", type=int, default=0, help="seed of the simulated cell (its planted errors)")
        p.add_argument("--time-scale", type=float, default=20.0, help="simulated seconds per real second")
        p.add_argument("--no-progress", action="store_true", help="no progress bars")

    p = add("collect", cmd_collect, "guided collection session of one arm (durable, resumable)")
    p.add_argument("--robot", required=True, help="robot name in the cell (R1, R2)")
    p.add_argument("--plan", help="plan file (cellcal plan); optional with --resume")
    p.add_argument("--session", required=True, help="session folder (created; holds session.sqlite)")
    p.add_argument("--resume", action="store_true", help="continue the session at the first target not recorded")
    p.add_argument("--json", help="write the session outcome as JSON")
    add_sim(p)
    p = add("export", cmd_export, "write a session's measured samples as a recording CSV")
    p.add_argument("--session", required=True, help="session folder")
    p.add_argument("--out", required=True, help="recording CSV")
    p.add_argument("--kinds", help="comma-separated target kinds to include (anchor, perturb, cpa, validation); all "
                                   "by default")
    p = add("recalibrate", cmd_recalibrate, "fit a new model, compare it with the one in service on fresh validation "
                                            "poses, replace it only if better")
    p.add_argument("--robot", required=True, help="robot name in the cell (R1, R2)")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--session", help="reuse the training samples of this session")
    src.add_argument("--plan", help="collect a new training session from this plan")
    p.add_argument("--model-dir", required=True, help="folder of the model in service (current.yaml, previous/)")
    p.add_argument("--method", default="fbf13", choices=METHODS)
    p.add_argument("--validation", type=int, default=30, help="fresh validation poses to measure")
    p.add_argument("--validation-seed", type=int, help="seed of the validation poses (default: from the clock)")
    p.add_argument("--json", help="write the decision with both figures as JSON")
    add_sim(p)
    p = add("demo", cmd_demo, "the main job on the simulated cell: collect both arms over zenoh, fit, evaluate, "
                              "report")
    p.add_argument("--out", default="demo_out", help="output folder (an earlier demo there is replaced)")
    p.add_argument("--full", action="store_true", help="the paper's 248-anchor design (5 deg steps; ~4x longer)")
    p.add_argument("--seed", type=int, default=0, help="seed of the planted errors, the noise and the validation poses")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, format="%(message)s")
    try:
        return args.func(args)
    except CellCalError as e:
        print(f"cellcal {args.command}: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
