"""``cellcal`` subcommands of the cell workflow: plan, collect, export, recalibrate, demo."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from app.cli.common import (
    SIGMA_RESIDUAL_HELP,
    add_report_options,
    add_topup_options,
    cell_spec,
    command_line,
    epoch_bar,
    non_negative_int,
    positive_float,
    show_progress,
    sigma_residual,
    tolerance_from_args,
    validation_count,
    write_json,
)
from calibration.errors import CellCalError

if TYPE_CHECKING:
    from app.collection.runtime.cell import Cell

#: The anchor-grid steps ``plan --q2-step/--q3-step`` and ``demo --anchor-step`` accept [deg].
MIN_GRID_STEP_DEG, MAX_GRID_STEP_DEG = 0.5, 90.0
#: ``plan --design grid``'s default step [deg]: the paper's 5-degree grid (248 anchors, 1736 poses on R1).
GRID_STEP_DEG = 5.0
#: ``plan``'s default --budget [poses] per purpose: 196 (28 clusters, about a ninth of the paper's grid, which sees
#: all 27 directions on the packaged R1 where the grid sees 11) for identification; 21 (3 clusters, the rebase
#: design's least) for --for rebase.
DEFAULT_BUDGET = {"identification": 196, "rebase": 21}


def cmd_plan(args: argparse.Namespace) -> int:
    from app.collection.plans.session import PlanSpec, session_plan
    from app.collection.runtime.sim import park_q
    from app.collection.safety import CellSafety

    cell = cell_spec(args)
    robot = cell.robot(args.robot)
    others = {n: park_q(n) for n in cell.robots if n != args.robot}
    safety = CellSafety(cell)
    for option, step in (("--q2-step", args.q2_step), ("--q3-step", args.q3_step)):
        if step is not None and args.design != "grid":
            raise CellCalError(f"{option} applies to --design grid only (the paper's anchor grid; the default design "
                               "is optimal): add --design grid")
        _check_grid_step(option, GRID_STEP_DEG if step is None else step)
    if args.given is not None or args.task is not None:
        return _plan_topup(args, cell, robot, safety, others)
    spec = PlanSpec(q2_step_deg=args.q2_step or GRID_STEP_DEG, q3_step_deg=args.q3_step or GRID_STEP_DEG,
                    cpa=args.cpa, n_validation=args.validation, seed=args.seed)
    anchors, figs = None, None
    if args.design == "optimal":
        anchors, figs = _optimal_anchors(args, robot, safety, others, park_q(args.robot))
    elif args.budget is not None:
        raise CellCalError("--budget applies to --design optimal only (the grid's size is set by its steps)")
    elif args.target != "identification":
        raise CellCalError("--for applies to --design optimal only")
    plan = session_plan(args.robot, safety, others, spec, park_q(args.robot), anchors)
    plan.save(args.out)
    kinds: dict[str, int] = {}
    for t in plan.targets:
        kinds[t.kind] = kinds.get(t.kind, 0) + 1
    print(f"{args.robot}: {len(plan)} targets ({', '.join(f'{v} {k}' for k, v in kinds.items())}), checked safe "
          f"with the other arms parked -> {args.out}")
    if figs is not None:
        from app.collection.plans.design import figures_table

        print(figures_table(figs))
    write_json(args.json, {"robot": args.robot, "design": args.design, "targets": len(plan), "kinds": kinds,
                           "params": plan.params, "out": str(args.out),
                           **({"figures": {k: f.to_json() for k, f in figs.items()}} if figs else {})})
    return 0


def _plan_topup(args: argparse.Namespace, cell: Any, robot: Any, safety: Any, others: dict[str, Any]) -> int:
    """``plan --design optimal [--given TRAIN] --task TASK --budget K``: the K poses the task needs beyond TRAIN
    (without --given: from scratch, the task's whole calibration)."""
    from app.collection.plans.design import topup_plan
    from app.collection.runtime.sim import park_q
    from app.jobs.task import read_task
    from app.workflows.inputs import read_given

    missing = [o for o, v in (("--task", args.task), ("--budget", args.budget)) if v is None]
    if args.design != "optimal" or missing:
        raise CellCalError("a task-driven plan needs --design optimal --task TASK --budget POSES (and --given TRAIN to "
                           "top up a training recording)"
                           + (f"; missing {', '.join(missing)}" if missing else ""))
    if args.target != "identification" or args.cpa or args.validation:
        raise CellCalError("--for, --cpa and --validation do not apply to a top-up plan (--given, --task)")
    import numpy as np

    q_given = read_given(args.given, robot).q if args.given is not None else np.zeros((0, 6))
    q_task = read_task(args.task, args.robot, cell)
    top = topup_plan(args.robot, robot.model(), safety, others, q_given, q_task, args.budget, args.noise_mm,
                     args.seed, park_q(args.robot))
    top.plan.save(args.out)
    b, a = top.sigma_before_mm, top.sigma_after_mm
    print(f"{args.robot}: {len(top.plan)} top-up poses chosen from {top.n_candidates} safe candidates, checked safe "
          f"with the other arms parked -> {args.out}")
    print(f"predicted position error over the task (sigma, RMS of the error norm, over its configurations: mean, "
          f"10-90 % range, worst): before {b.mean():.3f} ({np.percentile(b, 10):.3f}-{np.percentile(b, 90):.3f}, "
          f"worst {b.max():.3f}) mm -> after {a.mean():.3f} ({np.percentile(a, 10):.3f}-{np.percentile(a, 90):.3f}, "
          f"worst {a.max():.3f}) mm")
    write_json(args.json, {"robot": args.robot, "design": "topup", "targets": len(top.plan),
                           "candidates": top.n_candidates, "params": top.plan.params, "out": str(args.out),
                           "predicted_sigma_mm": {
                               "before": {"mean": float(b.mean()), "max": float(b.max())},
                               "after": {"mean": float(a.mean()), "max": float(a.max())}}})
    return 0


def _optimal_anchors(args: argparse.Namespace, robot: Any, safety: Any, others: dict[str, Any], q_start: Any) -> Any:
    """``plan --design optimal``: the D-optimal clusters and their figures beside the paper's grid."""
    from app.collection.plans.design import DesignSpec, check_budget, optimal_plan
    from calibration.kinematics.parameterisation import MinimalParameterisation

    budget = args.budget if args.budget is not None else DEFAULT_BUDGET[args.target]
    check_budget(budget)
    spec = DesignSpec.for_rebase(budget, args.noise_mm, args.seed) if args.target == "rebase" else \
        DesignSpec(budget=budget, noise_mm=args.noise_mm, seed=args.seed)
    return optimal_plan(args.robot, MinimalParameterisation(robot.model(), fit_tool=True), safety, others, spec,
                        q_start)


def _check_grid_step(option: str, step_deg: float) -> None:
    """Refuse an anchor-grid step outside [0.5, 90] deg (the demo's ``--anchor-step`` range): 0 and NaN were
    refused naming the internal key ``q2_range_deg/steps`` and not the value, inf gave a one-row grid."""
    if not MIN_GRID_STEP_DEG <= step_deg <= MAX_GRID_STEP_DEG:
        raise CellCalError(f"{option} must be in [{MIN_GRID_STEP_DEG:g}, {MAX_GRID_STEP_DEG:g}] deg, got {step_deg:g}")


def cmd_select(args: argparse.Namespace) -> int:
    from app.collection.plans.design import check_budget, figures_table
    from app.workflows.inputs import read_recording_for
    from calibration.data.recording import write_recording
    from calibration.frames.policy import refuse_another_arms
    from calibration.frames.rebase_design import select_rebase_recording
    from calibration.identification.design import select_recording
    from calibration.kinematics.parameterisation import MinimalParameterisation

    if args.given is not None or args.task is not None or args.poses is not None:
        return _select_topup(args)
    if args.budget is None:
        raise CellCalError("select needs --budget CLUSTERS (clusters of --data to keep), or --given TRAIN --task TASK "
                           "--poses K (the poses of --data a task needs beyond TRAIN)")
    if args.keep_all or args.sigma_residual_mm is not None:
        raise CellCalError("--keep-all and --sigma-residual-mm belong to a top-up selection (--given, --task, --poses); "
                           "--budget chooses clusters of one recording")
    robot = cell_spec(args).robot(args.robot)
    rec = read_recording_for(args.data, robot)
    refuse_another_arms(robot.arm(), rec)  # another arm's clusters would be chosen by this arm's Jacobian
    n_clusters = len(set(rec.clusters().tolist()))
    check_budget(args.budget, n_clusters, unit="clusters")
    par = MinimalParameterisation(robot.model(), fit_tool=True)
    if args.target == "rebase":
        sel = select_rebase_recording(par, rec, args.budget, args.noise_mm, rebase_offsets=())
    else:
        sel = select_recording(par, rec, args.budget, args.noise_mm)
    write_recording(rec.subset(sel.rows), args.out)
    print(f"{args.robot}: {len(sel.clusters)} of {n_clusters} clusters ({len(sel.rows)} of {len(rec)} samples) "
          f"-> {args.out}")
    print(figures_table({"selected": sel.selected, "all clusters": sel.every}))
    write_json(args.json, {"robot": args.robot, "data": str(args.data), "out": str(args.out), "budget": args.budget,
                           "clusters": list(sel.clusters), "samples": int(len(sel.rows)),
                           "figures": {"selected": sel.selected.to_json(), "all": sel.every.to_json()}})
    return 0


def _select_topup(args: argparse.Namespace) -> int:
    """``select --given TRAIN --task TASK --poses K``: the K rows of --data (candidates) that most lower the predicted
    position variance over the task's configurations given TRAIN (:mod:`calibration.methods.topup`), of which only as
    many are kept as lower the global fit's predicted task error, its misfit included
    (:mod:`calibration.methods.topup_risk`; all K with ``--keep-all``); joint angles only."""
    import numpy as np

    from app.jobs.task import read_task
    from app.workflows.inputs import read_given, read_recording_for
    from calibration.data.recording import copy_rows
    from calibration.methods.topup import TopupPrior, choose, predicted_sigma
    from calibration.methods.topup_risk import RISK_PRIOR, fit_risk

    missing = [o for o, v in (("--given", args.given), ("--task", args.task), ("--poses", args.poses)) if v is None]
    if missing:
        raise CellCalError(f"a top-up selection needs --given TRAIN, --task TASK and --poses K; missing "
                           f"{', '.join(missing)}")
    if args.budget is not None or args.target != "identification":
        raise CellCalError("--budget and --for choose clusters of one recording; a top-up selection (--given, --task, "
                           "--poses) takes neither")
    cell = cell_spec(args)
    robot = cell.robot(args.robot)
    cands = read_recording_for(args.data, robot)
    given = read_given(args.given, robot)
    q_task = read_task(args.task, args.robot, cell)
    if not 1 <= args.poses <= len(cands):
        raise CellCalError(f"--poses must be in 1..{len(cands)} (the rows of {args.data}), got {args.poses}")
    prior = TopupPrior(noise_mm=args.noise_mm)
    res = choose(robot.model(), given.q, cands.q, q_task, args.poses, prior)
    risk_prior = TopupPrior(**{**RISK_PRIOR.__dict__, "noise_mm": args.noise_mm})
    risk = fit_risk(robot.model(), given.q, cands.q[list(res.order)], q_task, risk_prior)
    kept = args.poses if args.keep_all else risk.useful()
    rows = np.sort(np.asarray(res.order[:kept], dtype=int))
    residual, source = sigma_residual(args, robot, given)
    before = predicted_sigma(robot.model(), given.q, q_task, prior, residual_mm=residual)
    after = predicted_sigma(robot.model(), np.concatenate([given.q, cands.q[rows]]), q_task, prior,
                            residual_mm=residual)
    copy_rows(args.data, rows, args.out, cands)
    print(f"{args.robot}: {len(rows)} of {len(cands)} candidate poses -> {args.out}")
    _print_declined(args.poses, kept, risk.rms_mm)
    print(f"predicted position error of a global fit (pi) over the task's {len(q_task)} configurations (sigma, RMS of "
          f"the error norm): mean {before.mean():.3f} -> {after.mean():.3f} mm, worst {before.max():.3f} -> "
          f"{after.max():.3f} mm")
    write_json(args.json, {"robot": args.robot, "data": str(args.data), "given": str(args.given),
                           "task": str(args.task), "out": str(args.out), "poses": len(rows), "asked": args.poses,
                           "declined": args.poses - kept, "rows": rows.tolist(), "order": list(res.order[:kept]),
                           "predicted_sigma_mm": {"before": {"mean": float(before.mean()), "max": float(before.max())},
                                                  "after": {"mean": float(after.mean()), "max": float(after.max())},
                                                  "residual_mm": residual, "residual_from": source},
                           "risk_scales": {"param_sd_mm": risk_prior.param_sd_mm, "gp_scale_mm": risk_prior.gp_scale_mm,
                                           "length_rad": risk_prior.length_rad},
                           "predicted_fit_error_rms_mm": {"before": float(risk.rms_mm[0]),
                                                          "after": float(risk.rms_mm[kept]),
                                                          "each_count": risk.rms_mm.tolist()},
                           "criterion": "mean + mean of the worst 10 % of the predicted task position variance "
                                        "(calibration.methods.topup); poses kept while the global fit's predicted "
                                        "task error, misfit included, is lowest (calibration.methods.topup_risk)"})
    return 0


def _print_declined(asked: int, kept: int, rms_mm: Any) -> None:
    """One line when fewer poses are kept than asked: the global fit's predicted task error is lowest with fewer."""
    if kept == asked:
        return
    print(f"declined {asked - kept} of the {asked} poses asked: the global fit's predicted task error (RMS, its misfit "
          f"included) is lowest with {kept} ({rms_mm[kept]:.3f} mm; {rms_mm[asked]:.3f} mm with all {asked}): "
          + ("no candidate is predicted to reduce the task error (the candidates lie far from the task); "
             if kept == 0 else "")
          + "--keep-all keeps them all")


def _print_events(session: str) -> list[dict[str, Any]]:
    """Print why the arms were stopped in this session (every recorded event); returns them for --json."""
    from dataclasses import asdict

    from app.collection.session_store import SessionStore

    with SessionStore(session, lock=False) as store:
        events = store.events()
    if events:
        print(f"{len(events)} stop(s) recorded in {session}:")
    for e in events:
        print(f"  {e.line()}")
    return [asdict(e) for e in events]


def cmd_collect(args: argparse.Namespace) -> int:
    from app.cli.cell_options import confirm_motion, motion_config, open_runtime, safety_for
    from app.collection.collect import SessionAborted, collect_arm
    from app.collection.plans.reader import read_arm_plan
    from app.collection.session_store import SessionStore, require_session
    from app.workflows.inputs import load_model_for
    from calibration.models import ConstantModel

    cell = cell_spec(args)
    cell.robot(args.robot)
    runtime = open_runtime(cell, args, robots=(args.robot,))  # a real cell's devices and registration: checked now
    if args.resume:
        require_session(args.session, args.robot)  # refused at once when there is none or another process holds it
    elif args.retry_skipped:
        raise CellCalError("--retry-skipped applies to --resume only (a new session has nothing skipped)")
    elif not args.plan:
        raise CellCalError("a new session needs --plan PLAN (or --resume an existing one)")
    elif SessionStore.exists(args.session):
        raise CellCalError(f"{args.session} already holds a session; pass --resume or choose a new folder")
    elif Path(args.session).exists() and not Path(args.session).is_dir():
        raise CellCalError(f"{args.session}: --session is a file; a session is a folder: choose a new folder")
    plan = read_arm_plan(args.plan, args.robot) if args.plan else None
    config, safety = motion_config(cell, args), safety_for(cell, args)
    robot = cell.robot(args.robot)
    model = (load_model_for(args.model, robot) if args.model else  # the -v lines' residuals
             ConstantModel(robot.name, "nominal", robot.model(), 0, {}))
    with runtime as rt:
        if args.dry_run:
            return _dry_run(args, rt, safety, plan, config)
        confirm_motion(args, f"{args.robot} will visit the targets of {args.plan or args.session} at "
                             f"{config.speed_fraction:g} of full speed")
        try:
            result = collect_arm(rt, safety, args.robot, plan, Path(args.session), config,
                                 resume=args.resume, retry_skipped=args.retry_skipped, progress=show_progress(args),
                                 model=model, model_name=args.model or f"the nominal {args.robot}")
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
                            "new": result.n_new, "retried": result.n_retried, "complete": result.complete,
                            "unmeasured": result.unmeasured, "seconds": result.elapsed_s,
                            "mocap_frames_received": frames, "events": events, "sim": bool(args.sim)})
    if result.unmeasured and not args.accept_skipped:  # it ended exit 0 with targets never measured again
        raise CellCalError(f"{args.robot}: {result.unmeasured} of {result.n_targets} targets not measured; "
                           f"cellcal collect --robot {args.robot} --session {args.session} --resume measures those "
                           "skipped for a transient reason again (add --retry-skipped for every skipped one), "
                           "or pass --accept-skipped to accept the session as it is")
    return 0


