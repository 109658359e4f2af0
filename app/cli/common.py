"""Helpers shared by the ``cellcal`` subcommands: the cell, recordings, fitters from arguments and JSON outputs."""

from __future__ import annotations

import argparse
import json
import logging
import math
import re
import sys
from collections.abc import Callable
from typing import Any, NoReturn, TypeVar

from calibration.errors import OutputError

log = logging.getLogger("cellcal.app")


class DefaultsHelpFormatter(argparse.HelpFormatter):
    """``--help`` that states every option's default: `` (default X)`` is added to an option's help unless the
    text states it already (``%(default)`` or ``default X``). Flags, options without a default (None) and empty
    repeatable lists have none to state. (argparse's ArgumentDefaultsHelpFormatter also prints ``None`` and
    ``False``, and a second default where the text gives one.)"""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        if not _stated_default(action) or "%(default)" in text or re.search(
                r"\bdefault:? " + re.escape(_default_text(action.default)) + r"(?![\w.])", text):
            return action.help
        return f"{text} (default %(default){'g' if isinstance(action.default, float) else 's'})"


class OneLineErrorParser(argparse.ArgumentParser):
    """An ArgumentParser whose usage errors are one line on stderr, exit 2, as every other bad input: argparse
    printed the whole usage first (4-10 lines), and for a mistyped option (``--methd nls1``) said only that
    ``--method`` was missing. An unknown option is named first, with the closest valid one. Subcommand parsers
    are of this class too (``add_subparsers`` uses the parent's)."""

    def parse_known_args(self, args: Any = None, namespace: Any = None) -> Any:
        import sys

        self._argv = list(sys.argv[1:] if args is None else args)
        return super().parse_known_args(args, namespace)

    def error(self, message: str) -> NoReturn:
        prog = self.prog
        if message.startswith("the following arguments are required") and self._command() is self:
            unknown = [a for a in getattr(self, "_argv", []) if a.startswith("--") and not self._knows(a)]
            if unknown:  # a mistyped option: say so first (argparse names only the option then missing)
                message = f"unrecognized arguments: {' '.join(unknown)}{self._suggest(unknown, self)}; {message}"
        elif message.startswith("unrecognized arguments: "):  # left over by the subcommand: named as its error
            command = self._command()
            message += self._suggest([a for a in message.split(": ", 1)[1].split() if a.startswith("--")], command)
            prog = command.prog
        self.exit(2, f"{prog}: {message}; {prog} --help lists the options\n")

    def _command(self) -> argparse.ArgumentParser:
        """The subcommand's parser named in the arguments (this parser when it has none)."""
        subs = next((a for a in self._actions if isinstance(a, argparse._SubParsersAction)), None)
        name = next((a for a in getattr(self, "_argv", []) if subs is not None and a in subs.choices), None)
        return subs.choices[name] if subs is not None and name is not None else self

    def _knows(self, arg: str) -> bool:
        """Whether ``arg`` (``--opt`` or ``--opt=value``) is one of this parser's options or a prefix of one."""
        name = arg.split("=", 1)[0]
        return any(o.startswith(name) for o in self._option_string_actions)

    @staticmethod
    def _suggest(unknown: list[str], parser: argparse.ArgumentParser) -> str:
        import difflib

        known = [o[2:] for o in parser._option_string_actions if o.startswith("--")]  # "--" alone looks alike
        pairs = [(a, difflib.get_close_matches(a.split("=", 1)[0][2:], known, n=1)) for a in unknown]
        hints = [f"--{close[0]} for {a}" for a, close in pairs if close]
        return f" (did you mean {', '.join(hints)}?)" if hints else ""


def _stated_default(action: argparse.Action) -> bool:
    """Whether ``--help`` should state ``action``'s default: it has a value a user would otherwise have to guess."""
    if isinstance(action, (argparse._StoreTrueAction, argparse._StoreFalseAction, argparse._HelpAction,
                           argparse._VersionAction)) or not action.option_strings:
        return False
    return action.default is not None and action.default != argparse.SUPPRESS and action.default != []


def _default_text(value: Any) -> str:
    """A default as ``--help`` prints it: floats as ``%g`` (5, 0.05, 1641), anything else as ``str``."""
    return f"{value:g}" if isinstance(value, float) else str(value)


#: ``--cell``'s help, before the command name and after it.
CELL_HELP = "cell.yaml (default: the packaged Motoman cell)"
#: Where ``--cell`` given after the command name is kept until :func:`resolve_cell` checks it against the one before.
CELL_AFTER = "cell_after_command"


