"""``cellcal`` subcommands of the cell workflow: plan, collect, export, recalibrate, demo."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any, Callable

from app.analysis.fitting import fitter_for
from app.cli.common import cell_spec, log, write_json
from calibration.errors import CellCalError


def _load_plan(path: str, robot: str) -> Any:
    from app.cell.plan_file import read_plan
    from calibration.errors import DataError

    plan = read_plan(path, "collection")
    if plan.robots != (robot,):
        raise DataError(path, None, "targets", f"the plan moves {', '.join(plan.robots) or 'nothing'}, "
                                               f"expected {robot} only")
    return plan


def _require_session(path: str) -> None:
    from app.cell.session_store import SessionStore

    SessionStore(path).close()  # raises DataError when there is no session


def cmd_plan(args: argparse.Namespace) -> int:
    from app.cell.runtime import park_q
    from app.cell.safety import CellSafety
    from app.cell.session_plan import PlanSpec, session_plan

    cell = cell_spec(args)
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


def _print_events(session: str) -> list[dict[str, Any]]:
    """Print why the arms were stopped in this session (every recorded event); returns them for --json."""
    from dataclasses import asdict

    from app.cell.session_store import SessionStore

    with SessionStore(session, lock=False) as store:
        events = store.events()
    if events:
        print(f"{len(events)} stop(s) recorded in {session}:")
    for e in events:
        print(f"  {e.line()}")
    return [asdict(e) for e in events]


def cmd_collect(args: argparse.Namespace) -> int:
    from app.cli.cell_options import confirm_motion, motion_config, open_runtime, safety_for
    from app.cell.collect import SessionAborted
    from app.demo.run import collect_arm
    from app.cell.session_store import SessionStore

    cell = cell_spec(args)
    cell.robot(args.robot)
    runtime = open_runtime(cell, args, robots=(args.robot,))  # a real cell's devices and registration: checked now
    if args.resume:
        _require_session(args.session)  # refused at once when there is none or another process holds it
    elif not args.plan:
        raise CellCalError("a new session needs --plan PLAN (or --resume an existing one)")
    elif SessionStore.exists(args.session):
        raise CellCalError(f"{args.session} already holds a session; pass --resume or choose a new folder")
    plan = _load_plan(args.plan, args.robot) if args.plan else None
    config, safety = motion_config(cell, args), safety_for(cell, args)
    with runtime as rt:
        if args.dry_run:
            return _dry_run(args, rt, safety, plan, config)
        confirm_motion(args, f"{args.robot} will visit the targets of {args.plan or args.session} at "
                             f"{config.speed_fraction:g} of full speed")
        try:
            result = collect_arm(rt, safety, args.robot, plan, Path(args.session), config,
                                 resume=args.resume, progress=not args.no_progress)
        except SessionAborted:
            _print_events(args.session)
            raise
        frames = rt.frames_received
    print(f"{args.robot}: {result.n_ok} of {result.n_targets} targets measured, {result.n_skipped} skipped, "
          f"{result.n_new} new this run in {result.elapsed_s:.1f} s ({frames} mocap frames over zenoh) -> "
          f"{args.session}")
    for index, reason in result.skipped:
        print(f"  skipped target {index}: {reason}")
    events = _print_events(args.session)
    write_json(args.json, {"robot": args.robot, "session": str(args.session), "targets": result.n_targets,
                            "measured": result.n_ok, "skipped": [list(s) for s in result.skipped],
                            "new": result.n_new, "complete": result.complete, "seconds": result.elapsed_s,
                            "mocap_frames_received": frames, "events": events, "sim": bool(args.sim)})
    return 0


def _dry_run(args: argparse.Namespace, rt: Any, safety: Any, plan: Any, config: Any) -> int:
    """Check the whole plan from where the arm stands against the other arms' live poses; print it; no motion."""
    from app.cell.dry_run import summarize_plan
    from app.cell.motion import live_poses, read_q
    from app.cell.planning import Plan
    from app.cell.session_store import SessionStore

    if plan is None:
        with SessionStore(args.session) as store:
            plan, done = store.plan(), store.done()
        plan = Plan(tuple(t for i, t in enumerate(plan.targets) if i not in done), plan.params)
    driver = rt.drivers[args.robot]
    others = live_poses(rt.others(args.robot))
    summary = summarize_plan(plan, safety, others, read_q(driver), speed_fraction=config.speed_fraction,
                             per_target_s=config.dwell_s + config.discard_s + 0.5)
    print("dry run, no motion:")
    for line in summary.lines():
        print(f"  {line}")
    write_json(args.json, {"robot": args.robot, "dry_run": True, **summary.to_json()})
    if not summary.safe:
        raise CellCalError(f"dry run: the plan would be refused: {summary.safety_error}")
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    from app.cell.collect import export
    from app.cell.planning import KINDS

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

    from app.cli.cell_options import confirm_motion, motion_config, open_runtime, safety_for
    from app.cell.collect import export
    from app.demo.run import collect_arm
    from app.analysis.recalibrate import check_model_dir, decide_and_install, model_in_service
    from app.cell.session_plan import validation_plan
    from calibration.recording import read_recording

    cell = cell_spec(args)
    robot = cell.robot(args.robot)
    runtime = open_runtime(cell, args, robots=(args.robot,))  # a real cell's devices and registration: checked now
    model_dir = check_model_dir(args.model_dir)
    if args.validation < 1:
        raise CellCalError(f"--validation must be at least 1, got {args.validation}")
    plan = _load_plan(args.plan, args.robot) if args.plan else None
    if args.session:
        _require_session(args.session)
    service = model_in_service(model_dir, args.robot, robot.model())  # another robot's model: stop before motion
    if service.problem:
        log.warning("the model in service %s is unusable (%s); a valid candidate will replace it",
                    model_dir / "current.yaml", service.problem)
    stamp = _time.strftime("%Y%m%dT%H%M%S")
    work = model_dir / "sessions" / stamp
    seed = args.validation_seed if args.validation_seed is not None else int(_time.time()) % 100_000
    config, safety = motion_config(cell, args), safety_for(cell, args)
    with runtime as rt:
        session = Path(args.session) if args.session else work / "train"
        parked = {n: d.read_joints().q for n, d in rt.others(args.robot).items()}
        val_plan = validation_plan(args.robot, safety, parked, args.validation, seed=seed)
        if args.dry_run:
            from app.cell.planning import Plan

            both = Plan((plan.targets if plan is not None else ()) + val_plan.targets, val_plan.params)
            return _dry_run(args, rt, safety, both, config)
        confirm_motion(args, f"{args.robot} will visit {len(plan) if plan is not None else 0} training and "
                             f"{len(val_plan)} validation targets at {config.speed_fraction:g} of full speed")
        if plan is not None:
            collect_arm(rt, safety, args.robot, plan, session, config, progress=not args.no_progress)
        collect_arm(rt, safety, args.robot, val_plan, work / "validation", config, progress=not args.no_progress)
    read = lambda p: read_recording(p, robot.robot.lower_rad, robot.robot.upper_rad)  # noqa: E731
    export(session, work / "train.csv", kinds=("anchor", "perturb"))
    cpa = None
    if args.method == "cpa":
        export(session, work / "cpa.csv", kinds=("cpa",))
        cpa = read(work / "cpa.csv")
    export(work / "validation", work / "validation.csv")
    fitter = fitter_for(robot, read(work / "train.csv"), cpa)
    model, _ = fitter.fit(args.method)
    decision = decide_and_install(model_dir, model, read(work / "validation.csv"), robot.model())
    print(decision.summary())
    print(f"model in service: {decision.current_path}" + (f"; previous one archived as {decision.archived}"
                                                           if decision.archived else ""))
    write_json(args.json, decision.to_json())
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    from app.demo.run import DemoConfig, run_demo, summary_table

    result = run_demo(args.out, cell_spec(args), DemoConfig(full=args.full, seed=args.seed,
                                                        progress=not args.no_progress))
    print(summary_table(result.summary))
    print(f"demo finished in {result.seconds:.1f} s; {result.summary['mocap_frames_received']} mocap frames "
          f"received over zenoh")
    print(f"summary: {result.out_dir / 'summary.json'}")
    print(f"report: {result.report}")
    return 0