def _dry_run(args: argparse.Namespace, rt: Cell, safety: Any, plan: Any, config: Any) -> int:
    """Check the whole plan from where the arm stands against the other arms' live poses; print it; no motion."""
    from app.collection.dry_run import summarize_plan
    from app.collection.motion import live_poses, read_q
    from app.collection.plans.collection import Plan
    from app.collection.session_store import SessionStore

    if plan is None:
        with SessionStore(args.session) as store:  # what the resume would measure: the same targets
            plan = store.plan()
            done = store.done() - store.retriable(lasting_too=getattr(args, "retry_skipped", False))
        if len(done) >= len(plan.targets):  # summarize_plan said 'plan: expected targets of one robot, got no target'
            print(f"dry run, no motion: every one of the {len(plan.targets)} targets of {args.session} is measured "
                  "or skipped; nothing left to collect")
            write_json(args.json, {"robot": args.robot, "dry_run": True, "targets": 0})
            return 0
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
    from app.collection.collect import export
    from app.collection.plans.collection import KINDS

    kinds = None
    if Path(args.out).suffix.lower() != ".csv":  # export-targets refuses an unknown suffix too
        raise CellCalError(f"--out {args.out}: a recording is a CSV file (.csv); got {Path(args.out).suffix or 'no'} "
                           "suffix")
    if args.kinds is not None:  # --kinds "" exported every kind
        kinds = [k.strip() for k in args.kinds.split(",") if k.strip()]
        bad = [k for k in kinds if k not in KINDS]
        if bad or not kinds:
            raise CellCalError(f"unknown target kind {bad[0] if bad else args.kinds!r}; valid: {', '.join(KINDS)}")
    from app.collection.session_store import SessionStore

    with SessionStore(args.session, lock=False, purpose="export") as store:  # reading: allowed while a collector runs
        if args.robot:
            store.check_robot(args.robot)
        robots = store.robots()
    n = export(args.session, args.out, kinds)  # staged with the JSON (app.cli.commands.STAGED_COMMANDS)
    print(f"{n} samples of {', '.join(robots)} -> {args.out}")
    write_json(args.json, {"session": str(args.session), "robot": ", ".join(robots), "samples": n, "kinds": kinds,
                           "out": str(args.out)})
    return 0