#: Most validation poses a command takes: each is a move and a measurement of seconds on the cell, so 10000 is hours
#: already; a count past it is a typo (plan --validation 100000000 ran for minutes, building a plan nobody could run).
MAX_VALIDATION_POSES = 10_000


def validation_count(text: str) -> int:
    """argparse type of a number of validation poses: an integer from 0 to :data:`MAX_VALIDATION_POSES`.

    Raises:
        argparse.ArgumentTypeError: naming the value (the parser's one line names the option).
    """
    value = non_negative_int(text)
    if value > MAX_VALIDATION_POSES:
        raise argparse.ArgumentTypeError(f"expected at most {MAX_VALIDATION_POSES} validation poses (each is a move "
                                         f"and a measurement on the cell), got {value}")
    return value


_Number = TypeVar("_Number", int, float)


def _checked_number(text: str, kind: Callable[[str], _Number], ok: Callable[[_Number], bool], expected: str
                   ) -> _Number:
    """``kind(text)`` when it is finite and ``ok(value)``; else ArgumentTypeError "expected EXPECTED, got TEXT"."""
    try:
        value = kind(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}") from None
    if not (math.isfinite(value) and ok(value)):
        raise argparse.ArgumentTypeError(f"expected {expected}, got {text}")
    return value


def non_negative_int(text: str) -> int:
    """argparse type of a seed or a count: an integer >= 0 (numpy's generators refuse a negative seed, and a
    negative seed reached them as a traceback, exit 1, after the command had started).

    Raises:
        argparse.ArgumentTypeError: naming the value (the parser's one line names the option).
    """
    return _checked_number(text, int, lambda v: v >= 0, "an integer >= 0")


def positive_int(text: str) -> int:
    """argparse type of a weight or a count that must be an integer >= 1.

    Raises:
        argparse.ArgumentTypeError: naming the value (the parser's one line names the option).
    """
    return _checked_number(text, int, lambda v: v >= 1, "an integer >= 1")


def add_weight(text: str) -> int:
    """argparse type of ``--add-weight``: an integer in 1..MAX_ADD_WEIGHT (the weight repeats each added pose's
    rows, so a huge one exhausted memory or ran for minutes).

    Raises:
        argparse.ArgumentTypeError: naming the value.
    """
    from calibration.data.recording import MAX_ADD_WEIGHT

    return _checked_number(text, int, lambda v: 1 <= v <= MAX_ADD_WEIGHT, f"an integer in 1..{MAX_ADD_WEIGHT}")


def positive_float(text: str) -> float:
    """argparse type of a size, an angle or a time that must be a finite number > 0 (``nan`` passes every ``<``
    test and ``inf`` every ``>`` test, so a bound given as either was silently no bound).

    Raises:
        argparse.ArgumentTypeError: naming the value (the parser's one line names the option).
    """
    return _checked_number(text, float, lambda v: v > 0, "a finite number > 0")


def non_negative_float(text: str) -> float:
    """argparse type of a delay, a noise or a spread that may be zero: a finite number >= 0 (``nan`` passes every
    test, so a delay given as nan was no delay at all).

    Raises:
        argparse.ArgumentTypeError: naming the value (the parser's one line names the option).
    """
    return _checked_number(text, float, lambda v: v >= 0, "a finite number >= 0")


def add_cell_option(p: argparse.ArgumentParser) -> None:
    """``--cell`` after the command name, as before it (``cellcal --cell C fit ...`` and ``cellcal fit --cell C``)."""
    p.add_argument("--cell", dest=CELL_AFTER, metavar="CELL", help=f"{CELL_HELP}; also accepted before the command")


def resolve_cell(args: argparse.Namespace) -> None:
    """``args.cell`` from ``--cell`` before or after the command name.

    Raises:
        CellCalError: both are given and name different files (which one was meant is not guessed).
    """
    from calibration.errors import CellCalError

    after = getattr(args, CELL_AFTER, None)
    if after is None:
        return
    if args.cell is not None and args.cell != after:
        raise CellCalError(f"--cell given twice: {args.cell} before the command and {after} after it; give it once")
    args.cell = after


def cell_spec(args: argparse.Namespace) -> Any:
    """The cell of ``--cell``, or the packaged Motoman cell."""
    from cell_config import load_cell

    return load_cell(args.cell) if args.cell else load_cell()


