"""The ``cellcal`` command line: one function per subcommand.

Exit codes: 0 success, 2 bad input (one clear line on stderr, nothing written), 1 unexpected failure, 130 Ctrl-C.
A standard output closed by its reader (`cellcal ... | head`) changes nothing but where the rest of the text goes.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import sys
from collections.abc import Callable
from typing import Any, TextIO

from app.cli.analysis import (
    _add_fit_inputs,
    cmd_compare,
    cmd_diagnose,
    cmd_evaluate,
    cmd_export_urdf,
    cmd_fit,
    cmd_predict,
    cmd_rebase,
)
from app.cli.cell import add_cell_parsers
from app.cli.common import (
    CELL_HELP,
    SIGMA_RESIDUAL_HELP,
    DefaultsHelpFormatter,
    OneLineErrorParser,
    add_cell_option,
    add_report_options,
    add_topup_options,
    check_output_args,
    positive_float,
    resolve_cell,
)
from app.cli.dual import add_dual_parsers
from app.cli.jobs import add_job_parsers
from app.cli.real import add_real_parsers
from calibration.data.files import staged_outputs
from calibration.errors import CellCalError

log = logging.getLogger("cellcal.app")










# -- dual-robot planning, validation, preview, export ----------------------------------------------------------


def _add_sigma_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--given", metavar="TRAIN", help="the training recording the model was fitted on: adds each pose's "
                                                    "predicted position sigma [mm] (the top-up design's error model)")
    p.add_argument("--add", action="append", default=[], metavar="PICKED.csv",
                   help="poses fitted with --given (fit --add); repeatable")
    p.add_argument("--sigma-residual-mm", type=positive_float, metavar="MM", help=SIGMA_RESIDUAL_HELP)


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineErrorParser(prog="cellcal", formatter_class=DefaultsHelpFormatter,
                                     description="Calibrate the arms of a robot cell from motion-capture recordings, "
                                     "plan with the calibrated models and put them into service.")
    parser.add_argument("--cell", help=f"{CELL_HELP}; also accepted after the command name of every command that "
                                       "reads it")
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress bars (they are off anyway when "
                                                                    "stderr is not a terminal)")
    parser.add_argument("--version", action="version", version=f"cellcal {version()}")
    sub = parser.add_subparsers(dest="command", required=True)
    add = _adder(sub)
    _add_model_parsers(add)
    _add_rebase_parser(add)
    _add_export_urdf_parser(add)
    _add_compare_parser(add)
    _add_diagnose_parser(add)
    add_dual_parsers(add)
    add_cell_parsers(add)
    add_real_parsers(add)
    add_job_parsers(add)
    return parser


def _adder(sub: argparse._SubParsersAction[OneLineErrorParser]) -> Callable[..., argparse.ArgumentParser]:
    """The ``add(name, func, help_text, reads_cell=True)`` every command group registers its subcommands with: a
    subparser of ``sub`` that runs ``func``, with the ``--cell`` option unless ``reads_cell`` is False."""
    def add(name: str, func: Callable[[argparse.Namespace], int], help_text: str, *,
            reads_cell: bool = True) -> argparse.ArgumentParser:
        p = sub.add_parser(name, help=help_text, formatter_class=DefaultsHelpFormatter)
        p.set_defaults(func=func)
        if reads_cell:
            add_cell_option(p)
        return p

    return add


def _add_model_parsers(add: Callable[..., argparse.ArgumentParser]) -> None:
    """fit, predict, evaluate."""
    from calibration.method_names import METHODS

    p = add("fit", cmd_fit, "fit one method and save the model")
    _add_fit_inputs(p)
    p.add_argument("--method", required=True, choices=METHODS, help="the calibration method to fit")
    p.add_argument("--out", required=True, help="model file (.yaml or .json)")
    p.add_argument("--json", help="write the method, parameter and sample counts and the fit time as JSON")
    p = add("predict", cmd_predict, "tool poses of a model for joint angles")
    p.add_argument("--model", required=True, help="the model file (fit --out)")
    p.add_argument("--robot", help="the arm the model is for (R1, R2): refuse a model of another robot (joints "
                                   "are checked against the limits of the model's robot either way)")
    p.add_argument("--joints", required=True, help="CSV with q1..q6 [rad] (header) or 6 headerless columns")
    _add_sigma_options(p)
    p.add_argument("--out", required=True, help="poses CSV to write (x, y, z [mm], qw, qx, qy, qz)")
    p.add_argument("--json", help="write the pose count, how many lie outside the model's (q2, q3) interpolation "
                                  "region (outside_fitted_region: 0 for a constant model) and beyond the training "
                                  "joint range (extrapolation), with what each count counts (counts_explained), as "
                                  "JSON")
    p = add("evaluate", cmd_evaluate, "accuracy of a model on a recording")
    p.add_argument("--model", required=True, help="the model file (fit --out)")
    p.add_argument("--robot", help="the arm the model is for (R1, R2): refuse a model of another robot (joints "
                                   "are checked against the limits of the model's robot either way)")
    p.add_argument("--test", required=True, help="recording CSV or Welding_Motoman folder to evaluate on")
    p.add_argument("--json", help="write the statistics as JSON")
    _add_sigma_options(p)
    add_report_options(p, "the model's errors and plots")


def _add_rebase_parser(add: Callable[..., argparse.ArgumentParser]) -> None:
    p = add("rebase", cmd_rebase, "move a fitted model of any kind onto a new day: refit only its base and tool-marker "
                                  "frames on a few poses")
    p.add_argument("--robot", help="robot name in the cell (R1, R2; default: the robot the model records): refuse "
                                   "a model of another robot")
    p.add_argument("--model", required=True, help="the fitted model file")
    p.add_argument("--data", required=True, help="a few poses of the new day (recording CSV or Welding_Motoman folder)")
    p.add_argument("--out", required=True, help="the rebased model file")
    p.add_argument("--json", help="write the corrections and the error before/after as JSON")
    p.add_argument("--tolerance", type=float, default=1e-2,
                   help="frame directions whose singular value is below this fraction, in (0, 1), of the largest "
                        "are held at zero")
    which = p.add_mutually_exclusive_group()
    which.add_argument("--translation-only", action="store_true",
                       help="fit only the two translations (6 parameters), unchecked on held-out clusters")
    which.add_argument("--all-directions", action="store_true",
                       help="fit both frames' translations and rotations (12), unchecked on held-out clusters; "
                            "default: clusters held out in turn (poses, with fewer than 2 clusters) confirm a frame "
                            "change or it is refused (exit 2, nothing written: the model as given does as well "
                            "there); both frames are then fitted along the combinations the poses see at least half "
                            "as much as configurations across the joint limits do (where the wrist turns), the rest "
                            "held, unless every direction leaves a tenth of that fit's residual")
    which.add_argument("--offsets", action="store_true",
                       help="fit both frames and the joint offsets of joints 4 and 5 (14): for poses that move the "
                            "wrist widely (cellcal plan --design optimal --for rebase); a still wrist cannot see "
                            "them")


def _add_export_urdf_parser(add: Callable[..., argparse.ArgumentParser]) -> None:
    p = add("export-urdf", cmd_export_urdf, "write a model's calibrated geometry as a URDF with the ROS-Industrial "
                                            "Motoman names (or a xacro macro), joint limits and efforts; says what "
                                            "a URDF cannot hold")
    p.add_argument("--model", required=True, help="the model file (constant, pi, cdc, physics, diagnosed, rebased)")
    p.add_argument("--robot", help="robot name in the cell (R1, R2; default: the robot the model records); its YAML "
                                   "gives the joint limits")
    p.add_argument("--out", required=True, help="the URDF file to write (lengths in metres; ROS-Industrial Motoman "
                                                "names: base_link on the floor, joint_1_s .. joint_6_t, link_1_s .. "
                                                "link_6_t, base = the robot frame, tool0; then flange and "
                                                "tool_marker)")
    p.add_argument("--meshes", metavar="URI",
                   help="mesh folder by package URI, e.g. package://motoman_ma2010_support/meshes/ma2010: each link "
                        "gets URI/visual/LINK.stl and URI/collision/LINK.stl (default: no geometry)")
    p.add_argument("--xacro", metavar="FILE",
                   help="also write the description as a xacro macro with a prefix parameter, for motoman_support / "
                        "MotoROS2 users: include it and call <xacro:MACRO prefix=\"\"/> in place of the support "
                        "package's macro (e.g. motoman_ma2010): same names, calibrated joint origins")
    p.add_argument("--macro", help="the xacro macro's name (default cellcal_<robot model>, e.g. cellcal_ma2010)")
    p.add_argument("--json", help="write what was exported and what was lost as JSON")


def _add_compare_parser(add: Callable[..., argparse.ArgumentParser]) -> None:
    p = add("compare", cmd_compare, "the paper's comparison table for every method")
    _add_fit_inputs(p)
    p.add_argument("--test", required=True, help="recording CSV or Welding_Motoman folder the methods never fit on")
    p.add_argument("--methods", default="all", help="all, or a comma-separated list")
    p.add_argument("--model", action="append", default=[], metavar="FILE",
                   help="a saved model (a diagnose result, ...) to add as a row of its own; repeatable")
    p.add_argument("--json", help="write the comparison as JSON")
    add_report_options(p, "every method's errors, tables and plots; also report.md and the PNGs")


def _add_diagnose_parser(add: Callable[..., argparse.ArgumentParser]) -> None:
    p = add("diagnose", cmd_diagnose, "find the physics the model in use left out, model it, show the fit improve")
    p.add_argument("--robot", required=True, help="robot name in the cell (R1, R2)")
    p.add_argument("--train", "--data", dest="train", required=True, action="append",
                   help="recording CSV or Welding_Motoman folder to fit on (--data: the old name); repeat it for "
                        "several days of one arm: what differs between them (frames, parameters, drift) is reported "
                        "and the diagnosis runs on them pooled, each with its frames taken out")
    add_topup_options(p)
    p.add_argument("--test", "--heldout", dest="test",
                   help="recording the selection never fits on (default: held-out clusters of --train; --heldout: "
                        "the old name)")
    p.add_argument("--model", help="model in use (default: the geometric NLS fit of --train)")
    p.add_argument("--json", help="write the report (schema cellcal.diagnose/1)")
    add_report_options(p, "the verdict, held-out accuracy before/after and plots; also report.md and the PNGs")
    p.add_argument("--out", help="save the refitted geometry + physics model")
    p.add_argument("--compliance-form", choices=("auto", "masses", "mass_free"), default="auto",
                   help="joint compliance from the robot YAML's link masses, or in the mass-free gravity form "
                        "(auto: masses when the YAML has them, the mass-free form when the data show another shape)")
    p.add_argument("--weighting", choices=("noise", "fixed"), default="noise",
                   help="weigh position and orientation by their noise floors estimated from the data (noise), or "
                        "by the fixed a = 1641 (1 mm ~ 1 deg)")


def version() -> str:
    """The installed package's version (one definition: :func:`app.reports.provenance.version`)."""
    from app.reports.provenance import version as cellcal_version

    return cellcal_version()


