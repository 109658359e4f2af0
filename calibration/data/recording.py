"""Recordings: static samples of one robot (joint angles + measured tool-marker pose).

Reads the project's recording CSV (documented in ``docs/formats/recording.md``) and the Welding_Motoman folder
layout, validates every value, and writes recordings atomically. Errors name the file, the 1-based row
(header = row 1) and the column.

Beyond the format's "non-numeric or non-finite" errors, a value is refused as physically absurd when
|x|, |y| or |z| > ``MAX_ABS_POSITION_MM`` (1e5 mm = 100 m), |q_i| > ``MAX_ABS_ANGLE_RAD`` (100 rad, checked
even when the joint limits are not known), or any other known column's |value| > ``MAX_ABS_OTHER`` (1e9).
Columns outside the format's table are ignored: their content is never checked, and they are kept (for
rewriting) only when every value is a finite number.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np

from calibration.data.files import atomic_write_text, read_input_text
from calibration.errors import DataError, ModelError
from calibration.kinematics import so3
from calibration.kinematics.arrays import IntArray


def take_out(rec: Recording, T_base: np.ndarray, T_tool: np.ndarray) -> Recording:
    """``rec`` with the frames taken out: ``T' = T_base^-1 @ T_meas @ T_tool^-1`` (the poses the inner arm
    should reach), other columns unchanged."""
    R_b, p_b, R_t, p_t = T_base[:3, :3], T_base[:3, 3], T_tool[:3, :3], T_tool[:3, 3]
    R = R_b.T @ rec.R @ R_t.T
    p = (rec.p - p_b) @ R_b - R @ p_t
    return Recording(rec.q, p, so3.R_to_quat(R), dict(rec.extra), rec.source)


def put_in(rec: Recording, T_base: np.ndarray, T_tool: np.ndarray) -> Recording:
    """The inverse of :func:`take_out`: ``T' = T_base @ T_meas @ T_tool`` (e.g. a planted registration error)."""
    R_b, p_b, R_t, p_t = T_base[:3, :3], T_base[:3, 3], T_tool[:3, :3], T_tool[:3, 3]
    R = R_b @ rec.R @ R_t
    p = (rec.R @ p_t + rec.p) @ R_b.T + p_b
    return Recording(rec.q, p, so3.R_to_quat(R), dict(rec.extra), rec.source)



JOINT_COLUMNS = tuple(f"q{i}" for i in range(1, 7))
POSE_COLUMNS = ("x", "y", "z", "qw", "qx", "qy", "qz")
REQUIRED_COLUMNS = JOINT_COLUMNS + POSE_COLUMNS
WELDING_LAYOUTS = (
    ("train_data_robot_q_align.csv", "train_data_mocap_T_align.csv"),
    ("robot_q_align.csv", "mocap_T_align.csv"),
)
QUAT_NORM_TOL = 1e-3
CONTEXT_COLUMNS = ("t", "temp_c", "payload_kg") + tuple(f"dir{i}" for i in range(1, 7))
SPEED_COLUMNS = tuple(f"qd{i}" for i in range(1, 7))
DEFAULT_CLUSTER_SIZE = 7
KNOWN_OPTIONAL_COLUMNS = ("cluster", "marker_err", "frames") + CONTEXT_COLUMNS + SPEED_COLUMNS
MAX_ABS_POSITION_MM = 1e5
"""Largest |x|, |y|, |z| accepted [mm]: 100 m, far beyond any cell; larger values are typos or overflow."""
MAX_ABS_ANGLE_RAD = 100.0
"""Largest |q_i| accepted [rad] before the joint limits are known: ~16 turns, beyond any joint."""
MAX_ABS_OTHER = 1e9
"""Largest magnitude accepted in any other known column (t [s], temp_c, payload_kg, ...)."""
#: The page that documents the recording CSV, named by the messages of a file in another layout (in the repository).
FORMAT_DOC = "docs/formats/recording.md"
MAX_ROWS = 200_000
"""Largest number of data rows read from one file: a calibration session holds a few thousand samples;
a bigger file is refused while it is read, before any of it is parsed, so memory stays bounded."""
MAX_RECORDING_BYTES = 256 * 2**20
"""Largest recording file read [bytes]: 256 MiB, over 1 kB for each of ``MAX_ROWS`` rows (a row of the 13 required
and 20 optional columns at full precision is about 700 bytes); a larger file, a device (``/dev/zero``) or a FIFO is
refused before it is read (:func:`calibration.data.files.read_input_bytes`)."""