def model_and_robot(args: argparse.Namespace, path: str, *, needs_robot: bool = False) -> tuple[Any, Any]:
    """The model file ``path`` and the cell entry of its robot: ``--robot``, else the robot the file records.

    Either way the file is checked to be that robot's, its geometry included (:func:`app.workflows.inputs.load_model_for`), so the
    check no longer needs ``--robot`` to be given; both given and disagreeing is refused.

    Args:
        needs_robot: the command cannot go on without the robot's cell entry (limits of a recording, a rebase);
            otherwise a model of a robot the cell does not describe comes with ``None`` and no checks against it.

    Raises:
        DataError: the file is unusable, records another robot than ``--robot``, or holds another robot type's
            geometry; ConfigError: the robot (given or recorded) is not in the cell and ``needs_robot``.
    """
    from app.workflows.inputs import load_model_for
    from calibration.models import load_model
    from calibration.models.checks import check_model_for

    cell = cell_spec(args)
    if args.robot:
        robot = cell.robot(args.robot)
        return load_model_for(path, robot), robot
    model = load_model(path)
    robot = cell.robot(model.robot) if needs_robot else cell.robots.get(model.robot)
    if robot is not None:
        check_model_for(model, robot.name, robot.model(), path)
    return model, robot


ADD_HELP = ("extra poses (a recording CSV or Welding_Motoman folder, no cluster column needed, e.g. cellcal select "
            "--out) fitted with the training recording as one day, each pose standing alone: the global fits use "
            "them, the local (per-cluster) fits of the CDC methods do not; repeatable")
ADD_WEIGHT_HELP = ("weight of each --add pose against one training pose in the fits (an integer in 1..100; the default "
                   "counts a stand-alone pose as much as one training cluster of 7 poses)")


SIGMA_RESIDUAL_HELP = ("the predicted sigma's residual per coordinate [mm] (the error a global model never learns); "
                       "default: chosen on --given itself by maximum likelihood of pi refitted without 8 held-out "
                       "folds (calibration.methods.topup_sigma; about 10 s for a 1736-pose grid)")


def sigma_residual(args: argparse.Namespace, robot: Any, given: Any) -> tuple[float, str]:
    """The predicted sigma's residual [mm] and where it came from: ``--sigma-residual-mm``, else chosen on the
    given recording's held-out folds (:func:`calibration.methods.topup_sigma.held_out_residual`), else (a given
    recording with fewer than 2 clusters to hold out) the fixed one, said so on stderr."""
    import time

    from calibration.errors import ModelError
    from calibration.methods.fitter import Fitter
    from calibration.methods.topup import SIGMA_RESIDUAL_MM
    from calibration.methods.topup_sigma import held_out_residual

    if getattr(args, "sigma_residual_mm", None) is not None:
        return float(args.sigma_residual_mm), "--sigma-residual-mm"
    t0 = time.perf_counter()
    try:
        scales = held_out_residual(Fitter.for_arm(robot.arm(), given))
    except ModelError as e:
        print(f"note: the predicted sigma uses the fixed residual {SIGMA_RESIDUAL_MM:g} mm: the given poses have no "
              f"folds to hold out ({e})", file=sys.stderr)
        return SIGMA_RESIDUAL_MM, "fixed (no held-out folds in --given)"
    print(f"predicted sigma: residual {scales.residual_mm:g} mm per coordinate, chosen on {scales.held_out_poses} "
          f"held-out predictions of --given (pi refitted without 8 folds, {time.perf_counter() - t0:.1f} s)")
    return scales.residual_mm, "held-out folds of --given"


def add_topup_options(p: argparse.ArgumentParser) -> None:
    """``--add`` and ``--add-weight`` of fit, compare, diagnose and recalibrate."""
    from calibration.data.recording import DEFAULT_ADD_WEIGHT

    p.add_argument("--add", action="append", default=[], metavar="PICKED.csv", help=ADD_HELP)
    p.add_argument("--add-weight", type=add_weight, default=DEFAULT_ADD_WEIGHT, help=ADD_WEIGHT_HELP)


#: File outputs every subcommand may take; ``demo --out`` is a folder and is left to the demo.
OUTPUT_FILE_OPTIONS = ("out", "json", "html", "xacro", "jbi")


