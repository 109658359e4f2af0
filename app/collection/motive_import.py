"""Import of Motive's CSV export (OptiTrack) into a cellcal recording.

The layout Motive writes with "Header information" on (Motive 2.x / 3.x, "Data Export: CSV"):

    Format Version,1.23,Take Name,...,Rotation Type,Quaternion,Length Units,Meters,Coordinate Space,Global
    (blank)
    ,Type,Rigid Body,Rigid Body,...           asset type of each column
    ,Name,weldgun,weldgun,...                 asset name
    ,ID,1,1,...                               asset id (Motive 3 may add a ,Parent, row)
    ,,Rotation,Rotation,Rotation,Rotation,Position,Position,Position,...
    Frame,Time (Seconds),X,Y,Z,W,X,Y,Z,...
    0,0.000000,...                            one row per frame; an occluded frame has blank cells

A rigid body's quaternion is scalar-last (X, Y, Z, W, as the axis row names it); cellcal's recordings are
scalar-first (qw, qx, qy, qz). Positions are in the header's ``Length Units`` (Meters, Centimeters or
Millimeters) and become millimetres. Columns are found by their Type/Name/kind/axis labels, never by position.

The joint file gives, per pose, the joint angles (``q1..q6`` [rad] or ``q1_deg..q6_deg`` [deg], as the pendant
shows them) and the dwell window in the take's time (``t_start_s``, ``t_end_s`` [s], Motive's "Time (Seconds)"):
each pose's marker pose is the mean of the rigid body's tracked frames in its window (positions averaged,
quaternions sign-aligned, averaged and normalised), with the frame count in the ``frames`` column. The pose
stays in Motive's frame, as ``cellcal collect`` records it (the fit identifies the base frame).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calibration.data.files import MAX_INPUT_BYTES
from calibration.data.recording import JOINT_COLUMNS, Recording, csv_rows
from calibration.errors import DataError

#: Motive's ``Length Units`` -> millimetres per unit.
LENGTH_UNITS_MM = {"Meters": 1000.0, "Centimeters": 10.0, "Millimeters": 1.0}
LABEL_ROWS = ("Type", "Name", "ID", "Parent")
WINDOW_COLUMNS = ("t_start_s", "t_end_s")


@dataclass(frozen=True)
class MotiveRigidBody:
    """One rigid body's frames from a Motive CSV export.

    Attributes:
        name: the rigid body's name.
        t_s: frame times [s], shape (F,).
        p_mm: positions [mm], shape (F, 3); NaN where the body was not tracked.
        quat_wxyz: orientations, scalar first, shape (F, 4); NaN where not tracked.
    """

    name: str
    t_s: np.ndarray
    p_mm: np.ndarray
    quat_wxyz: np.ndarray


#: A tracked frame's quaternion norm may differ from 1 by this much (Motive writes 6 decimals of a unit quaternion).
QUAT_NORM_TOL = 1e-3
#: Largest coordinate of a tracked frame [mm]: 1 km, far beyond any capture volume (a larger one is a corrupt cell).
MAX_POSITION_MM = 1e6


def _cells(row: list[str]) -> list[str]:
    return [c.strip() for c in row]


def _csv_rows(path: Path) -> list[list[str]]:
    """The rows of the CSV file ``path``, cells stripped (:func:`calibration.data.recording.csv_rows`: every reading
    failure is one line naming the file)."""
    return [_cells(r) for r in csv_rows(path, MAX_INPUT_BYTES)]


def read_motive_csv(path: str | Path, rigid_body: str) -> MotiveRigidBody:
    """The frames of ``rigid_body`` in a Motive CSV export.

    Raises:
        DataError: not a Motive export with its header, a rotation type other than Quaternion, unknown length
            units, the rigid body missing (the message lists those present) or a malformed number.
    """
    path = Path(path)
    rows = _csv_rows(path)
    if not rows or not rows[0] or rows[0][0] != "Format Version":
        raise DataError(path, 1, None, "not a Motive CSV export: expected 'Format Version,...' on the first row "
                                       "(export with Header information on)")
    meta = dict(zip(rows[0][0::2], rows[0][1::2]))
    if meta.get("Rotation Type") != "Quaternion":
        raise DataError(path, 1, "Rotation Type", f"is {meta.get('Rotation Type')!r}; export with Rotation Type "
                                                  "Quaternion")
    unit = meta.get("Length Units")
    if unit not in LENGTH_UNITS_MM:
        raise DataError(path, 1, "Length Units", f"is {unit!r}; expected one of {', '.join(LENGTH_UNITS_MM)}")
    labels: dict[str, list[str]] = {}
    kinds, axes, first = None, None, None
    for i, r in enumerate(rows[1:], start=2):
        label = r[1] if len(r) > 1 and r[0] == "" else (r[0] if r else "")
        if label in LABEL_ROWS:
            labels[label] = r
        elif len(r) > 2 and r[0] == "" and r[1] == "" and {"Rotation", "Position"} & set(r[2:]):
            kinds = r
        elif r and r[0] == "Frame":
            axes, first = r, i + 1
            break
    if "Type" not in labels or "Name" not in labels or kinds is None or axes is None or first is None:
        raise DataError(path, None, None, "no Type, Name, Rotation/Position and Frame header rows; expected "
                                          "Motive's CSV export layout")

    def at(row: list[str], c: int) -> str:
        return row[c] if c < len(row) else ""

    columns: dict[tuple[str, str], int] = {}
    bodies = set()
    for c in range(2, len(axes)):
        if at(labels["Type"], c) != "Rigid Body":
            continue
        bodies.add(at(labels["Name"], c))
        if at(labels["Name"], c) == rigid_body:
            columns.setdefault((at(kinds, c), at(axes, c)), c)
    need = [("Rotation", a) for a in "XYZW"] + [("Position", a) for a in "XYZ"]
    missing = [k for k in need if k not in columns]
    if missing:
        found = ", ".join(sorted(b for b in bodies if b)) or "none"
        raise DataError(path, None, rigid_body, f"no rigid body {rigid_body!r} with {missing[0][0]} "
                                                f"{missing[0][1]} (rigid bodies: {found})")
    data = rows[first - 1:]
    n = len(data)
    t = np.empty(n)
    values = np.full((n, 7), np.nan)
    order = [columns[k] for k in need]
    for k, r in enumerate(data):
        row = first + k
        t[k] = _number(path, row, "Time (Seconds)", at(r, 1))
        for j, c in enumerate(order):
            text = at(r, c)
            if text:
                values[k, j] = _number(path, row, f"{need[j][0]} {need[j][1]}", text)
    xyzw, p = values[:, :4], values[:, 4:] * LENGTH_UNITS_MM[unit]
    return MotiveRigidBody(rigid_body, t, p, xyzw[:, [3, 0, 1, 2]])


def _number(path: Path, row: int, column: str, text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise DataError(path, row, column, f"expected a number, got {text[:30]!r}") from None
    if not math.isfinite(value):
        raise DataError(path, row, column, f"expected a finite number, got {text[:30]!r}")
    return value


def read_pose_windows(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Joint angles [rad] (N, 6) and dwell windows [s] (N, 2) of a joint file (see the module docstring)."""
    path = Path(path)
    rows = [r for r in _csv_rows(path) if any(r)]
    if not rows:
        raise DataError(path, None, None, "empty joint file")
    header = rows[0]
    deg = all(f"{c}_deg" in header for c in JOINT_COLUMNS)
    joint_names = [f"{c}_deg" for c in JOINT_COLUMNS] if deg else list(JOINT_COLUMNS)
    for name in [*joint_names, *WINDOW_COLUMNS]:
        if name not in header:
            raise DataError(path, 1, name, "required column missing (required: q1..q6 [rad] or q1_deg..q6_deg "
                                           "[deg], t_start_s, t_end_s [s of the Motive take])")
    if len(rows) < 2:
        raise DataError(path, None, None, "no poses: the joint file has a header and no rows")
    table = np.empty((len(rows) - 1, 8))
    for k, r in enumerate(rows[1:]):
        for j, name in enumerate([*joint_names, *WINDOW_COLUMNS]):
            c = header.index(name)
            table[k, j] = _number(path, k + 2, name, r[c] if c < len(r) else "")
        if not table[k, 6] < table[k, 7]:
            raise DataError(path, k + 2, "t_end_s", f"window [{table[k, 6]:g}, {table[k, 7]:g}] s is empty; "
                                                    "expected t_start_s < t_end_s")
    q = np.radians(table[:, :6]) if deg else table[:, :6]
    return q, table[:, 6:]