def _max_abs(column: str) -> float:
    if column in ("x", "y", "z"):
        return MAX_ABS_POSITION_MM
    if column in JOINT_COLUMNS:
        return MAX_ABS_ANGLE_RAD
    return MAX_ABS_OTHER


@dataclass(frozen=True)
class Recording:
    """Static samples of one robot.

    Attributes:
        q: joint angles [rad], shape (N, 6).
        p: measured tool-marker position in the base frame [mm], shape (N, 3).
        quat: measured orientation, unit quaternion (w, x, y, z), shape (N, 4).
        extra: optional columns (``cluster``, ``t``, ``dir1``.., ``payload_kg``, ...), each shape (N,).
        source: where it was read from.
    """

    q: np.ndarray
    p: np.ndarray
    quat: np.ndarray
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    source: str = ""

    def __len__(self) -> int:
        n: int = self.q.shape[0]
        return n

    @property
    def R(self) -> np.ndarray:
        """Measured orientation as rotation matrices, shape (N, 3, 3)."""
        return so3.quat_to_R(self.quat)

    def clusters(self, size: int = DEFAULT_CLUSTER_SIZE) -> np.ndarray:
        """Cluster id of every sample: the ``cluster`` column, else consecutive groups of ``size`` rows.

        A negative id in the column marks a stand-alone pose (e.g. one added by :func:`with_added`): each distinct
        negative id gets an id of its own above the others, so no two stand-alone poses are ever taken for one
        cluster (rows sharing a negative id are one pose given weight by repetition, one unit wherever units count).

        Raises:
            DataError: no cluster column and the row count is not a multiple of ``size``.
        """
        if "cluster" in self.extra:
            ids = self.extra["cluster"].astype(int)
            alone = ids < 0
            if alone.any():
                ids = ids.copy()
                ids[alone] = max(int(ids.max()), -1) + 1 + np.unique(ids[alone], return_inverse=True)[1]
            return ids
        if len(self) % size:
            raise DataError(self.source, None, "cluster",
                            f"no cluster column and {len(self)} rows are not a multiple of the "
                            f"{size}-sample anchor design; add a cluster column")
        return np.arange(len(self)) // size

    def context(self) -> dict[str, np.ndarray]:
        """Per-sample context for context-dependent models: the ``t``, ``temp_c``, ``payload_kg`` and
        ``dir1..6`` (as signs) columns present, and ``qd`` (N, 6) [rad/s] when all of ``qd1..qd6`` are."""
        ctx = {k: np.asarray(self.extra[k], dtype=float) for k in CONTEXT_COLUMNS if k in self.extra}
        for i in range(1, 7):
            if f"dir{i}" in ctx:
                ctx[f"dir{i}"] = np.sign(ctx[f"dir{i}"])
        if all(c in self.extra for c in SPEED_COLUMNS):
            ctx["qd"] = np.stack([self.extra[c] for c in SPEED_COLUMNS], axis=1).astype(float)
        return ctx

    def subset(self, index: np.ndarray) -> Recording:
        """The samples selected by a boolean mask or an index array."""
        return Recording(self.q[index], self.p[index], self.quat[index],
                         {k: v[index] for k, v in self.extra.items()}, self.source)


def _parse_float(text: str, path: Path, row: int, column: str) -> float:
    # float() also accepts "1_000" (Python literal syntax); a CSV number has no underscores
    try:
        if "_" in text:
            raise ValueError(text)
        value = float(text)
    except ValueError:
        raise DataError(path, row, column, f"not a number: {text!r}") from None
    if not math.isfinite(value):
        raise DataError(path, row, column, f"not a finite number: {text!r}")
    bound = _max_abs(column)
    if abs(value) > bound:
        raise DataError(path, row, column, f"{value:.6g} is physically absurd (|value| > {bound:g})")
    return value