#: Options that name files a command reads (``--models`` as ``R1=FILE,R2=FILE``, ``--model`` also as ``R2=FILE``;
#: ``--cell`` is the packaged cell when left out).
INPUT_FILE_OPTIONS = ("train", "add", "test", "cpa", "data", "model", "models", "joints", "plan", "job", "relative_pose",
                      "motive", "path", "cell", CELL_AFTER)


def _folder_files(args: argparse.Namespace) -> list[tuple[str, str, str]]:
    """``(option, file name, path)`` of the files a command owns inside the folders it is given: a session's
    database (and its WAL, shared-memory and lock files), a model folder's model in service. They may not exist yet
    (recalibrate installs the first ``current.yaml``), so they are compared by path."""
    import os

    folders: dict[str, tuple[str, ...]] = {}
    if isinstance(getattr(args, "session", None), str):
        from app.collection.session_store import DB_NAME, LOCK_NAME

        folders["session"] = (DB_NAME, f"{DB_NAME}-wal", f"{DB_NAME}-shm", LOCK_NAME)
    if isinstance(getattr(args, "model_dir", None), str):
        from app.workflows.recalibrate import CURRENT

        folders["model_dir"] = (CURRENT,)
    return [(name, file, os.path.join(getattr(args, name), file)) for name, files in folders.items() for file in files]


def check_output_args(args: argparse.Namespace) -> None:
    """Refuse an empty, symlink, device, FIFO or folder output path before any work, so nothing is written; and an
    output that is one of the command's input files or another of its outputs (``fit --train r.csv --out r.csv``
    replaced the recording with the model, ``--json`` equal to ``--out`` the model with its summary), or a file the
    command owns in a folder it is given (:func:`_folder_files`: ``export --out S/session.sqlite`` would replace the
    session it reads, ``recalibrate --json M/current.yaml`` the model it installs).

    Raises:
        OutputError: the first such ``--out``/``--json``/``--html`` path.
    """
    import os

    from calibration.data.files import check_output_path
    from calibration.errors import OutputError

    check_input_args(args)
    check_no_stdout_dash(args)
    outputs: list[tuple[str, str]] = []
    for name in OUTPUT_FILE_OPTIONS:
        value = getattr(args, name, None)
        if isinstance(value, str) and not (name == "out" and args.command == "demo"):
            check_output_path(value)
            outputs.append((name, value))
    inputs = [(name, path) for name in INPUT_FILE_OPTIONS for path in _named_files(getattr(args, name, None))]
    if hasattr(args, CELL_AFTER) and not args.cell:  # the command reads the packaged cell
        from cell_config import DEFAULT_CELL

        inputs.append(("cell", str(DEFAULT_CELL)))
    owned = ([(other, path, "output") for other, path in outputs]  # an input that does not exist is refused later
             + [(other, path, "input") for other, path in inputs if os.path.exists(path)]
             + [(folder, path, f"folder's {file}") for folder, file, path in _folder_files(args)])
    for i, (name, value) in enumerate(outputs):
        clash = next(((other, what) for j, (other, path, what) in enumerate(owned)
                      if j != i and (what != "output" or j < i) and _same_file(value, path)), None)
        if clash is not None:
            raise OutputError(value, f"--{name} is also the --{_option(clash[0])} {clash[1]}; refusing to "
                                     f"overwrite it (give --{name} another file)")


#: Commands whose ``--session`` folder they create or extend (elsewhere ``--session`` is read).
SESSION_WRITERS = ("collect",)

#: Every option naming something a command writes, file or folder (``--session`` only where the command writes it).
WRITTEN_OPTIONS = (*OUTPUT_FILE_OPTIONS, "report", "model_dir", "session")


def check_no_stdout_dash(args: argparse.Namespace) -> None:
    """Refuse ``-`` as an output: every command writes its outputs to files (several at once, a summary on stdout
    beside them), so the Unix "standard output" reading cannot hold; ``export-urdf --out -`` wrote a file named ``-``.

    Raises:
        OutputError: the first output option given as ``-``.
    """
    for name in WRITTEN_OPTIONS:
        if getattr(args, name, None) == "-" and (name != "session" or args.command in SESSION_WRITERS):
            raise OutputError(f"--{_option(name)} -", "cellcal writes its outputs to files, not to standard output "
                                                      "(nor to a file named '-'); give a file name")


