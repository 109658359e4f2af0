"""The cell's registration file: where each arm's base and marker are, as measured by ``cellcal register``.

One YAML mapping ``robot -> entry`` (every pose in millimetres, rotations orthonormal)::

    R1:
      T_world_base: [[...], [...], [...], [0.0, 0.0, 0.0, 1.0]]     # base in the mocap world (4, 4) [mm]
      T_flange_marker: [[...], ...]                                  # marker rigid body in the flange (4, 4) [mm]
      date: '2026-12-01T16:00:00+00:00'                              # ISO 8601
      rms_mm: 0.21
      rms_deg: 0.05
      n_samples: 24
      sigma_world_base: [x, y, z, rx, ry, rz]                        # 1-sigma [mm, mm, mm, deg, deg, deg]
      sigma_flange_marker: [x, y, z, rx, ry, rz]

:func:`save_registration` replaces one robot's entry atomically and keeps the others; floats are written
with ``repr`` so a save/load round trip is bit-identical.
"""

from __future__ import annotations

import os
import stat
from collections.abc import Mapping
from dataclasses import dataclass
from datetime import date as _date
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from calibration.data.files import atomic_write_text
from calibration.errors import ConfigError, OutputError
from cell_config._yaml import Node, read_yaml

_HEADER = """\
# Cell registration, written by cellcal (cell_config.save_registration); one entry per robot.
# T_world_base: the robot base in the mocap world frame, 4x4 homogeneous [mm].
# T_flange_marker: the marker rigid body in the flange frame, 4x4 homogeneous [mm].
# date: when it was measured (ISO 8601). rms_mm / rms_deg: fit residuals over n_samples poses.
# sigma_world_base / sigma_flange_marker: 1-sigma of x, y, z [mm] and rx, ry, rz [deg].
# Rewritten whole on every save: edits to these comments are not kept.
"""
_FIELDS = ("T_world_base", "T_flange_marker", "date", "rms_mm", "rms_deg", "n_samples", "sigma_world_base",
           "sigma_flange_marker")
_RIGID_ATOL = 1e-6


@dataclass(frozen=True)
class RobotRegistration:
    """One arm's registration in the mocap world.

    Attributes:
        T_world_base: the robot base in the mocap world frame, shape (4, 4) [mm].
        T_flange_marker: the marker rigid body in the flange frame, shape (4, 4) [mm].
        date: when it was measured, ISO 8601.
        rms_mm: position residual RMS [mm].
        rms_deg: orientation residual RMS [deg].
        n_samples: number of poses the fit used.
        sigma_world_base: 1-sigma of T_world_base, shape (6,) [mm, mm, mm, deg, deg, deg].
        sigma_flange_marker: 1-sigma of T_flange_marker, shape (6,) [mm, mm, mm, deg, deg, deg].
    """

    T_world_base: np.ndarray
    T_flange_marker: np.ndarray
    date: str
    rms_mm: float
    rms_deg: float
    n_samples: int
    sigma_world_base: np.ndarray
    sigma_flange_marker: np.ndarray


def check_rigid(node: Node, key: str, T: np.ndarray) -> np.ndarray:
    """Refuse a (4, 4) that is not a finite rigid transform (orthonormal rotation, det +1, last row 0 0 0 1)."""
    R = T[:3, :3]
    if not np.all(np.isfinite(T)):
        raise node.error(key, "expected finite numbers")
    if not np.allclose(R @ R.T, np.eye(3), atol=_RIGID_ATOL):
        raise node.error(key, "expected a rigid transform: the rotation block is not orthonormal")
    if np.linalg.det(R) < 0:
        raise node.error(key, "expected a rigid transform: the rotation block has det -1 (a reflection)")
    if not np.array_equal(T[3], [0.0, 0.0, 0.0, 1.0]):
        raise node.error(key, f"expected a rigid transform with last row [0, 0, 0, 1], got {T[3].tolist()}")
    return T


def _read_entry(node: Node) -> RobotRegistration:
    node.only(_FIELDS)
    raw_date = node.get("date")
    if isinstance(raw_date, (datetime, _date)):  # an unquoted timestamp typed by hand
        raw_date = raw_date.isoformat()
    if not isinstance(raw_date, str):
        raise node.error("date", f"expected an ISO 8601 date string, got {raw_date!r}")
    try:
        datetime.fromisoformat(raw_date)
    except ValueError as e:
        raise node.error("date", f"expected an ISO 8601 date string, got {raw_date!r}") from e
    sigmas = {}
    for key in ("sigma_world_base", "sigma_flange_marker"):
        sigmas[key] = node.array(key, (6,))
        if np.any(sigmas[key] < 0):
            raise node.error(key, "expected non-negative standard deviations [mm, mm, mm, deg, deg, deg]")
    return RobotRegistration(
        T_world_base=check_rigid(node, "T_world_base", node.array("T_world_base", (4, 4))),
        T_flange_marker=check_rigid(node, "T_flange_marker", node.array("T_flange_marker", (4, 4))),
        date=raw_date,
        rms_mm=node.number("rms_mm", lo=0.0),
        rms_deg=node.number("rms_deg", lo=0.0),
        n_samples=node.integer("n_samples", lo=1),
        **sigmas,
    )