def cmd_recalibrate(args: argparse.Namespace) -> int:
    """Parse, open the runtime, check the inputs and run :func:`app.workflows.recalibrate.recalibrate`, print,
    write JSON."""
    from app.cli.cell_options import open_runtime
    from app.workflows.recalibrate import checked_inputs, recalibrate, write_report

    cell = cell_spec(args)
    robot = cell.robot(args.robot)
    tolerance = tolerance_from_args(args)
    runtime = open_runtime(cell, args, robots=(args.robot,))  # a real cell's devices and registration: checked now
    inputs = checked_inputs(robot, args.model_dir, args.plan, args.session, args.validation, args.method, args.add,
                            validation_seed=args.validation_seed, rebase=args.rebase, add_weight=args.add_weight,
                            tolerance=tolerance, dry_run=args.dry_run, report=args.report,
                            command=command_line(args) if args.report else "")
    result = recalibrate(cell, runtime, inputs, _recalibration_hooks(args, cell))
    if result.decision is None:  # the dry run printed and wrote its own
        return result.exit_code
    decision = result.decision
    if decision.refused:
        write_json(args.json, decision.to_json())
        raise CellCalError(decision.summary())
    print(decision.summary())
    print(f"model in service: {decision.current_path}" + (f"; previous one archived as {decision.archived}"
                                                           if decision.archived else ""))
    write_json(args.json, result.to_json())
    if args.report:
        print(f"report: {write_report(result, inputs)}")
    return 0


