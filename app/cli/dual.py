"""``cellcal`` subcommands of the dual-robot spray task: plan-dual, validate-dual, preview, export-targets."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from typing import Any

from app.cli.cell_options import add_motion_options
from app.cli.common import cell_spec, show_progress, write_json
from calibration.errors import CellCalError

#: export-targets --jbi's joint speed VJ [% of maximum] when --speed is not given.
DEFAULT_JOB_SPEED = 10.0


def _model_pair(spec: str | None, where: str, cell: Any) -> dict[str, Any]:
    """``R1=a.yaml,R2=b.yaml`` -> {robot: model}; robots not named stay nominal (absent from the dict).

    Each file must record the arm it is given for and hold that arm's geometry (robot YAML).
    """
    from app.workflows.inputs import load_model_for
    from calibration.errors import DataError

    models: dict[str, Any] = {}
    for item in filter(None, (spec or "").split(",")):
        robot, sep, path = item.partition("=")
        if not sep or robot.strip() not in ("R1", "R2") or not path.strip():
            raise DataError(where, None, None, f"bad model entry {item!r}; expected R1=FILE,R2=FILE")
        if robot.strip() in models:  # the last one was used without a word
            raise DataError(where, None, None, f"{robot.strip()} is given twice ({spec!r}); give one model per robot")
        models[robot.strip()] = load_model_for(path.strip(), cell.robot(robot.strip()))
    return models


def cmd_plan_dual(args: argparse.Namespace) -> int:
    """Read the models, run :func:`app.dual.plan_dual.plan_dual` (its checks included), print, write JSON."""
    from app.dual.plan_dual import PlanDualInputs, plan_dual

    cell = cell_spec(args)
    models = _model_pair(args.models, "--models", cell)
    result = plan_dual(cell, PlanDualInputs(args.path, args.relative_pose, models, args.compile, args.out, args.json,
                                            show_progress(args)))
    write_json(args.json, result.to_json())
    print(result.line())
    return 0


def _model_sets(specs: list[str] | None, cell: Any) -> dict[str, dict[str, Any]]:
    """``[LABEL:]R1=a,R2=b`` per entry -> {label: {R1, R2}} (label: the models' method by default)."""
    from calibration.models import ConstantModel

    out: dict[str, dict[str, Any]] = {}
    for spec in specs or []:
        label, sep, rest = spec.partition(":")
        if not sep or "=" in label:
            label, rest = "", spec
        pair = _model_pair(rest, "--models", cell)
        if not label:
            label = "/".join(sorted({m.method for m in pair.values()})) or "nominal"
        for robot in ("R1", "R2"):
            pair.setdefault(robot, ConstantModel(robot, "nominal", cell.robot(robot).model()))
        out[label] = pair
    return out


def cmd_validate_dual(args: argparse.Namespace) -> int:
    from calibration.errors import CellCalError, ModelError

    cell = cell_spec(args)
    if args.sim:
        from app.dual.validate import run_sim_validation

        if args.configurations < 2:
            raise ModelError(f"--configurations must be >= 2, got {args.configurations}")
        given = [o for o, v in (("--time-scale", args.time_scale), ("--speed", args.speed)) if v is not None]
        if given:  # both were silently ignored: the simulated contact moves are not timed
            raise CellCalError(f"{' and '.join(given)}: not used by validate-dual --sim, whose simulated contact "
                               f"moves have no clock; leave {'it' if len(given) == 1 else 'them'} out")
        if args.plan_models:  # read only with --plan on the real cell: it was silently ignored
            raise CellCalError("--plan-models: not used by validate-dual --sim, which plans its own contact "
                               "configurations; give it with --plan on the real cell")
        methods = tuple(m.strip() for m in args.methods.split(",") if m.strip()) if args.methods else None
        model_sets = _model_sets(args.models, cell) or None
        if args.dry_run:  # it ran the whole simulated validation, fits included, as if --dry-run were not given
            from app.dual.sim import SIM_METHODS, check_methods

            sets = list(model_sets) if model_sets else list(methods or SIM_METHODS)
            check_methods(() if model_sets else tuple(sets))
            print(f"dry run, no motion: the simulated cell's {args.configurations} contact configurations, "
                  f"{len(sets)} model set(s) to score ({', '.join(sets)}); nothing fitted or measured")
            write_json(args.json, {"dry_run": True, "configurations": args.configurations, "model_sets": sets})
            return 0
        from dataclasses import replace

        from app.dual.sim import VALIDATION_CELL

        options = VALIDATION_CELL if args.seed is None else replace(VALIDATION_CELL, seed=args.seed)
        result = run_sim_validation(cell, args.configurations, model_sets, methods, options)
    else:
        result = _validate_real(args, cell)
        if result is None:
            return 0
    print(result.table())
    write_json(args.json, result.to_json())
    return 0


def _validate_real(args: argparse.Namespace, cell: Any) -> Any:
    """The contact validation on the real arms and probe; None after a dry run."""
    import numpy as np

    from app.cli.cell_options import confirm_motion, open_runtime, safety_for, speed_fraction
    from app.collection.motion import live_poses
    from app.dual.validate import check_contact_sequence
    from app.dual.validate_real import contact_configurations, open_probe, run_real_validation
    from calibration.errors import ModelError

    if not args.plan:
        raise ModelError("the real-cell validation needs --plan DUAL_PLAN (from plan-dual) with the contact "
                         "configurations; --sim plans its own")
    runtime = open_runtime(cell, args, robots=())  # the arms only: contacts come from the CAN probe
    probe = open_probe(cell)
    q_plan, p_contact = contact_configurations(args.plan, cell, _model_pair(args.plan_models, "--plan-models", cell))
    model_sets, speed, safety = _model_sets(args.models, cell), speed_fraction(cell, args), safety_for(cell, args)
    with runtime as rt:
        if args.dry_run:
            now = live_poses(rt.drivers)
            check_contact_sequence(safety, q_plan, np.concatenate([now["R1"], now["R2"]]))
            print(f"dry run, no motion: {len(q_plan)} contact configurations of {args.plan}, every move checked "
                  f"safe from where the arms stand; {len(model_sets)} model set(s) to score besides nominal")
            write_json(args.json, {"dry_run": True, "configurations": len(q_plan)})
            return None
        confirm_motion(args, f"R1 and R2 will visit {len(q_plan)} contact configurations at {speed:g} of full "
                             "speed, one arm at a time")
        with probe:
            return run_real_validation(cell, rt, safety, q_plan, p_contact, model_sets, probe, speed_fraction=speed)


def cmd_preview(args: argparse.Namespace) -> int:
    from app.dual.preview.page import preview
    from calibration.errors import ModelError

    if not args.html and not args.serve:
        raise ModelError("preview needs --html OUT (a static page) or --serve (a live viewer)")
    cell = cell_spec(args)
    result = preview(cell, args.plan, html_out=args.html, serve=args.serve,
                     plan_models=_model_pair(args.models, "--models", cell))
    write_json(args.json, result.summary())
    if result.html_path:
        print(f"{result.n_frames} frames -> {result.html_path}")
    for d in result.defects:  # drawn in red with the reason in the readout; said here too
        print(f"UNSAFE {d}", file=sys.stderr)
    if result.url:
        print(f"live viewer at {result.url}; Ctrl-C (SIGINT) or SIGTERM stops it", flush=True)
        serve_until_stopped()
    return 0


def serve_until_stopped() -> None:
    """Wait until SIGINT (Ctrl-C) or SIGTERM. Waiting for Enter returned at once without a terminal (stdin at end
    of file under nohup, a service or a test), taking the viewer down as soon as it was up."""
    import signal
    import threading

    stop = threading.Event()
    previous = signal.signal(signal.SIGTERM, lambda *_: stop.set())
    try:
        while not stop.wait(0.5):
            pass
    except KeyboardInterrupt:
        pass
    finally:
        signal.signal(signal.SIGTERM, previous)


def cmd_export_targets(args: argparse.Namespace) -> int:
    from app.dual.export_targets import checked_rows, write_targets
    from app.jobs.plan_job import job_bytes
    from calibration.data.files import atomic_write_bytes

    cell = cell_spec(args)
    rows = checked_rows(args.plan, cell, args.frame, args.skip_failed, models=_model_pair(args.models, "--models", cell))
    if args.speed is not None and args.jbi is None:
        raise CellCalError("--speed sets the speed of the JBI job; it needs --jbi NAME.JBI (the targets file has no "
                           "speed)")
    speed = DEFAULT_JOB_SPEED if args.speed is None else args.speed
    job = None if args.jbi is None else job_bytes(rows, args.jbi, speed)  # before writing: a bad name, nothing
    write_targets(rows, args.out, args.frame)  # refuses an unknown file type before writing
    if job is not None:
        atomic_write_bytes(args.jbi, job)
    n = len(rows)
    print(f"{n} targets ({args.frame} frame) -> {args.out}")
    if args.jbi:
        print(f"{n // 2} coordinated joint moves (R1 = RB1, R2 = RB2, pulses, VJ={speed:.2f}) -> {args.jbi}")
    write_json(args.json, {"plan": str(args.plan), "targets": n, "frame": args.frame, "out": str(args.out),
                           "jbi": args.jbi})
    return 0


PLAN_MODELS_HELP = ("R1=FILE,R2=FILE: the models the plan was solved with (plan-dual --models); its relative pose is "
                    "recomputed from them (a robot left out: its nominal model)")


def add_dual_parsers(add: Callable[..., argparse.ArgumentParser]) -> None:
    p = add("plan-dual", cmd_plan_dual, "plan both arms holding a relative tool pose along a workpiece path")
    p.add_argument("--models", help="R1=FILE,R2=FILE (a robot left out uses its nominal model)")
    p.add_argument("--relative-pose", help="gun pose in the workpiece frame: a file (JSON {p_mm, quat} or CSV) or "
                                           "inline x,y,z,qw,qx,qy,qz [mm]; default: the reference pose")
    p.add_argument("--path", default="sweep:200", help="CSV/JSON of workpiece poses in the cell frame "
                                                       "(x,y,z,qw,qx,qy,qz [mm]) or sweep:N (default sweep:200)")
    p.add_argument("--out", help="write the plan file (JSON)")
    p.add_argument("--json", help="write a summary as JSON")
    p.add_argument("--compile", choices=("auto", "wait", "off"), default="auto",
                   help="auto: the compiled planner from the cache, else interpreted while gcc builds it alongside "
                        "(used once built); wait: build it first; off: interpreted (default auto)")
    p.add_argument("--no-compile", dest="compile", action="store_const", const="off", help="same as --compile off")
    p = add("validate-dual", cmd_validate_dual, "contact validation of model sets (the paper's dual-robot check)")
    p.add_argument("--plan", help="dual plan (plan-dual --out) whose waypoints are the contact configurations; "
                                  "needed on the real cell")
    p.add_argument("--plan-models", help=PLAN_MODELS_HELP.replace("R1=FILE,R2=FILE: ", "R1=FILE,R2=FILE with --plan: "))
    p.add_argument("--configurations", type=int, default=20, help="contact configurations with --sim, inward to "
                                                                  "outstretched")
    p.add_argument("--models", action="append", help="[LABEL:]R1=FILE,R2=FILE, repeatable; with --sim and none, "
                                                     "the model sets are fitted on twin data")
    p.add_argument("--methods", help="model sets to fit with --sim (default nominal,cpa,fbf13,ae,pi; pi is the "
                                     "physics-informed model)")  # the default: app.dual.sim.SIM_METHODS
    p.add_argument("--json", help="write the statistics as JSON")
    add_motion_options(p)
    seed, scale, speed = (p._option_string_actions[o] for o in ("--seed", "--time-scale", "--speed"))
    # --sim's cell is app.dual.sim.VALIDATION_CELL, and its contact moves have no clock to scale
    seed.default, seed.help = None, ("seed of the simulated cell (its planted errors and calibration data); --sim "
                                     "only (default 7, the validation cell's)")
    scale.default, scale.help = None, "not used here: the simulated validation (--sim) has no clock"
    speed.help = f"{speed.help}; the real cell only (the simulated validation has no clock)"
    p = add("preview", cmd_preview, "meshcat preview of a plan (static HTML page or live viewer)")
    p.add_argument("--plan", required=True, help="plan file (dual or collection)")
    p.add_argument("--html", help="write a self-contained HTML page")
    p.add_argument("--serve", action="store_true", help="start a live meshcat viewer on 127.0.0.1 and serve it until Ctrl-C (SIGINT) or SIGTERM")
    p.add_argument("--json", help="write a summary as JSON (waypoints, largest residual, files, joint-limit check)")
    p.add_argument("--models", help=PLAN_MODELS_HELP)
    p = add("export-targets", cmd_export_targets, "controller targets (rad, pulses, poses) from a dual plan")
    p.add_argument("--plan", required=True, help="plan file written by plan-dual")
    p.add_argument("--out", required=True, help="targets file (.csv or .json)")
    p.add_argument("--frame", choices=("flange", "tool"), default="flange", help="pose frame of the targets")
    p.add_argument("--skip-failed", action="store_true", help="leave out unsolved waypoints instead of refusing")
    p.add_argument("--models", help=PLAN_MODELS_HELP)
    p.add_argument("--jbi", metavar="NAME.JBI",
                   help="also write an INFORM job: one two-group job (GROUP1 RB1 = R1, GROUP2 RB2 = R2), one "
                        "coordinated MOVJ line per waypoint so both arms reach it together, positions in pulses "
                        "(pulse = pulse_zero + pulse_sign * q_deg * pulses_per_deg, from the robot YAML); the job "
                        "is named after the file")
    p.add_argument("--speed", type=float, default=None,
                   help=f"the job's joint speed VJ [%% of maximum] (--jbi only; default {DEFAULT_JOB_SPEED:g})")
    p.add_argument("--json", help="write the target count and frame as JSON")
