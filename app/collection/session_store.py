"""Durable storage of a collection session: one SQLite file in the session folder.

WAL journal with ``synchronous=FULL``: every sample is committed (and on disk) as soon as it exists, so a
killed collector loses at most the sample it was measuring. The plan is stored in the same file. The target
index is the primary key of the samples table: a target is recorded at most once (measured or skipped).

One collector per folder: a :class:`SessionStore` holds an exclusive ``flock`` on ``session.lock`` (with the
holder's pid written in it) for its whole lifetime; the kernel releases it when the process dies, so a killed
collector never leaves a stale lock. A second store on the same folder is refused at once
(:class:`SessionLocked`).

Creation is atomic: the plan, the information and the schema tag are committed in one transaction. A folder
whose ``session.sqlite`` holds no committed plan (a collector killed while creating it) counts as "not yet
created": a new session takes it over and a resume is refused with a clear message.

Why the arms were stopped (alarm, e-stop, lost connection, abort) is kept in an ``events`` table
(:meth:`SessionStore.add_event`, :meth:`SessionStore.events`).

A skipped target records whether its cause was transient (a timeout, lost mocap, no fresh status: worth measuring
again) or lasting (a sample the store refused, a readback outside the limits); a resumed session tries the
transient ones again (:meth:`SessionStore.retriable`; the new row replaces the skipped one in one transaction). A session written before that column existed gets it
when a collector opens it, its skipped rows counting as transient.

A write the disk refuses (full, read-only) raises :class:`SessionWriteFailed`, one line naming the file; what was
committed before stays, and the session resumes once there is room.
"""

from __future__ import annotations

import json
import math
import os
import sqlite3
import sys
import time
from collections.abc import Callable, Sequence
from contextlib import closing
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from app.collection.plans.collection import Plan
from calibration.data.files import ExclusiveLock, InputRefused, LockHeld, check_input_path
from calibration.errors import CellCalError, DataError

DB_NAME = "session.sqlite"
LOCK_NAME = "session.lock"
#: What opening a folder without a session says, by what the command wanted of it: "resume" (collect, and by default)
#: "export" or "recalibrate" (which resume nothing: "nothing to resume" misled users who exported, or recalibrated
#: from, a mistyped folder).
_NOTHING = {"resume": "nothing to resume", "export": "nothing to export", "recalibrate": "nothing to recalibrate from"}
#: How each purpose says a folder without a session comes to hold one.
_START = {"resume": "start a new collect with a plan",
          "export": "check the folder, or collect a session into it first (cellcal collect --robot R --plan PLAN "
                    "--session DIR)",
          "recalibrate": "check the folder, collect a session into it first (cellcal collect --robot R --plan PLAN "
                         "--session DIR), or give recalibrate --plan PLAN instead of --session to collect one"}


def _no_session(purpose: str) -> str:
    """The reason of a folder without any session.sqlite, for ``purpose``."""
    return f"no session here (session.sqlite not found): {_NOTHING[purpose]}; {_START[purpose]}"


def _interrupted(purpose: str) -> str:
    """The reason of a session.sqlite whose creation stopped before the plan was stored, for ``purpose``."""
    return ("no session here: its creation was interrupted before the plan was stored (or the file is empty), "
            f"so there is {_NOTHING[purpose]}; start a new collect with a plan in this folder (it takes it over)")
SCHEMA = "cellcal.session/1"
QUAT_NORM_TOL = 1e-3

_SAMPLE_COLUMNS = (
    ["target_index", "status", "robot", "kind", "cluster"] + [f"q{i}" for i in range(1, 7)]
    + ["x", "y", "z", "qw", "qx", "qy", "qz", "std_pos_mm", "std_rot_deg", "marker_err", "frames", "t"]
    + [f"dir{i}" for i in range(1, 7)] + ["attempts", "reason", "recorded_at", "transient"]
)
#: Columns a measured row holds as numbers (:meth:`SessionStore.add_sample`).
_MEASURED_COLUMNS = ([f"q{i}" for i in range(1, 7)] + ["x", "y", "z", "qw", "qx", "qy", "qz", "marker_err", "frames",
                                                        "t"] + [f"dir{i}" for i in range(1, 7)])