#: Commands whose outputs (files, a report folder, a JSON summary) are one set: they take their names together when
#: the command succeeds, and a failure (a full disk) leaves none of them, not even a folder
#: (:func:`calibration.data.files.staged_outputs`). Commands that read back what they wrote (recalibrate, demo) are not.
STAGED_COMMANDS = frozenset({"evaluate", "compare", "fit", "predict", "select", "plan", "export", "diagnose",
                             "plan-dual", "export-targets", "export-urdf", "compensate-job", "init-cell",
                             "import-motive"})


def main(argv: list[str] | None = None) -> int:
    """Run one subcommand: 0 on success, 2 on bad input or a refused action, 130 on Ctrl-C.

    A standard output whose reader has gone (``cellcal ... | head``) changes nothing but where the rest of the text
    goes: the command finishes as it would have (its files written), printing into the null device, and exits with
    its own status, with no BrokenPipeError traceback. Python ignores SIGPIPE, so that error would otherwise come
    from whichever print met the closed pipe (unbuffered) or from the interpreter's last flush (a pipe is
    block-buffered, so most commands had finished by then): handled here once, for every command.
    """
    guard = _StdoutGuard(sys.stdout)
    sys.stdout = guard
    try:
        try:
            return _run(argv)
        finally:
            guard.flush()  # a closed pipe shows here, not in the interpreter's final flush
    finally:
        if sys.stdout is guard:
            sys.stdout = guard.stream