def _check_frames(body: MotiveRigidBody, frames: np.ndarray, source: str, row: int) -> None:
    """DataError naming the joint-file row of a window whose frames hold a quaternion that is not a unit one (a zero,
    a corrupt cell) or a position beyond any capture volume."""
    quat, p = body.quat_wxyz[frames], body.p_mm[frames]
    with np.errstate(over="ignore", invalid="ignore"):
        norm = np.linalg.norm(quat, axis=1)
        bad = (np.abs(norm - 1.0) > QUAT_NORM_TOL) | (np.abs(p) > MAX_POSITION_MM).any(axis=1)
    if bad.any():
        k = int(np.argmax(bad))
        raise DataError(source, row, "t_start_s", f"the window's frame at {body.t_s[frames[k]]:g} s of {body.name!r} "
                                                  f"has a quaternion of norm {norm[k]:.6g} (not 1) or a position "
                                                  f"{np.abs(p[k]).max():.6g} mm from the origin (over "
                                                  f"{MAX_POSITION_MM:g}); not a tracked pose")


def poses_in_windows(body: MotiveRigidBody, windows_s: np.ndarray, source: str = "",
                     min_frames: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean position [mm] (N, 3), mean quaternion (N, 4) and frame count (N,) of ``body`` in each window.

    Raises:
        DataError: a window holds fewer than ``min_frames`` tracked frames (naming the pose's row).
    """
    tracked = np.isfinite(body.p_mm).all(axis=1) & np.isfinite(body.quat_wxyz).all(axis=1)
    p = np.empty((len(windows_s), 3))
    quat = np.empty((len(windows_s), 4))
    count = np.empty(len(windows_s))
    for k, (t0, t1) in enumerate(windows_s):
        sel = tracked & (body.t_s >= t0) & (body.t_s <= t1)
        if sel.sum() < max(min_frames, 1):  # a window without a frame has no pose, whatever min_frames says
            raise DataError(source, k + 2, "t_start_s", f"the window [{t0:g}, {t1:g}] s holds {int(sel.sum())} "
                                                        f"tracked frames of {body.name!r}, expected at least "
                                                        f"{max(min_frames, 1)}")
        _check_frames(body, np.flatnonzero(sel), source, k + 2)
        qs = body.quat_wxyz[sel]
        qs = qs * np.where(qs @ qs[0] < 0, -1.0, 1.0)[:, None]  # q and -q are one rotation
        mean = qs.mean(axis=0)
        quat[k] = mean / np.linalg.norm(mean)
        p[k] = body.p_mm[sel].mean(axis=0)
        count[k] = sel.sum()
    return p, quat, count


def import_motive(motive: str | Path, joints: str | Path, rigid_body: str, min_frames: int = 1) -> Recording:
    """A recording of the poses of ``joints`` measured in the Motive export ``motive`` (see the module docstring)."""
    q, windows = read_pose_windows(joints)
    body = read_motive_csv(motive, rigid_body)
    p, quat, frames = poses_in_windows(body, windows, str(joints), min_frames)
    return Recording(q, p, quat, {"frames": frames, "t": windows.mean(axis=1)}, str(motive))