def _parse(path: Path, data: Any) -> dict[str, RobotRegistration]:
    if data is None:  # an empty file
        return {}
    top = Node(path, data)
    regs = {}
    for robot in top.data:
        if not isinstance(robot, str) or not robot:
            raise ConfigError(path, str(robot), "expected a robot name (R1, R2) as key")
        regs[robot] = _read_entry(top.child(robot))
    return regs


def load_registration(path: str | Path) -> dict[str, RobotRegistration]:
    """Load a registration file: robot name -> :class:`RobotRegistration`.

    Raises:
        ConfigError: the file is missing, is not valid YAML, or an entry is malformed (names the key).
    """
    path = Path(path)
    return _parse(path, read_yaml(path))


def _entry_to_yaml(path: Path, robot: str, reg: RobotRegistration) -> dict[str, Any]:
    """Plain Python values (floats are written with repr, exact on reload); junk is left for the checks."""
    def plain(key: str) -> Any:
        value = getattr(reg, key)
        if isinstance(value, np.ndarray):
            if value.dtype.kind not in "fiu":
                raise ConfigError(path, f"{robot}.{key}", f"expected numbers, got an array of {value.dtype}")
            return value.astype(float).tolist()
        return value.item() if isinstance(value, np.generic) else value

    if not isinstance(reg, RobotRegistration):
        raise ConfigError(path, robot, f"expected a RobotRegistration, got {type(reg).__name__}")
    entry = {key: plain(key) for key in _FIELDS}
    for key in ("rms_mm", "rms_deg"):
        if isinstance(entry[key], int) and not isinstance(entry[key], bool):
            entry[key] = float(entry[key])
    return entry


def _existing(path: Path) -> dict[str, RobotRegistration]:
    """The entries already in ``path`` ({} when it does not exist); refuses symlinks and non-regular files."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return {}
    if stat.S_ISLNK(st.st_mode):
        raise ConfigError(path, "", "refusing to replace a symlink; point the cell at the real file")
    if not stat.S_ISREG(st.st_mode):
        raise ConfigError(path, "", "refusing to replace something that is not a regular file")
    return load_registration(path)


def save_registration(path: str | Path, robot: str, reg: RobotRegistration) -> None:
    """Write ``robot``'s registration into ``path``, keeping the other robots already in the file.

    The write is atomic (a temporary file in the same folder, fsynced, then ``os.replace``): a reader sees
    the old file or the new one, and a failure leaves the old file and no temporary behind. A new file gets
    the permissions a plain ``open(path, "w")`` would give (0o666 minus the umask); an existing file keeps
    its mode.

    Raises:
        ConfigError: ``reg`` is malformed (nothing is written), the existing file is malformed, a symlink or
            not a regular file, or the write failed.
    """
    path = Path(path)
    if not isinstance(robot, str) or not robot:
        raise ConfigError(path, "", f"expected a robot name (R1, R2), got {robot!r}")
    entries = {name: _entry_to_yaml(path, name, r) for name, r in _existing(path).items()}
    entries[robot] = _entry_to_yaml(path, robot, reg)
    _read_entry(Node(path, entries[robot], robot))  # the checks a later load makes: refuse before writing
    text = _HEADER + yaml.safe_dump(entries, sort_keys=False, default_flow_style=None, width=200)
    _atomic_write(path, text)


def _atomic_write(path: Path, text: str) -> None:
    try:
        atomic_write_text(path, text)
    except OutputError as e:
        raise ConfigError(path, "", e.reason) from e


def registrations_for(path: Path, robots: Mapping[str, Any]) -> dict[str, RobotRegistration]:
    """The registration file of a cell ({} when it does not exist yet); every entry must name a cell robot."""
    if not path.exists() and not path.is_symlink():
        return {}
    regs = load_registration(path)
    for name in regs:
        if name not in robots:
            raise ConfigError(path, name, f"unknown robot {name!r}; valid: {', '.join(robots)}")
    return regs