def _recalibration_hooks(args: argparse.Namespace, cell: Any) -> Any:
    """The workflow's hooks: stdout/stderr lines, the operator's confirmation, the Ctrl-C line on ``args``."""
    from app.cli.cell_options import confirm_motion, motion_config, safety_for
    from app.workflows.recalibrate import RecalibrationHooks

    return RecalibrationHooks(
        say=print, warn=lambda line: print(line, file=sys.stderr),
        confirm=lambda summary: confirm_motion(args, summary),
        stop_hint=lambda hint: setattr(args, "stop_hint", hint),
        dry_run=lambda rt, safety, plan, config: _dry_run(args, rt, safety, plan, config),
        motion=lambda: (motion_config(cell, args), safety_for(cell, args)),
        progress=show_progress(args), epoch_progress=epoch_bar(args))


def cmd_demo(args: argparse.Namespace) -> int:
    from app.cli.cell_options import checked_time_scale
    from app.collection.runtime.sim import SimCellOptions
    from app.workflows.demo import DemoConfig, run_demo, stop_note, summary_table

    if args.anchor_step is not None:
        _check_grid_step("--anchor-step", args.anchor_step)
    if args.validation < 1:
        raise CellCalError(f"--validation must be at least 1, got {args.validation}")
    config = DemoConfig(full=args.full, anchor_step_deg=args.anchor_step, seed=args.seed, n_validation=args.validation,
                        methods=_demo_methods(args.methods),
                        sim=SimCellOptions(time_scale=checked_time_scale(args.time_scale)),
                        progress=show_progress(args),
                        tolerance=tolerance_from_args(args), report_dir=Path(args.report) if args.report else None)
    cell = cell_spec(args)
    try:
        result = run_demo(args.out, cell, config)
    except KeyboardInterrupt:  # what the stop line says (app.cli.commands.main): what was left, what a re-run does
        args.stop_hint = stop_note(Path(args.out), tuple(cell.robots))
        raise
    print(summary_table(result.summary))
    print(f"demo finished in {result.seconds:.1f} s; {result.summary['mocap_frames_received']} mocap frames "
          f"received over zenoh")
    print(f"summary: {result.out_dir / 'summary.json'}")
    print(f"report: {result.report}")
    write_json(args.json, {**result.summary, "summary": str(result.out_dir / "summary.json"),
                           "report": str(result.report)})
    return 0


