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
        target = Path(path)
        target.parent.mkdir(parents=True, exist_ok=True)
        tmp = target.with_name(f".{target.name}.tmp")
        tmp.write_text(json.dumps(data, indent=1), encoding="utf-8")
        tmp.replace(target)


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
