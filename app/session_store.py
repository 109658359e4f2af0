"""Durable storage of a collection session: one SQLite file in the session folder.

WAL journal with ``synchronous=FULL``: every sample is committed (and on disk) as soon as it exists, so a
killed collector loses at most the sample it was measuring. The plan is stored in the same file. The target
index is the primary key of the samples table: a target is recorded at most once (measured or skipped).
"""

from __future__ import annotations

import json
import math
import sqlite3
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from app.planning import Plan
from calibration.errors import DataError

DB_NAME = "session.sqlite"
SCHEMA = "cellcal.session/1"
QUAT_NORM_TOL = 1e-3

_SAMPLE_COLUMNS = (
    ["target_index", "status", "robot", "kind", "cluster"] + [f"q{i}" for i in range(1, 7)]
    + ["x", "y", "z", "qw", "qx", "qy", "qz", "std_pos_mm", "std_rot_deg", "marker_err", "frames", "t"]
    + [f"dir{i}" for i in range(1, 7)] + ["attempts", "reason", "recorded_at"]
)
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
    attempts INTEGER NOT NULL, reason TEXT, recorded_at REAL NOT NULL
);
"""


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
    """

    def __init__(self, session_dir: str | Path, create: bool = False) -> None:
        self.dir = Path(session_dir)
        self.path = self.dir / DB_NAME
        if create:
            if self.path.exists():
                raise DataError(self.path, None, None, "a session already exists here; resume it or pick a new folder")
            self.dir.mkdir(parents=True, exist_ok=True)
        elif not self.path.exists():
            raise DataError(self.path, None, None, "no session here (session.sqlite not found)")
        try:
            self.conn = sqlite3.connect(self.path, timeout=10.0, isolation_level=None)
            self.conn.execute("PRAGMA journal_mode=WAL")
            self.conn.execute("PRAGMA synchronous=FULL")
            self.conn.executescript(_DDL)
        except sqlite3.DatabaseError as e:
            raise DataError(self.path, None, None, f"not a usable session database ({e})") from e

    def __enter__(self) -> "SessionStore":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self.conn.close()

    # ---- metadata and plan -------------------------------------------------------------------------------

    def init(self, plan: Plan, info: dict[str, Any]) -> None:
        """Store the plan and the session information (once, when the session is created)."""
        with self.conn:
            self.conn.execute("BEGIN IMMEDIATE")
            rows = {"schema": SCHEMA, "plan": json.dumps(plan.to_dict()), "info": json.dumps(info),
                    "created_wall": repr(time.time())}
            self.conn.executemany("INSERT INTO meta (key, value) VALUES (?, ?)", rows.items())

    def _meta(self, key: str) -> str:
        row = self.conn.execute("SELECT value FROM meta WHERE key = ?", (key,)).fetchone()
        if row is None:
            raise DataError(self.path, None, key, "missing from the session (was it created by cellcal?)")
        return row[0]

    def plan(self) -> Plan:
        """The plan stored in the session."""
        return Plan.from_dict(json.loads(self._meta("plan")), str(self.path))

    def info(self) -> dict[str, Any]:
        """Session information (robot, rigid body, options) stored at creation."""
        return json.loads(self._meta("info"))

    def created_wall(self) -> float:
        """Wall-clock creation time [s since the epoch]."""
        return float(self._meta("created_wall"))

    # ---- samples -------------------------------------------------------------------------------------------

    def done(self) -> set[int]:
        """Target indices already recorded (measured or skipped)."""
        return {r[0] for r in self.conn.execute("SELECT target_index FROM samples")}

    def add_sample(self, s: Sample, robot: str, kind: str, cluster: int,
                   lower: np.ndarray | None = None, upper: np.ndarray | None = None) -> None:
        """Validate and commit one measured sample; nothing is written when a value is unusable.

        Raises:
            DataError: non-finite value, quaternion norm off by more than 1e-3, joint outside [lower, upper],
                or the target already recorded.
        """
        values = np.concatenate([s.q, s.p, s.quat, [s.std_pos_mm, s.std_rot_deg, s.marker_err, s.t]])
        if values.shape != (17,) or not np.all(np.isfinite(values)):
            raise DataError(self.path, None, f"target {s.target_index}", "sample has non-finite or missing values")
        norm = float(np.linalg.norm(s.quat))
        if abs(norm - 1.0) > QUAT_NORM_TOL:
            raise DataError(self.path, None, f"target {s.target_index}", f"quaternion norm {norm:.6f} is not 1")
        if lower is not None and upper is not None:
            bad = np.flatnonzero((s.q < lower) | (s.q > upper))
            if bad.size:
                j = int(bad[0])
                raise DataError(self.path, None, f"target {s.target_index}",
                                f"q{j + 1} = {math.degrees(s.q[j]):.3f} deg is outside the joint limits "
                                f"[{math.degrees(lower[j]):.1f}, {math.degrees(upper[j]):.1f}] deg")
        row = ([s.target_index, "ok", robot, kind, cluster] + [float(v) for v in s.q]
               + [float(v) for v in s.p] + [float(v) for v in s.quat]
               + [s.std_pos_mm, s.std_rot_deg, s.marker_err, int(s.frames), s.t]
               + [int(v) for v in s.dirs] + [s.attempts, None, time.time()])
        self._insert(row)

    def add_skipped(self, target_index: int, robot: str, kind: str, cluster: int, reason: str,
                    attempts: int) -> None:
        """Commit a target that could not be measured, with the reason."""
        values = {"target_index": target_index, "status": "skipped", "robot": robot, "kind": kind,
                  "cluster": cluster, "attempts": attempts, "reason": reason, "recorded_at": time.time()}
        row = [values.get(c) for c in _SAMPLE_COLUMNS]
        self._insert(row)

    def forget_skipped(self) -> int:
        """Delete skipped rows so a resumed session tries those targets again; returns how many."""
        with self.conn:
            return self.conn.execute("DELETE FROM samples WHERE status = 'skipped'").rowcount

    def _insert(self, row: list[Any]) -> None:
        sql = f"INSERT INTO samples ({', '.join(_SAMPLE_COLUMNS)}) VALUES ({', '.join('?' * len(_SAMPLE_COLUMNS))})"
        try:
            with self.conn:
                self.conn.execute(sql, row)
        except sqlite3.IntegrityError as e:
            raise DataError(self.path, None, f"target {row[0]}", f"already recorded ({e})") from e

    def rows(self, status: Literal["ok", "skipped"] | None = None) -> list[dict[str, Any]]:
        """Recorded rows as dicts ordered by target index, optionally filtered by status."""
        sql = f"SELECT {', '.join(_SAMPLE_COLUMNS)} FROM samples"
        args: tuple[Any, ...] = ()
        if status is not None:
            sql += " WHERE status = ?"
            args = (status,)
        cur = self.conn.execute(sql + " ORDER BY target_index", args)
        return [dict(zip(_SAMPLE_COLUMNS, r)) for r in cur]