def _demo_methods(text: str | None) -> tuple[str, ...] | None:
    """``--methods`` of the demo: None (every method) or the parsed comma-separated list."""
    if not text:
        return None
    from app.workflows.compare import parse_methods

    return tuple(parse_methods(text))


def cmd_init_cell(args: argparse.Namespace) -> int:
    from app.workflows.init_cell import init_cell

    written = init_cell(args.folder)
    print(f"cell folder {args.folder}: {', '.join(written.files)}")
    print(f"edit {written.cell} for your cell (its header and each file's say the units), then e.g.\n"
          f"  cellcal --cell {written.cell} plan --robot R1 --out r1_plan.json")
    write_json(args.json, {"folder": str(args.folder), "cell": str(written.cell), "files": list(written.files)})
    return 0


def cmd_import_motive(args: argparse.Namespace) -> int:
    from app.collection.motive_import import import_motive
    from calibration.data.recording import check_quaternion_order, write_recording

    robot = cell_spec(args).robot(args.robot)
    rigid_body = args.rigid_body or robot.tool.rigid_body
    rec = import_motive(args.motive, args.joints, rigid_body, args.min_frames)
    _check_joint_limits(args.joints, rec.q, robot)
    check_quaternion_order(rec, robot.model(), "Motive's X, Y, Z, W (converted to qw, qx, qy, qz)")
    write_recording(rec, args.out)
    frames = rec.extra["frames"]
    print(f"{len(rec)} poses of {args.robot} ({rigid_body!r}, {int(frames.min())}-{int(frames.max())} frames each) "
          f"-> {args.out}")
    write_json(args.json, {"robot": args.robot, "rigid_body": rigid_body, "poses": len(rec), "out": str(args.out),
                           "frames_min": int(frames.min()), "frames_max": int(frames.max())})
    return 0