def _number_or_nan(text: str) -> float:
    try:
        return float(text) if "_" not in text else math.nan
    except ValueError:
        return math.nan


def csv_rows(path: str | Path, max_bytes: int = MAX_RECORDING_BYTES,
             what: str = "CSV file") -> Iterator[list[str]]:
    """The rows of the CSV text file ``path`` (at most ``max_bytes``, a regular file: :func:`read_input_text`), as
    ``csv.reader`` gives them; every reading failure is one :class:`DataError` naming the file (and the line for a
    CSV error: a NUL byte, a field over csv's 131072-character limit, an unclosed quote).

    Raises:
        DataError: the file is missing, a folder, not UTF-8 text, not CSV (``what`` names what was expected) or
            unreadable.
    """
    reader = None
    try:
        reader = csv.reader(io.StringIO(read_input_text(path, max_bytes), newline=""))
        yield from reader
    except csv.Error as e:
        raise DataError(path, reader.line_num if reader else None, None, f"not a {what} ({e})") from None
    except FileNotFoundError:
        raise DataError(path, None, None, "file not found") from None
    except IsADirectoryError:
        raise DataError(path, None, None, "is a folder, expected a CSV file") from None
    except UnicodeDecodeError as e:
        raise DataError(path, None, None, f"not UTF-8 text ({e.reason})") from None
    except OSError as e:
        raise DataError(path, None, None, f"cannot read ({e.strerror or e})") from None


def _read_rows(path: Path) -> list[list[str]]:
    """The non-blank CSV rows of ``path``; a UTF-8 byte-order mark (as Excel writes) is accepted.

    Raises:
        DataError: more than ``MAX_ROWS`` data rows (counted while reading, so a huge file stops early).
    """
    rows: list[list[str]] = []
    for r in csv_rows(path, MAX_RECORDING_BYTES, "CSV recording"):
        if r and any(c.strip() for c in r):
            rows.append(r)
            if len(rows) > MAX_ROWS + 1:
                raise DataError(path, None, None, f"more than {MAX_ROWS} data rows (the limit bounds "
                                                  f"memory; split the recording or subsample it)")
    return rows


def _read_table(path: Path, columns: tuple[str, ...] | None,
                known: tuple[str, ...] | None = None) -> tuple[list[str], np.ndarray, int]:
    """Read a numeric CSV. ``columns`` given: headerless with those names. Returns names, data, first row no.

    ``known`` given: only those columns are validated; any other column's content is ignored (its values
    are kept as numbers where they parse, NaN elsewhere).
    """
    rows = _read_rows(path)
    if rows:
        _check_separator(path, rows[0], len(columns) if columns is not None else len(REQUIRED_COLUMNS))
    if columns is None:
        if not rows:
            raise DataError(path, None, None, "empty file, expected a header row")
        names = [c.strip() for c in rows[0]]
        body, first = rows[1:], 2
    else:
        names, body, first = list(columns), rows, 1
    if not body:
        raise DataError(path, None, None, "no data rows")
    if len(body) > MAX_ROWS:  # a headerless file: _read_rows allowed one row for a header
        raise DataError(path, None, None, f"more than {MAX_ROWS} data rows (the limit bounds "
                                          f"memory; split the recording or subsample it)")
    data = np.empty((len(body), len(names)))
    for i, r in enumerate(body):
        row_no = first + i
        if len(r) != len(names):
            raise DataError(path, row_no, None, f"expected {len(names)} fields, found {len(r)}")
        for j, text in enumerate(r):
            if known is None or names[j] in known:
                data[i, j] = _parse_float(text.strip(), path, row_no, names[j])
            else:
                data[i, j] = _number_or_nan(text.strip())
    return names, data, first


#: Separators a file saved by a spreadsheet in another locale may use instead of the format's comma: (separator, how
#: the message names its fields, how it names the separator).
OTHER_SEPARATORS = ((";", "';'-separated", "';'"), ("\t", "tab-separated", "tabs"))