def check_input_args(args: argparse.Namespace) -> None:
    """Refuse, before any work and without opening it, an input file option naming a FIFO, a device or a socket: a
    FIFO blocked its reader forever, ``/dev/zero`` as a recording read until memory ran out. Each reader refuses
    them too (:func:`calibration.data.files.read_input_bytes`, with its own bound on the size); this names the option.

    Raises:
        DataError: naming the option and the path.
    """
    import sys

    from calibration.data.files import InputRefused, check_input_path
    from calibration.errors import DataError

    for name in INPUT_FILE_OPTIONS:
        for path in _named_files(getattr(args, name, None)):
            try:
                check_input_path(path, sys.maxsize)  # sizes are each reader's to bound
            except InputRefused as e:
                raise DataError(path, None, None, f"--{_option(name)}: {e.strerror}") from None


def _same_file(a: str, b: str) -> bool:
    """Whether two paths name one file: the same path once resolved (a file not written yet), or, both existing,
    the same file (hard links included)."""
    import os

    return os.path.realpath(a) == os.path.realpath(b) or (os.path.exists(a) and os.path.exists(b)
                                                          and os.path.samefile(a, b))


def _option(dest: str) -> str:
    """The option a parser destination comes from (``cell_after_command`` is ``--cell``)."""
    return "cell" if dest == CELL_AFTER else dest.replace("_", "-")


def _named_files(value: Any) -> list[str]:
    """The file paths an input option's value names: itself, each of a list, and the FILEs of ``NAME=FILE,...``."""
    values = value if isinstance(value, (list, tuple)) else [value]
    paths: list[str] = []
    for v in values:
        if isinstance(v, str) and v:
            paths.append(v)
            paths += [part.split("=", 1)[1] for part in v.split(",") if "=" in part]
    return paths


def show_progress(args: argparse.Namespace) -> bool:
    """Whether this command shows progress bars: the CLI's policy (a terminal, no ``--quiet``) and no
    ``--no-progress``."""
    from app.progress import enabled

    return enabled() and not getattr(args, "no_progress", False)


def epoch_bar(args: argparse.Namespace) -> Any:
    """The training-epoch bar of the neural interpolators (``FitOptions.epoch_progress``), or None without bars."""
    if not show_progress(args):
        return None
    from app.progress import EpochBar

    return EpochBar("nn/ae training")


def write_json(path: str | None, data: dict[str, Any]) -> None:
    """Write ``data`` as JSON to ``path`` atomically; nothing when ``path`` is None."""
    if path:
        from calibration.data.files import atomic_write_text

        atomic_write_text(path, json.dumps(data, indent=1))


def add_report_options(p: argparse.ArgumentParser, what: str, tolerance_note: str = "") -> None:
    """``--report DIR`` and the acceptance tolerance of its ``report.html`` (issue 12); ``tolerance_note`` is added
    to ``--tolerance-mm``'s help (what else the command does with it)."""
    p.add_argument("--report", metavar="DIR", help=f"write report.html (self-contained: {what}, pass/fail against "
                                                   "the tolerance, ISO 9283 where poses repeat, input hashes) here")
    p.add_argument("--tolerance-mm", type=float, default=1.0, metavar="MM",
                   help="acceptance: largest position error allowed on the evaluation poses [mm] (default "
                        "%(default)g, cold spray)" + tolerance_note)
    p.add_argument("--tolerance-deg", type=float, default=1.0, metavar="DEG",
                   help="acceptance: largest orientation error allowed on the evaluation poses [deg] (default "
                        "%(default)g, cold spray)")


def tolerance_from_args(args: argparse.Namespace) -> Any:
    """The report's :class:`~app.reports.acceptance.Tolerance` from ``--tolerance-mm``/``--tolerance-deg``, with
    ``--report`` checked to be a folder or a new path (call before any work, so bad input writes nothing).

    Raises:
        CellCalError: a tolerance that is not a positive finite number; ConfigError: ``--report`` is a file.
    """
    from pathlib import Path

    from app.reports.acceptance import Tolerance
    from calibration.errors import ConfigError

    report = getattr(args, "report", None)
    if report is not None and (report == "" or (Path(report).exists() and not Path(report).is_dir())):
        raise ConfigError(Path(report), "", "--report must be a folder (report.html is written into it)")
    return Tolerance(args.tolerance_mm, args.tolerance_deg)


def command_line(args: argparse.Namespace) -> str:
    """The command as run, for the report (``cellcal`` and the arguments given)."""
    import shlex
    import sys

    argv = getattr(args, "argv", None)
    return "cellcal " + " ".join(shlex.quote(a) for a in (argv if argv is not None else sys.argv[1:]))