_DDL = f"""
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS samples (
    target_index INTEGER PRIMARY KEY,
    status TEXT NOT NULL CHECK (status IN ('ok', 'skipped')),
    robot TEXT NOT NULL, kind TEXT NOT NULL, cluster INTEGER NOT NULL,
    {", ".join(f"q{i} REAL" for i in range(1, 7))},
    x REAL, y REAL, z REAL, qw REAL, qx REAL, qy REAL, qz REAL,
    std_pos_mm REAL, std_rot_deg REAL, marker_err REAL, frames INTEGER, t REAL,
    {", ".join(f"dir{i} INTEGER" for i in range(1, 7))},
    attempts INTEGER NOT NULL, reason TEXT, recorded_at REAL NOT NULL, transient INTEGER
);
CREATE TABLE IF NOT EXISTS events (
    id INTEGER PRIMARY KEY AUTOINCREMENT, t_wall REAL NOT NULL, robot TEXT NOT NULL, kind TEXT NOT NULL,
    reason TEXT NOT NULL, target_index INTEGER
);
"""

#: Called with a stage name (``"schema"``: the file exists, nothing committed; ``"init"``: inside the creation
#: transaction, before its commit) while a session is created. None in production; a test's child process
#: sets it to hold creation open and be killed there.
creation_hook: Callable[[str], None] | None = None

EventKind = Literal["alarm", "e-stop", "robot-fault", "driver-fault", "connection-lost", "bad-feedback", "aborted"]


class SessionLocked(DataError):
    """Another process holds the session folder (a collector or a resume is running on it).

    Attributes:
        folder: the session folder.
        pid: the process holding it, as written in the lock file (None if unreadable).
    """

    def __init__(self, folder: Path, pid: int | None) -> None:
        self.folder = folder
        self.pid = pid
        holder = f"process {pid}" if pid is not None else "another process (pid unknown)"
        super().__init__(folder, None, None, f"session folder is in use by {holder}; only one collector may use a "
                                             f"session at a time: wait for it to end or stop it, then retry")


class SessionWriteFailed(CellCalError):
    """The session file could not be written (a full disk, a read-only folder): what was committed before is kept.

    Attributes:
        path: the session file.
        reason: SQLite's words.
    """

    def __init__(self, path: Path, reason: str) -> None:
        self.path, self.reason = path, reason
        super().__init__(f"{path}: cannot write the session ({reason}); everything recorded before is kept: free "
                         "space (or fix the folder's permissions), then resume the session")


@dataclass(frozen=True)
class SessionEvent:
    """Why the session stopped the arms, as recorded.

    Attributes:
        t_wall: wall-clock time [s since the epoch].
        robot: the robot whose driver reported it.
        kind: what happened (alarm, e-stop, robot-fault, connection-lost, bad-feedback, aborted).
        reason: the driver's or the session's message.
        target_index: the target being visited, or None.
    """

    t_wall: float
    robot: str
    kind: str
    reason: str
    target_index: int | None = None

    def line(self) -> str:
        """One human-readable line (what ``cellcal collect`` prints)."""
        when = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(self.t_wall))
        at = f" at target {self.target_index}" if self.target_index is not None else ""
        return f"{when} {self.robot} {self.kind}{at}: {self.reason}"


def _folder_lock(folder: Path) -> ExclusiveLock:
    """The exclusive lock of ``<folder>/session.lock`` holding this process's pid; SessionLocked when taken."""
    try:
        return ExclusiveLock(folder / LOCK_NAME, f"{os.getpid()}\n")
    except LockHeld as e:
        raise SessionLocked(folder, int(e.holder) if e.holder.isdigit() else None) from None


@dataclass(frozen=True)
class Sample:
    """One averaged static measurement of a target.

    Attributes:
        target_index: index of the target in the plan.
        q: joint angles read from the controller [rad], shape (6,).
        p: mean tool-marker position [mm], shape (3,).
        quat: mean orientation (w, x, y, z), shape (4,).
        std_pos_mm: RMS distance of the frames from the mean position [mm].
        std_rot_deg: RMS angle of the frames from the mean orientation [deg].
        marker_err: mean marker error of the averaged frames [mm].
        frames: number of frames averaged.
        t: time since the session started [s].
        dirs: sign (-1, 0, +1) of each joint's last motion, shape (6,); 0 = unknown or never moved.
        attempts: measurement attempts it took.
    """

    target_index: int
    q: np.ndarray
    p: np.ndarray
    quat: np.ndarray
    std_pos_mm: float
    std_rot_deg: float
    marker_err: float
    frames: int
    t: float
    dirs: np.ndarray
    attempts: int = 1