def _check_separator(path: Path, first: list[str], expected: int) -> None:
    """Refuse a file whose first row is one field holding several ``;``- or tab-separated ones (saved with another
    separator): read with commas it was one column, and the reader said only that column ``q1`` was missing.

    Args:
        first: the first row's fields as the comma reader split them.
        expected: how many columns the file should have (one field is then never right when it is above 1).

    Raises:
        DataError: naming the file and the separator it seems to use.
    """
    if expected < 2 or len(first) == expected:
        return
    for sep, fields, name in OTHER_SEPARATORS:
        if len(first) == 1 and len([part for part in first[0].split(sep) if part.strip()]) > 1:
            raise DataError(path, 1, None, f"one column holding {fields} fields: the file seems to be separated by "
                                           f"{name}, but recordings are comma-separated (see {FORMAT_DOC})")
        # Decimal commas too (a headerless "0,5;1,25;..."): the comma reader split the numbers, not the fields.
        if len(first) > 1 and len(",".join(first).split(sep)) == expected:
            raise DataError(path, 1, None, f"{expected} {fields} fields with decimal commas: the file seems to be "
                                           f"separated by {name}, but recordings are comma-separated with decimal "
                                           f"points (see {FORMAT_DOC})")


def _check_pose(path: Path, q: np.ndarray, quat: np.ndarray, first_row: int,
                lower: np.ndarray | None, upper: np.ndarray | None, q_path: Path | None = None) -> None:
    norms = np.linalg.norm(quat, axis=1)
    bad = np.flatnonzero(np.abs(norms - 1.0) > QUAT_NORM_TOL)
    if bad.size:
        i = int(bad[0])
        raise DataError(path, first_row + i, "qw..qz", f"quaternion norm {norms[i]:.6f} is not 1 (tolerance {QUAT_NORM_TOL})")
    _check_limits(q_path or path, q, first_row, lower, upper)


def _check_limits(path: Path, q: np.ndarray, first_row: int,
                  lower: np.ndarray | None, upper: np.ndarray | None) -> None:
    if lower is not None and upper is not None:
        outside = (q < lower - 1e-9) | (q > upper + 1e-9)
        if outside.any():
            i, j = (int(v) for v in np.argwhere(outside)[0])
            raise DataError(path, first_row + i, JOINT_COLUMNS[j],
                            f"{math.degrees(q[i, j]):.6g} deg is outside the joint limits "
                            f"[{math.degrees(lower[j]):.1f}, {math.degrees(upper[j]):.1f}] deg")


def welding_layout(path: str | Path) -> tuple[Path, Path] | None:
    """The joint and pose files of ``path`` when it is a folder in the Welding_Motoman layout of the paper's own cell
    (``[train_data_]robot_q_align.csv`` + ``[train_data_]mocap_T_align.csv``), else None."""
    path = Path(path)
    if path.is_dir():
        for q_name, t_name in WELDING_LAYOUTS:
            if (path / q_name).exists() and (path / t_name).exists():
                return path / q_name, path / t_name
    return None