def _check_joint_limits(path: str, q: Any, robot: Any) -> None:
    """DataError naming the row and joint of the first angle outside ``robot``'s limits."""
    import numpy as np

    from calibration.errors import DataError

    bad = np.argwhere((q < robot.robot.lower_rad) | (q > robot.robot.upper_rad))
    if bad.size:
        i, j = (int(v) for v in bad[0])
        raise DataError(path, i + 2, f"q{j + 1}", f"{np.degrees(q[i, j]):.2f} deg is outside {robot.name}'s joint "
                                                  f"{j + 1} limits [{np.degrees(robot.robot.lower_rad[j]):g}, "
                                                  f"{np.degrees(robot.robot.upper_rad[j]):g}] deg")


def add_cell_parsers(add: Callable[..., argparse.ArgumentParser]) -> None:
    """Register the cell-workflow subcommands."""
    _add_init_import_parsers(add)
    _add_plan_parser(add)
    _add_select_parser(add)
    _add_collect_export_parsers(add)
    _add_recalibrate_parser(add)
    _add_demo_parser(add)


def _add_init_import_parsers(add: Callable[..., argparse.ArgumentParser]) -> None:
    """init-cell, import-motive."""
    p = add("init-cell", cmd_init_cell, "write an editable cell folder (cell.yaml with its devices, robots/, tools/) "
                                        "that loads as written; never overwrites", reads_cell=False)
    p.add_argument("folder", metavar="DIR", help="the folder to write (new or without these files): DIR/cell.yaml, "
                                                 "DIR/robots/*.yaml, DIR/tools/*.yaml; use it as cellcal --cell "
                                                 "DIR/cell.yaml ...")
    p.add_argument("--json", help="write the files written as JSON")

    p = add("import-motive", cmd_import_motive, "make a recording from Motive's CSV export of a take and the joint "
                                                "angles of its poses")
    p.add_argument("--robot", required=True, help="robot name in the cell (R1, R2): its tool YAML names the rigid "
                                                  "body, its limits check the joints")
    p.add_argument("--motive", required=True, metavar="TAKE.csv",
                   help="Motive's CSV export with Header information on and Rotation Type Quaternion (X, Y, Z, W: "
                        "scalar last; positions in the header's Length Units, converted to mm)")
    p.add_argument("--joints", required=True, metavar="JOINTS.csv",
                   help="one row per pose: q1..q6 [rad] or q1_deg..q6_deg [deg], and t_start_s, t_end_s: its dwell "
                        "window in the take's Time (Seconds)")
    p.add_argument("--rigid-body", help="the Motive rigid-body name (default: the robot's tool YAML rigid_body)")
    p.add_argument("--min-frames", type=non_negative_int, default=1,
                   help="refuse a pose whose window holds fewer tracked frames")
    p.add_argument("--out", required=True, help="recording CSV to write (q1..q6, x, y, z [mm], qw, qx, qy, qz, "
                                                "frames, t)")
    p.add_argument("--json", help="write the pose count and frames per pose as JSON")