class SessionStore:
    """The session's SQLite file. Use as a context manager.

    Args:
        session_dir: the session folder (created when ``create`` is True).
        create: start a new session; False opens an existing one.
        lock: hold the folder lock (a writer); readers pass False.
        purpose: what the caller wants of an existing session (``"resume"``, ``"export"`` or ``"recalibrate"``),
            for the message when there is none.
    """

    def __init__(self, session_dir: str | Path, create: bool = False, *, lock: bool = True,
                 purpose: Literal["resume", "export", "recalibrate"] = "resume") -> None:
        self.dir = Path(session_dir)
        self.path = self.dir / DB_NAME
        if create:
            self.dir.mkdir(parents=True, exist_ok=True)
        elif not self.path.exists():
            raise DataError(self.path, None, None, _no_session(purpose))
        _refuse_special(self.path)  # SQLite blocks forever opening a FIFO
        if not create and not self._created_read_only(self.path):  # read-only: opening must not write tables into it
            raise DataError(self.path, None, None, _interrupted(purpose))
        self._lock = _folder_lock(self.dir) if lock else None
        try:
            self.conn = self._connect()
            if create and self.is_created():
                raise DataError(self.path, None, None, "a session already exists here; resume it or pick a new folder")
            if not create and not self.is_created():
                raise DataError(self.path, None, None, _interrupted(purpose))
        except BaseException:
            self.close()
            raise

    def _connect(self) -> sqlite3.Connection:
        conn = None
        try:
            conn = sqlite3.connect(self.path, timeout=10.0, isolation_level=None)
            conn.execute("PRAGMA journal_mode=WAL")
            conn.execute("PRAGMA synchronous=FULL")
            conn.executescript(_DDL)
            if "transient" not in {r[1] for r in conn.execute("PRAGMA table_info(samples)")} and self._lock is not None:
                conn.execute("ALTER TABLE samples ADD COLUMN transient INTEGER")  # a session of an older cellcal
            return conn
        except sqlite3.DatabaseError as e:
            if conn is not None:
                conn.close()
            if _write_refused(e):
                raise SessionWriteFailed(self.path, str(e)) from e
            raise DataError(self.path, None, None, f"not a usable session database ({e})") from e

    def is_created(self) -> bool:
        """True once the plan is committed (a killed creation leaves a file without one)."""
        return self.conn.execute("SELECT 1 FROM meta WHERE key = 'plan'").fetchone() is not None

    @staticmethod
    def _created_read_only(path: Path) -> bool:
        """True when ``path`` holds a committed plan; False for an empty or half-created file (nothing written).

        Raises:
            DataError: the file is not an SQLite database at all.
        """
        try:
            with closing(sqlite3.connect(f"file:{path}?mode=ro", uri=True, timeout=10.0)) as conn:
                return conn.execute("SELECT 1 FROM meta WHERE key = 'plan'").fetchone() is not None
        except sqlite3.OperationalError:  # no meta table yet: an empty file or a creation killed early
            return False
        except sqlite3.DatabaseError as e:
            raise DataError(path, None, None, f"not a usable session database ({e})") from e

    @staticmethod
    def exists(session_dir: str | Path) -> bool:
        """True when ``session_dir`` holds a fully created session (read-only look, no lock taken)."""
        path = Path(session_dir) / DB_NAME
        if not path.exists():
            return False
        _refuse_special(path)
        try:
            with closing(sqlite3.connect(f"file:{path}?mode=ro", uri=True, timeout=10.0)) as conn:
                return conn.execute("SELECT 1 FROM meta WHERE key = 'plan'").fetchone() is not None
        except sqlite3.DatabaseError:  # no meta table yet, or not a database: no created session
            return False

    def __enter__(self) -> SessionStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Close the database and release the folder lock; safe to call twice."""
        conn = getattr(self, "conn", None)
        if conn is not None:
            conn.close()
            self.conn = None  # type: ignore[assignment]
        if self._lock is not None:
            self._lock.release()

    # ---- metadata and plan -------------------------------------------------------------------------------

    def init(self, plan: Plan, info: dict[str, Any]) -> None:
        """Store the plan and the session information in one transaction (once, when the session is created).

        Until it commits the folder holds no session: a kill before leaves a folder a new session takes over.

        Raises:
            DataError: the folder already holds a created session or recorded rows.
        """
        _hook("schema")
        rows = {"schema": SCHEMA, "plan": json.dumps(plan.to_dict()), "info": json.dumps(info),
                "created_wall": repr(time.time())}
        try:
            self._create(rows)
        except sqlite3.OperationalError as e:
            if _write_refused(e):
                raise SessionWriteFailed(self.path, str(e)) from e
            raise

    def _create(self, rows: dict[str, str]) -> None:
        with self.conn:
            self.conn.execute("BEGIN IMMEDIATE")
            if self.is_created() or self.conn.execute("SELECT 1 FROM samples").fetchone() is not None:
                raise DataError(self.path, None, None, "a session already exists here; resume it or pick a new folder")
            self.conn.execute("DELETE FROM meta")  # leftovers of an interrupted creation (never committed: empty)
            self.conn.executemany("INSERT INTO meta (key, value) VALUES (?, ?)", rows.items())
            _hook("init")

    def _meta(self, key: str) -> str:
        row = self.conn.execute("SELECT value FROM meta WHERE key = ?", (key,)).fetchone()
        if row is None:
            raise DataError(self.path, None, key, "missing from the session (was it created by cellcal?)")
        value: str = row[0]  # the meta table's values are TEXT
        return value

    def _meta_json(self, key: str) -> Any:
        """A metadata value as JSON, refused naming the key when it is not (a damaged or edited database).

        Raises:
            DataError: naming the database and the key.
        """
        try:
            return json.loads(self._meta(key))
        except (ValueError, TypeError, RecursionError) as e:
            raise DataError(self.path, None, key, f"not valid JSON in the session ({e.__class__.__name__}: "
                                                  f"{str(e)[:200]}); was the database edited?") from None

    def plan(self) -> Plan:
        """The plan stored in the session."""
        try:
            return Plan.from_dict(self._meta_json("plan"), str(self.path))
        except (ValueError, TypeError, KeyError, AttributeError, IndexError, RecursionError) as e:
            raise DataError(self.path, None, "plan", f"the session's plan is unusable ({e.__class__.__name__}: "
                                                     f"{str(e)[:200]})") from None

    def info(self) -> dict[str, Any]:
        """Session information (robot, rigid body, options) stored at creation."""
        info = self._meta_json("info")
        if not isinstance(info, dict):
            raise DataError(self.path, None, "info", f"expected a JSON object, found {type(info).__name__}")
        return info

    def robots(self) -> list[str]:
        """Every robot the session names: the one in its information, then any other in its plan or its rows."""
        names = [str(self.info().get("robot", ""))] + list(self.plan().robots)
        names += [r[0] for r in self.conn.execute("SELECT DISTINCT robot FROM samples")]
        return list(dict.fromkeys(n for n in names if n))

    def check_robot(self, robot: str) -> None:
        """Refuse a session collected on another arm than ``robot`` (its information, plan or rows name another).

        Raises:
            DataError: naming the session's robot(s) and ``robot``.
        """
        names = self.robots()
        if names != [robot]:
            raise DataError(self.path, None, "robot", f"the session was collected on {', '.join(names) or 'no robot'}"
                                                      f", not {robot} (--robot {robot}); give the session of {robot}"
                                                      " or the --robot it was collected on")

    def created_wall(self) -> float:
        """Wall-clock creation time [s since the epoch]."""
        return float(self._meta("created_wall"))

    # ---- samples -------------------------------------------------------------------------------------------

    def done(self) -> set[int]:
        """Target indices already recorded (measured or skipped)."""
        return {r[0] for r in self.conn.execute("SELECT target_index FROM samples")}

    def add_sample(self, s: Sample, robot: str, kind: str, cluster: int,
                   lower: np.ndarray | None = None, upper: np.ndarray | None = None, *,
                   replace_skip: bool = False) -> None:
        """Validate and commit one measured sample; nothing is written when a value is unusable. With
        ``replace_skip`` it replaces the target's skipped row (a resume measured it again), in one transaction.

        Raises:
            DataError: non-finite value, quaternion norm off by more than 1e-3, joint outside [lower, upper],
                or the target already recorded.
        """
        _check_sample(self.path, s, lower, upper)
        row = ([s.target_index, "ok", robot, kind, cluster] + [float(v) for v in s.q]
               + [float(v) for v in s.p] + [float(v) for v in s.quat]
               + [s.std_pos_mm, s.std_rot_deg, s.marker_err, int(s.frames), s.t]
               + [int(v) for v in s.dirs] + [s.attempts, None, time.time(), None])
        self._insert(row, replace_skip)

    def add_skipped(self, target_index: int, robot: str, kind: str, cluster: int, reason: str,
                    attempts: int, transient: bool = True, *, replace_skip: bool = False) -> None:
        """Commit a target that could not be measured, with the reason and whether it was transient (a resume
        tries a transient skip again); ``replace_skip`` replaces its earlier skipped row, in one transaction."""
        values = {"target_index": target_index, "status": "skipped", "robot": robot, "kind": kind,
                  "cluster": cluster, "attempts": attempts, "reason": reason, "recorded_at": time.time(),
                  "transient": int(transient)}
        row = [values.get(c) for c in _SAMPLE_COLUMNS]
        self._insert(row, replace_skip)

    def retriable(self, lasting_too: bool = False) -> set[int]:
        """Skipped targets a resume measures again: those skipped for a transient reason (or recorded before the
        cause was kept), and with ``lasting_too`` every skipped one."""
        sql = "SELECT target_index FROM samples WHERE status = 'skipped'"
        if not lasting_too:
            sql += " AND (transient IS NULL OR transient != 0)"
        return {r[0] for r in self.conn.execute(sql)}

    def _insert(self, row: list[Any], replace_skip: bool) -> None:
        sql = f"INSERT INTO samples ({', '.join(_SAMPLE_COLUMNS)}) VALUES ({', '.join('?' * len(_SAMPLE_COLUMNS))})"
        writes = [(sql, row)]
        if replace_skip:  # in the same transaction: a target is never left without its row by a failed write
            writes.insert(0, ("DELETE FROM samples WHERE target_index = ? AND status = 'skipped'", [row[0]]))
        try:
            self._write(*writes)
        except sqlite3.IntegrityError as e:
            raise DataError(self.path, None, f"target {row[0]}", f"already recorded ({e})") from e

    def _write(self, *writes: tuple[str, Sequence[Any]]) -> None:
        """Run the writes in one transaction; a write the disk refuses raises SessionWriteFailed."""
        try:
            with self.conn:
                for sql, args in writes:
                    self.conn.execute(sql, args)
        except sqlite3.OperationalError as e:
            if _write_refused(e):
                raise SessionWriteFailed(self.path, str(e)) from e
            raise

    # ---- events --------------------------------------------------------------------------------------------

    def add_event(self, robot: str, kind: EventKind, reason: str, target_index: int | None = None) -> SessionEvent:
        """Commit why the arms were stopped (at once, like a sample) and return the recorded event."""
        event = SessionEvent(time.time(), robot, kind, reason, target_index)
        self._write(("INSERT INTO events (t_wall, robot, kind, reason, target_index) VALUES (?, ?, ?, ?, ?)",
                     (event.t_wall, robot, kind, reason, target_index)))
        return event

    def events(self) -> list[SessionEvent]:
        """Every recorded event, oldest first."""
        cur = self.conn.execute("SELECT t_wall, robot, kind, reason, target_index FROM events ORDER BY id")
        return [SessionEvent(*r) for r in cur]

    def rows(self, status: Literal["ok", "skipped"] | None = None) -> list[dict[str, Any]]:
        """Recorded rows as dicts ordered by target index, optionally filtered by status."""
        present = {r[1] for r in self.conn.execute("PRAGMA table_info(samples)")}  # a reader of an older session
        columns = [c for c in _SAMPLE_COLUMNS if c in present]
        sql = f"SELECT {', '.join(columns)} FROM samples"
        args: tuple[Any, ...] = ()
        if status is not None:
            sql += " WHERE status = ?"
            args = (status,)
        try:
            cur = self.conn.execute(sql + " ORDER BY target_index", args)
            rows = [dict(zip(columns, r)) for r in cur]
        except sqlite3.DatabaseError as e:  # a damaged page, a table of another layout
            raise DataError(self.path, None, None, f"not a usable session database ({e})") from None
        for r in rows:
            _check_row(self.path, r)
        return rows


def _check_sample(path: Path, s: Sample, lower: np.ndarray | None, upper: np.ndarray | None) -> None:
    """Refuse a sample :meth:`SessionStore.add_sample` must not write: a non-finite or missing value, a quaternion
    that is not unit, a joint outside [lower, upper].

    Raises:
        DataError: naming the database, the target and the value.
    """
    values = np.concatenate([s.q, s.p, s.quat, [s.std_pos_mm, s.std_rot_deg, s.marker_err, s.t]])
    if values.shape != (17,) or not np.all(np.isfinite(values)):
        raise DataError(path, None, f"target {s.target_index}", "sample has non-finite or missing values")
    _check_quat(path, s.quat, f"target {s.target_index}")
    if lower is not None and upper is not None:
        bad = np.flatnonzero((s.q < lower) | (s.q > upper))
        if bad.size:
            j = int(bad[0])
            raise DataError(path, None, f"target {s.target_index}",
                            f"q{j + 1} = {math.degrees(s.q[j]):.6g} deg is outside the joint limits "
                            f"[{math.degrees(lower[j]):.1f}, {math.degrees(upper[j]):.1f}] deg")


def _check_row(path: Path, r: dict[str, Any]) -> None:
    """Refuse a recorded row whose values :meth:`SessionStore.add_sample` would not have written (a damaged or
    edited database): text or NULL where a number belongs, a non-finite number, an unknown status, a quaternion that
    is not unit.

    Raises:
        DataError: naming the database, the target and the column.
    """
    where = f"target {r['target_index']}"
    if not isinstance(r["target_index"], int) or r["status"] not in ("ok", "skipped") \
            or not isinstance(r["robot"], str) or not isinstance(r["kind"], str):
        raise DataError(path, None, where, f"malformed row (status {r['status']!r}, robot {r['robot']!r}, "
                                           f"kind {r['kind']!r})")
    numeric = ["cluster"] + (_MEASURED_COLUMNS if r["status"] == "ok" else [])
    for c in numeric:
        v = r[c]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise DataError(path, None, f"{where}, column {c}", f"expected a finite number, found {v!r}")
    if r["status"] == "ok":
        _check_quat(path, [r[c] for c in ("qw", "qx", "qy", "qz")], where)


def _check_quat(path: Path, quat: Any, where: str) -> None:
    """Refuse a quaternion whose norm is off 1 by more than :data:`QUAT_NORM_TOL` (written or read back)."""
    norm = float(np.linalg.norm(np.asarray(quat, dtype=float)))
    if abs(norm - 1.0) > QUAT_NORM_TOL:
        raise DataError(path, None, where, f"quaternion norm {norm:.6f} is not 1")

def _refuse_special(path: Path) -> None:
    """Refuse a session database that is a FIFO, a device or a socket: SQLite blocked forever opening a FIFO.

    Raises:
        DataError: naming the file and what it is.
    """
    try:
        check_input_path(path, sys.maxsize)
    except InputRefused as e:
        raise DataError(path, None, None, f"not a session database: {e.strerror}") from None


#: SQLite's primary result codes of a write the disk or the folder refused: SQLITE_READONLY, SQLITE_IOERR,
#: SQLITE_FULL, SQLITE_CANTOPEN.
_REFUSED_CODES = {8, 10, 13, 14}


def _write_refused(e: sqlite3.Error) -> bool:
    """True for a write the disk or the folder refused (full, read-only, I/O error)."""
    code = getattr(e, "sqlite_errorcode", None)
    return code is not None and (code & 0xFF) in _REFUSED_CODES


def _hook(stage: str) -> None:
    if creation_hook is not None:
        creation_hook(stage)


def require_session(path: str | Path, robot: str, kinds: tuple[str, ...] = (),
                    purpose: Literal["resume", "recalibrate"] = "resume") -> None:
    """Refuse at once (before any device opens) a folder without a session, or a session of another arm; with
    ``kinds``, also one whose plan still has targets of those kinds neither measured nor skipped (a collection
    stopped half-way: recalibrate fitted and installed a model on what it had measured, without a word).

    Raises:
        DataError: no session there, another process holds it, another arm's, or targets of ``kinds`` left.
    """
    with SessionStore(path, purpose=purpose) as store:  # DataError when there is none or another process holds it
        store.check_robot(robot)
        if kinds:
            wanted = [i for i, t in enumerate(store.plan().targets) if t.kind in kinds]
            left = len(set(wanted) - store.done())
            if left:
                raise DataError(store.path, None, None,
                                f"the session is incomplete: {left} of its {len(wanted)} {'/'.join(kinds)} targets "
                                f"not yet measured; finish it first (cellcal collect --robot {robot} --session "
                                f"{path} --resume)")