def read_recording(path: str | Path, lower: np.ndarray | None = None, upper: np.ndarray | None = None) -> Recording:
    """Read a recording CSV or a Welding_Motoman folder.

    Args:
        path: recording CSV, or a folder with ``[train_data_]robot_q_align.csv`` + ``[train_data_]mocap_T_align.csv``.
        lower, upper: joint limits [rad], shape (6,); when given, samples outside are an error.

    Raises:
        DataError: naming file, row and column of the first bad value.
    """
    path = Path(path)
    if path.is_dir():
        layout = welding_layout(path)
        if layout is not None:
            q_path, t_path = layout
            _, q, _ = _read_table(q_path, JOINT_COLUMNS)
            _, T, _ = _read_table(t_path, POSE_COLUMNS)
            if len(q) != len(T):
                raise DataError(t_path, None, None, f"{len(T)} pose rows but {q_path.name} has {len(q)} joint rows")
            _check_pose(t_path, q, T[:, 3:], 1, lower, upper, q_path)
            return Recording(q, T[:, :3], T[:, 3:] / np.linalg.norm(T[:, 3:], axis=1, keepdims=True), {}, str(path))
        raise DataError(path, None, None, "folder has neither robot_q_align.csv + mocap_T_align.csv nor the "
                                          "train_data_ variants")
    names, data, first = _read_table(path, None, REQUIRED_COLUMNS + KNOWN_OPTIONAL_COLUMNS)
    missing = [c for c in REQUIRED_COLUMNS if c not in names]
    if missing:
        raise DataError(path, 1, missing[0], f"required column missing (required: {', '.join(REQUIRED_COLUMNS)})")
    if len(set(names)) != len(names):
        dup = next(n for n in names if names.count(n) > 1)
        raise DataError(path, 1, dup, "column appears twice")
    col = {n: data[:, i] for i, n in enumerate(names)}
    q = np.stack([col[c] for c in JOINT_COLUMNS], axis=1)
    quat = np.stack([col[c] for c in ("qw", "qx", "qy", "qz")], axis=1)
    _check_pose(path, q, quat, first, lower, upper)
    # unknown columns are ignored (the format); kept for rewriting only when every value is a finite number
    extra = {n: v for n, v in col.items()
             if n not in REQUIRED_COLUMNS and (n in KNOWN_OPTIONAL_COLUMNS or np.isfinite(v).all())}
    if "cluster" in extra and np.any(extra["cluster"] != np.round(extra["cluster"])):
        i = int(np.flatnonzero(extra["cluster"] != np.round(extra["cluster"]))[0])
        raise DataError(path, first + i, "cluster", "expected an integer cluster id")
    back: IntArray | tuple[int, ...] = np.flatnonzero(np.diff(extra["t"]) < 0) if "t" in extra else ()
    if len(back):  # the format: t is the time since the session started, monotonic
        i = int(back[0]) + 1
        raise DataError(path, first + i, "t", f"time goes backwards ({extra['t'][i - 1]:g} s, then {extra['t'][i]:g} "
                                              "s): t is the time since the session started, monotonic (one session "
                                              "per recording; rows in the order they were measured)")
    return Recording(q, np.stack([col["x"], col["y"], col["z"]], 1),
                     quat / np.linalg.norm(quat, axis=1, keepdims=True), extra, str(path))


#: Stand-alone poses (measured on their own, e.g. top-up poses; no anchor's cluster) have ``cluster`` ids below 0:
#: pose j added by :func:`with_added` has ``STANDALONE - j``.
STANDALONE = -1
#: Weight of an added stand-alone pose against one training pose in the fits (:func:`with_added`): it stands for as
#: much as one of the training grid's clusters of 7, whose poses share an anchor and so most of their error. The
#: value is the cluster size; it was checked (not searched) on the top-up protocol's task figures of the two
#: tuning days 0725 and 0620 after (pi, 21 chosen poses, weights 1 / 7 / 20): weighting lowers the task mean on 6
#: of their 8 splits and raises it on 0725's halves splits (0.192 -> 0.220 mm on halves-swapped).
DEFAULT_ADD_WEIGHT = 7
#: Largest weight of an added pose: 100 training poses (about 14 clusters). The weight repeats the pose's rows, so
#: an unbounded one ran out of memory (1e9) or ran for minutes (1e5); beyond this the training recording no
#: longer counts in the fit and a recording of the added poses alone says that more plainly.
MAX_ADD_WEIGHT = 100


def standalone_mask(rec: Recording) -> np.ndarray:
    """Which samples of ``rec`` stand alone (a negative ``cluster`` id), shape (N,) bool."""
    if "cluster" not in rec.extra:
        return np.zeros(len(rec), dtype=bool)
    return np.asarray(rec.extra["cluster"]) < 0


