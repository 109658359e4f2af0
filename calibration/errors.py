"""The project's exception hierarchy: one root, subclasses that carry data.

Every package (calibration, cell_config, drivers, app) raises these, so the CLI can turn any of them
into one clear line on stderr and exit code 2.
"""

from __future__ import annotations

from pathlib import Path


class CellCalError(Exception):
    """Root of every error cellcal raises on purpose.

    Pickles as it is (message, type and data attributes), whatever its subclass's ``__init__`` takes: an error
    raised in a worker process reaches the parent as itself, not as a broken pool.
    """

    def __reduce__(self) -> tuple[object, ...]:
        return _rebuild, (type(self), self.args, dict(self.__dict__))


def _rebuild(cls: type[CellCalError], args: tuple[object, ...], state: dict[str, object]) -> CellCalError:
    """The unpickled error: ``cls`` with its message and attributes, its ``__init__`` not called again."""
    e = cls.__new__(cls)
    Exception.__init__(e, *args)
    e.__dict__.update(state)
    return e


class ConfigError(CellCalError):
    """A configuration file is malformed.

    Args:
        path: the file.
        key: dotted key inside the file (``robots.R1.tool``), or ``""`` for the whole file.
        reason: what was expected.
    """

    def __init__(self, path: str | Path, key: str, reason: str) -> None:
        self.path = str(path)
        self.key = key
        self.reason = reason
        where = f"{self.path}: {key}" if key else self.path
        super().__init__(f"{where}: {reason}")


class DataError(CellCalError):
    """A data file (recording, joint list, model) is unusable.

    Args:
        path: the file.
        row: 1-based row (header = row 1), or None when the problem is not tied to a row.
        column: column name, or None.
        reason: what is wrong and what was expected.
    """

    def __init__(self, path: str | Path, row: int | None, column: str | None, reason: str) -> None:
        self.path = str(path)
        self.row = row
        self.column = column
        self.reason = reason
        where = self.path
        if row is not None:
            where += f", row {row}"
        if column is not None:
            where += f", column {column!r}"
        super().__init__(f"{where}: {reason}")


class ModelFileError(DataError):
    """A model file is unusable: a value that is not finite, a matrix that is not a rotation, an unknown method,
    a model of another robot, a malformed block.

    Args:
        path: the model file (``""`` while the file is being decoded; the loader fills it in).
        key: dotted key inside the file (``geometry.R_flange``, ``theta_ref``), ``""`` for the whole file.
        reason: what is wrong and what was expected.
    """

    def __init__(self, path: str | Path, key: str, reason: str) -> None:
        self.path = str(path)
        self.row = None
        self.column = None
        self.key = key
        self.reason = reason
        CellCalError.__init__(self, ": ".join(x for x in (self.path, key, reason) if x))


class OutputError(CellCalError):
    """An output file cannot be written; whatever was at the path is left as it was.

    Args:
        path: the output path.
        reason: what is wrong (a symlink, a device, a folder, a failed write) and what to give instead.
    """

    def __init__(self, path: str | Path, reason: str) -> None:
        self.path = str(path)
        self.reason = reason
        super().__init__(f"{self.path or '(empty path)'}: {reason}")


class ModelError(CellCalError):
    """A kinematic model or identification request is inconsistent (unknown method, bad shapes)."""


class UnsafeTarget(CellCalError):
    """A motion target violates a joint limit or the cell's collision model; refused before motion.

    Args:
        robot: robot name (``R1``).
        joint: 1-based joint number, or None for a collision.
        value: the offending value [rad] (or clearance [mm] for a collision).
        limit: the limit it violates.
        reason: free text, e.g. which bodies collide.
    """

    def __init__(self, robot: str, joint: int | None, value: float, limit: float, reason: str = "") -> None:
        self.robot = robot
        self.joint = joint
        self.value = value
        self.limit = limit
        if joint is not None:
            import math

            msg = (f"{robot} joint {joint}: target {math.degrees(value):.6g} deg is outside the limit "
                   f"{math.degrees(limit):.6g} deg")
        else:
            msg = f"{robot}: {reason} (clearance {value:.1f} mm, required {limit:.1f} mm)"
        if reason and joint is not None:
            msg += f" ({reason})"
        super().__init__(msg)


def parse_error_text(e: BaseException) -> str:
    """One line saying where and why a YAML or JSON document failed to parse: ``line L, column C: problem``.

    (A YAML error's own text spans several lines, and quoting only its class name named no place.)
    """
    mark = getattr(e, "problem_mark", None)
    if mark is not None:  # yaml.MarkedYAMLError
        problem = " ".join(str(getattr(e, "problem", "") or e.__class__.__name__).split())
        return f"line {mark.line + 1}, column {mark.column + 1}: {problem}"
    if hasattr(e, "lineno") and hasattr(e, "colno") and hasattr(e, "msg"):  # json.JSONDecodeError
        return f"line {e.lineno}, column {e.colno}: {e.msg}"
    return " ".join(str(e).split()) or e.__class__.__name__