class _StdoutGuard:
    """sys.stdout while a command runs: once the reader of the pipe has gone, stdout (and stderr, when it is closed
    too) is pointed at the null device, so what is still printed goes nowhere instead of raising. A BrokenPipeError
    while stdout is open (a socket whose peer left) is not this one and propagates."""

    def __init__(self, stream: TextIO) -> None:
        self.stream = stream

    def write(self, text: str) -> int:
        try:
            return self.stream.write(text)
        except BrokenPipeError:
            if not _discard_closed_streams(self.stream):
                raise
            return len(text)

    def flush(self) -> None:
        try:
            self.stream.flush()
        except BrokenPipeError:
            if not _discard_closed_streams(self.stream):
                raise

    def __getattr__(self, name: str) -> Any:
        return getattr(self.stream, name)


def _discard_closed_streams(stdout: TextIO) -> bool:
    """Point ``stdout``'s descriptor (and stderr's, when its reader has gone too) at the null device if its reader
    has gone; True if it had."""
    import os
    import select

    def closed_fd(stream: Any) -> int | None:
        try:
            fd = stream.fileno()
        except (AttributeError, OSError, ValueError):  # io.UnsupportedOperation is an OSError and a ValueError
            return None
        poller = select.poll()
        poller.register(fd, select.POLLOUT)
        masks = [mask for _, mask in poller.poll(0)]
        return fd if masks and masks[0] & (select.POLLERR | select.POLLHUP) else None

    stdout_fd = closed_fd(stdout)
    if stdout_fd is None:
        return False
    stderr_fd = closed_fd(sys.stderr)
    null = os.open(os.devnull, os.O_WRONLY)
    try:
        for fd in (stdout_fd, stderr_fd):
            if fd is not None:
                os.dup2(null, fd)
    finally:
        os.close(null)
    return True


def _run(argv: list[str] | None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    args.argv = list(argv) if argv is not None else sys.argv[1:]
    from app.progress import configure, install_logging
    from app.reports.command_warnings import collecting

    install_logging(logging.INFO if args.verbose else logging.WARNING)  # log lines go through the bars
    configure(quiet=args.quiet)
    try:
        resolve_cell(args)
        check_output_args(args)
        with staged_outputs() if args.command in STAGED_COMMANDS else contextlib.nullcontext(), collecting():
            code: int = args.func(args)  # every warning it gives reaches its report (app.reports.command_warnings)
            return code
    except CellCalError as e:
        print(f"cellcal {args.command}: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        hint = getattr(args, "stop_hint", None)  # a command's own word on what was left (recalibrate)
        if hint is None:  # a session of a command that can resume it (collect)
            hint = " (continue with --resume)" if getattr(args, "session", None) and hasattr(args, "resume") else ""
        print(f"cellcal {args.command}: stopped{hint}", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