def with_added(train: Recording, added: list[Recording], size: int = DEFAULT_CLUSTER_SIZE, weight: int = 1
               ) -> Recording:
    """``train`` with the poses of ``added`` appended as stand-alone poses, fitted as one day.

    The training samples keep their cluster ids (:meth:`Recording.clusters`: the column, else consecutive groups
    of ``size`` rows); added pose j gets ``STANDALONE - j`` whatever cluster column it has, so global fits use it
    and local (per-cluster) fits never group it. Extra columns are kept only when every recording has them.

    Args:
        weight: each added pose's weight against a training pose in the least-squares fits, given by repeating it
            ``weight`` times under its one id (one unit for held-out folds and paired tests).

    Raises:
        DataError: ``train`` has no cluster column and not whole ``size``-row clusters.
        ModelError: ``weight`` is not a positive integer.
    """
    if isinstance(weight, bool) or not isinstance(weight, (int, np.integer)) or not 1 <= weight <= MAX_ADD_WEIGHT:
        raise ModelError(f"the weight of added poses must be an integer in 1..{MAX_ADD_WEIGHT}, got {weight!r}")
    if not added:
        return train
    own = standalone_mask(train)
    ids = np.where(own, train.extra["cluster"] if own.any() else 0, train.clusters(size)).astype(float)
    start = STANDALONE - (int(-ids[own].min()) if own.any() else 0)  # below the training's own stand-alone ids
    n_added = sum(len(r) for r in added)
    repeat = np.repeat(np.arange(n_added), weight)  # pose j's rows, weight of them, in the added order
    common = [k for k in train.extra if k != "cluster" and all(k in r.extra for r in added)]
    extra = {k: np.concatenate([np.asarray(train.extra[k], dtype=float),
                                np.concatenate([np.asarray(r.extra[k], dtype=float) for r in added])[repeat]])
             for k in common}
    extra["cluster"] = np.concatenate([ids, (start - np.arange(n_added, dtype=float))[repeat]])
    q_add, p_add, quat_add = (np.concatenate([getattr(r, f) for r in added])[repeat] for f in ("q", "p", "quat"))
    source = " + ".join([train.source] + [r.source for r in added])
    return Recording(np.concatenate([train.q, q_add]), np.concatenate([train.p, p_add]),
                     np.concatenate([train.quat, quat_add]), extra, source)


def copy_rows(source: str | Path, rows: np.ndarray, path: str | Path, rec: Recording | None = None) -> None:
    """Write rows ``rows`` (0-based data rows, as :func:`read_recording` numbers the samples) of the recording
    ``source`` to ``path`` as they are there: a CSV's header and those lines' fields unchanged (no number is
    reformatted), atomically. A Welding_Motoman folder has no one file to copy from: its samples ``rec`` (read
    from it) are written as a recording CSV (:func:`write_recording`)."""
    rows = np.asarray(rows, dtype=int)
    if Path(source).is_dir():
        if rec is None:
            raise DataError(source, None, None, "a folder's rows are written from its recording; none given")
        write_recording(rec.subset(rows), path)
        return
    table = _read_rows(Path(source))
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(table[0])
    w.writerows(table[1 + int(i)] for i in rows)
    atomic_write_text(path, buf.getvalue())


def read_joints(path: str | Path, lower: np.ndarray | None = None, upper: np.ndarray | None = None) -> np.ndarray:
    """Read joint angles [rad] for prediction: a header row with q1..q6, or a headerless 6-column file.

    Args:
        path: the joint file.
        lower, upper: joint limits [rad], shape (6,); when given, a row outside them is an error.

    Returns:
        shape (N, 6).
    """
    path = Path(path)
    rows = _read_rows(path)
    if not rows:
        raise DataError(path, None, None, "empty file")
    headerless = not any(c.strip() in JOINT_COLUMNS for c in rows[0])
    if headerless:
        _, q, first = _read_table(path, JOINT_COLUMNS)
    else:
        names, data, first = _read_table(path, None, JOINT_COLUMNS)
        missing = [c for c in JOINT_COLUMNS if c not in names]
        if missing:
            raise DataError(path, 1, missing[0],
                            "required column missing (need q1..q6 in rad, or no header and 6 columns)")
        q = np.stack([data[:, names.index(c)] for c in JOINT_COLUMNS], axis=1)
    _check_limits(path, q, first, lower, upper)
    return q