def _add_plan_parser(add: Callable[..., argparse.ArgumentParser]) -> None:
    """plan."""
    p = add("plan", cmd_plan, "make a collection plan for one arm (the optimal design or the paper's grid, CPA sweeps, "
                                "validation poses)")
    p.add_argument("--robot", required=True, help="robot name in the cell (R1, R2)")
    p.add_argument("--out", required=True, help="plan file (JSON)")
    p.add_argument("--q2-step", type=float,
                   help="--design grid: anchor grid q2 step [deg], 0.5 to 90 (default 5: the paper's design)")
    p.add_argument("--q3-step", type=float, help="--design grid: anchor grid q3 step [deg], 0.5 to 90 (default 5)")
    p.add_argument("--cpa", action="store_true", help="add single-joint sweeps (needed by the cpa method)")
    p.add_argument("--validation", type=validation_count, default=0, help="random validation poses to add (the test set)")
    p.add_argument("--seed", type=non_negative_int, default=0, help="seed of the validation poses (and of the optimal design's "
                                                        "candidates)")
    p.add_argument("--design", choices=("grid", "optimal"), default="optimal",
                   help="optimal: D-optimal clusters that move joints 1, 4, 5, 6 widely and spread over (q2, q3), "
                        "within the limits and the safety model (on the packaged R1 its 196 poses see all 27 "
                        "parameter directions); grid: the paper's anchor grid (1736 poses at 5 deg, sees 11 of 27)")
    p.add_argument("--budget", type=int, metavar="POSES",
                   help="--design optimal: the number of POSES to measure (not clusters, as select --budget counts), "
                        "taken as whole clusters of 7 (rounded down; at least 21, 3 clusters, and enough clusters "
                        "to see every identifiable direction: an identification design needs more, about 49 on "
                        "the packaged R1); default 196 (28 clusters, about a ninth of the paper's grid), 21 with "
                        "--for rebase")
    p.add_argument("--for", dest="target", choices=("identification", "rebase"), default="identification",
                   help="--design optimal: what the poses are for: identifying the geometry or rebasing a "
                        "fitted model onto a new day (its frames and the joint offsets of joints 4 and 5; "
                        "cellcal rebase --offsets)")
    p.add_argument("--given", metavar="TRAIN", help="--design optimal top-up: the training recording already "
                                                    "measured; --budget POSES are then chosen for --task")
    p.add_argument("--task", help="--design optimal top-up: the configurations the cell will run: a joints CSV "
                                  "(q1..q6 [rad]), a dual plan (.json: this robot's waypoints) or a JBI job (.jbi)")
    p.add_argument("--noise-mm", type=positive_float, default=0.05,
                   help="measurement noise assumed for the predicted parameter uncertainty [mm]")
    p.add_argument("--json", help="write the plan summary (target counts per kind, and the design figures: each "
                                  "parameter's sigma in the unit sigma_units gives it) as JSON")


def _add_select_parser(add: Callable[..., argparse.ArgumentParser]) -> None:
    """select."""
    p = add("select", cmd_select, "choose the most informative clusters of a recording (the plan --design optimal "
                                  "criterion), or the poses of a candidate recording a task needs beyond a training "
                                  "recording (--given, --task, --poses), and write them as a recording subset")
    p.add_argument("--robot", required=True, help="robot name in the cell (R1, R2)")
    p.add_argument("--data", required=True, help="training recording CSV or Welding_Motoman folder")
    p.add_argument("--budget", type=int, metavar="CLUSTERS",
                   help="the number of CLUSTERS of the recording to keep (not poses, as plan --budget counts; a "
                        "cluster is usually 7 poses): at least 3, at most the recording's; no default (required "
                        "unless --given/--task/--poses choose a top-up)")
    p.add_argument("--given", metavar="TRAIN", help="top-up: the training recording already measured (its joint "
                                                    "angles); --data is then the candidate poses (no clusters needed)")
    p.add_argument("--task", help="top-up: the configurations the cell will run: a joints CSV (q1..q6 [rad]), a dual "
                                  "plan (.json: this robot's waypoints) or a JBI job (.jbi: its PULSE positions)")
    p.add_argument("--poses", type=int, metavar="K", help="top-up: how many candidate poses to choose at most (fewer "
                                                          "when more are predicted to make the global fit worse "
                                                          "on the task)")
    p.add_argument("--sigma-residual-mm", type=positive_float, metavar="MM", help=SIGMA_RESIDUAL_HELP)
    p.add_argument("--keep-all", action="store_true",
                   help="top-up: keep all K poses even where the global fit is predicted to do worse on the task "
                        "with them (the candidates far from the task)")
    p.add_argument("--out", required=True, help="the subset recording CSV (top-up: the chosen rows of --data as they "
                                                "are there)")
    p.add_argument("--for", dest="target", choices=("identification", "rebase"), default="identification",
                   help="what the clusters are for: identifying the geometry or rebasing a fitted model "
                        "(D-optimal on the 12 frame directions cellcal rebase fits, no spread term)")
    p.add_argument("--noise-mm", type=positive_float, default=0.05,
                   help="measurement noise assumed for the predicted parameter uncertainty [mm]")
    p.add_argument("--json", help="write the chosen clusters and the design figures (each parameter's sigma in the unit "
                                  "sigma_units gives it: rad for a rotation or offset, not the table's mdeg) as JSON")