def add_cell_parsers(add: Callable[..., argparse.ArgumentParser]) -> None:
    """Register the cell-workflow subcommands."""
    from app.cli.cell_options import add_motion_options
    from calibration.methods import METHODS

    p = add("plan", cmd_plan, "make a collection plan for one arm (anchor grid, CPA sweeps, validation poses)")
    p.add_argument("--robot", required=True, help="robot name in the cell (R1, R2)")
    p.add_argument("--out", required=True, help="plan file (JSON)")
    p.add_argument("--q2-step", type=float, default=5.0, help="anchor grid q2 step [deg] (5: the paper's design)")
    p.add_argument("--q3-step", type=float, default=5.0, help="anchor grid q3 step [deg]")
    p.add_argument("--cpa", action="store_true", help="add single-joint sweeps (needed by the cpa method)")
    p.add_argument("--validation", type=int, default=0, help="random validation poses to add (the test set)")
    p.add_argument("--seed", type=int, default=0, help="seed of the validation poses")

    p = add("collect", cmd_collect, "guided collection session of one arm (durable, resumable)")
    p.add_argument("--robot", required=True, help="robot name in the cell (R1, R2)")
    p.add_argument("--plan", help="plan file (cellcal plan); optional with --resume")
    p.add_argument("--session", required=True, help="session folder (created; holds session.sqlite)")
    p.add_argument("--resume", action="store_true", help="continue the session at the first target not recorded")
    p.add_argument("--json", help="write the session outcome as JSON")
    add_motion_options(p)
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
    p.add_argument("--method", default="pi+fbf13", choices=METHODS)
    p.add_argument("--validation", type=int, default=30, help="fresh validation poses to measure")
    p.add_argument("--validation-seed", type=int, help="seed of the validation poses (default: from the clock)")
    p.add_argument("--json", help="write the decision with both figures as JSON")
    add_motion_options(p)
    p = add("demo", cmd_demo, "the main job on the simulated cell: collect both arms over zenoh, fit, evaluate, "
                              "report")
    p.add_argument("--out", default="demo_out", help="output folder (an earlier demo there is replaced)")
    p.add_argument("--full", action="store_true", help="the paper's 248-anchor design (5 deg steps; ~4x longer)")
    p.add_argument("--seed", type=int, default=0, help="seed of the planted errors, the noise and the validation poses")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