def write_table(path: str | Path, columns: dict[str, np.ndarray]) -> None:
    """Write named columns as a CSV with a header, atomically (a crash leaves no half-written file)."""
    names = list(columns)
    data = np.column_stack([np.asarray(columns[n], dtype=float) for n in names])
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(names)
    w.writerows([repr(float(v)) for v in row] for row in data)
    atomic_write_text(path, buf.getvalue())


def write_recording(rec: Recording, path: str | Path) -> None:
    """Write a recording CSV (required columns first, then the extra columns), atomically."""
    cols: dict[str, np.ndarray] = {c: rec.q[:, i] for i, c in enumerate(JOINT_COLUMNS)}
    cols.update({c: rec.p[:, i] for i, c in enumerate("xyz")})
    cols.update({c: rec.quat[:, i] for i, c in enumerate(("qw", "qx", "qy", "qz"))})
    cols.update(rec.extra)
    write_table(path, cols)


#: The quaternion order check refuses a recording whose orientations, read in the format's (w, x, y, z) order, scatter
#: by more than this around their best constant tool offset from the nominal model [deg] (median) ...
QUAT_ORDER_SPREAD_DEG = 2.0
#: ... while read in Motive's own (x, y, z, w) order they scatter this many times less. Every Welding_Motoman day
#: (both folders, 16 recordings): 0.04-0.07 deg as stored, 16-44 deg in the other order.
QUAT_ORDER_RATIO = 10.0


def _offset_spread_deg(R_nominal: np.ndarray, R_measured: np.ndarray) -> float:
    """Median angle [deg] of the measured orientations from the nominal ones times their best constant offset on the
    tool side (the chordal mean of ``R_nominal^T R_measured``): small when the marker frame is rigidly on the
    tool, whatever the tool frame's orientation."""
    offsets = np.swapaxes(R_nominal, 1, 2) @ R_measured
    U, _, Vt = np.linalg.svd(offsets.mean(axis=0))
    mean = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    return float(np.degrees(np.median(np.linalg.norm(so3.log(np.swapaxes(offsets, 1, 2) @ mean), axis=1))))


class PoseModel(Protocol):
    """Anything with forward kinematics (a :class:`calibration.kinematics.poe.PoeModel` or a fitted model)."""

    def fk(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Tool pose ``(R (N, 3, 3), p (N, 3) [mm])`` at joint angles q [rad] (N, n)."""
        ...


def check_quaternion_order(rec: Recording, nominal: PoseModel, columns: str = "qw, qx, qy, qz") -> None:
    """Refuse a recording whose quaternions are stored x, y, z, w (Motive's order) under the format's w, x, y, z
    columns: read as they are, its orientations would fit a model ~20-40 deg off.

    Both orders are compared against the nominal model (the arm's geometry and tool from the cell): the one the
    format says must fit it (up to a constant tool offset) at least :data:`QUAT_ORDER_RATIO` times better than the
    other whenever it is off by more than :data:`QUAT_ORDER_SPREAD_DEG`.

    Args:
        rec: the recording as read.
        nominal: the arm's nominal model (``fk(q) -> (R (N, 3, 3), p)``), its tool included.
        columns: how the message names the quaternion columns.

    Raises:
        DataError: naming the file and the columns, with both orders' spreads.
    """
    if len(rec) < 3:
        return
    R_nominal, _ = nominal.fk(rec.q)
    as_read = _offset_spread_deg(R_nominal, rec.R)
    if not as_read > QUAT_ORDER_SPREAD_DEG:
        return
    other = _offset_spread_deg(R_nominal, so3.quat_to_R(rec.quat[:, [3, 0, 1, 2]]))
    if other * QUAT_ORDER_RATIO < as_read:
        raise DataError(rec.source, None, columns,
                        f"the quaternions look stored in x, y, z, w order (Motive's), not w, x, y, z: against the "
                        f"nominal model they scatter {as_read:.1f} deg (median) as read and {other:.2f} deg read as "
                        "x, y, z, w; write them in the order qw, qx, qy, qz")