def _add_collect_export_parsers(add: Callable[..., argparse.ArgumentParser]) -> None:
    """collect, export."""
    from app.cli.cell_options import add_motion_options

    p = add("collect", cmd_collect, "guided collection session of one arm (durable, resumable)")
    p.add_argument("--robot", required=True, help="robot name in the cell (R1, R2)")
    p.add_argument("--plan", help="plan file (cellcal plan); optional with --resume")
    p.add_argument("--session", required=True, help="session folder (created; holds session.sqlite)")
    p.add_argument("--resume", action="store_true",
                   help="continue the session: the targets not yet recorded and those skipped for a transient reason "
                        "(a timeout, lost mocap, no fresh controller status) are measured")
    p.add_argument("--retry-skipped", action="store_true",
                   help="with --resume: also measure again the targets skipped for a lasting reason (a sample the "
                        "session refused, a joint readback outside the limits)")
    p.add_argument("--accept-skipped", action="store_true",
                   help="exit 0 even when targets stay skipped (without it a run that ends with targets not measured "
                        "says so and exits 2)")
    p.add_argument("--json", help="write the session outcome as JSON")
    p.add_argument("--model", help="model file in use for this arm: with -v each measured target's line gives its "
                                   "residual against it (default: the cell's nominal arm)")
    add_motion_options(p)
    p = add("export", cmd_export, "write a session's measured samples as a recording CSV", reads_cell=False)
    p.add_argument("--session", required=True, help="session folder")
    p.add_argument("--out", required=True, help="recording CSV")
    p.add_argument("--kinds", help="comma-separated target kinds to include (anchor, perturb, cpa, validation); all "
                                   "by default")
    p.add_argument("--robot", help="refuse the session unless it was collected on this robot (R1, R2)")
    p.add_argument("--json", help="write the sample count as JSON")


def _add_recalibrate_parser(add: Callable[..., argparse.ArgumentParser]) -> None:
    """recalibrate (its parser only; the command is :func:`cmd_recalibrate`)."""
    from app.cli.cell_options import add_motion_options
    from calibration.method_names import METHODS

    p = add("recalibrate", cmd_recalibrate, "fit a new model, compare it with the one in service on fresh validation "
                                            "poses, replace it only if better")
    p.add_argument("--robot", required=True, help="robot name in the cell (R1, R2)")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--session", help="reuse the training samples of this session")
    src.add_argument("--plan", help="collect a new training session from this plan")
    p.add_argument("--model-dir", required=True, help="folder of the model in service (current.yaml, previous/)")
    p.add_argument("--method", default="pi+fbf13", choices=METHODS,
                   help="the method of the new model (default pi+fbf13)")
    p.add_argument("--rebase", action="store_true", help="refit only the base and tool-marker frames of the model in "
                                                         "service on the training poses (a few clusters of a new day) "
                                                         "instead of fitting a new model (--method is not used)")
    p.add_argument("--validation", type=validation_count, default=30, help="fresh validation poses to measure")
    add_topup_options(p)
    p.add_argument("--validation-seed", type=non_negative_int, help="seed of the validation poses (default: from the clock)")
    p.add_argument("--json", help="write the decision with both figures as JSON")
    add_report_options(p, "candidate and model in service on the validation poses",
                       "; with no usable model in service, a candidate whose RMS on the validation poses is above it "
                       "is refused (exit 2, filed under rejected/)")
    add_motion_options(p)


def _add_demo_parser(add: Callable[..., argparse.ArgumentParser]) -> None:
    """demo."""
    p = add("demo", cmd_demo, "the main job on the simulated cell: collect both arms over zenoh, fit, evaluate, "
                              "report")
    p.add_argument("--out", default="demo_out", help="output folder (an earlier demo there is replaced)")
    p.add_argument("--full", action="store_true", help="the paper's 248-anchor design (5 deg steps; about twice the CPU time)")
    p.add_argument("--seed", type=non_negative_int, default=0, help="seed of the planted errors, the noise and the validation poses")
    p.add_argument("--anchor-step", type=float, help="anchor grid q2/q3 step [deg] (default 10, 5 with --full; a "
                                                     "coarse grid, e.g. 40, makes a short demo)")
    p.add_argument("--validation", type=validation_count, default=50, help="random validation poses per arm (the test set)")
    p.add_argument("--methods", help="comma-separated methods to fit (default: all)")
    p.add_argument("--time-scale", type=float, default=20.0,  # SimCellOptions.time_scale, as --sim commands
                   help="simulated seconds per real second of the collections (default %(default)g); the demo's "
                        "clock is stepped, so its recordings and figures do not depend on it, only its duration")
    p.add_argument("--json", help="write the summary (per arm and method: test statistics) as JSON")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    add_report_options(p, "per arm: every method's errors, tables and plots (default DIR: --out)")
