"""``cellcal init-cell DIR``: an editable cell folder, copied from the packaged cell, that loads as written.

The folder holds ``cell.yaml`` (the arms, their base poses, the commented device blocks) and the robot and tool
YAMLs it names under ``robots/`` and ``tools/`` (paths in ``cell.yaml`` are relative to it, so the folder moves
as a whole). Each file opens with a header naming what it describes and the unit of every key; the packaged
files' own comments follow unchanged. Nothing is overwritten: a folder that already holds one of these files is
refused, naming it.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path

import yaml

from calibration.data.files import atomic_write_text, make_folders
from calibration.errors import CellCalError
from cell_config.loader import DEFAULT_CELL, load_cell

CELL_HEADER = """\
# Your cell, written by `cellcal init-cell`: edit it, then run every command with `cellcal --cell {cell} ...`.
# Paths below (robot:, tool:, registration:) are relative to this file: keep robots/ and tools/ beside it.
# Units: T_cell_base is a 4x4 homogeneous transform, rotation rows then translation [mm], the pose of each arm's
# robot frame (its base) in the cell frame (R1's base); every *_s is seconds, every *_port a TCP/UDP port.
# After `cellcal register` on the cell, put R2's registered base into T_cell_base (register prints the matrix).
#
"""
ROBOT_HEADER = """\
# Robot YAML written by `cellcal init-cell` (one file per arm model; the single source of each physical fact).
# Units: H unit joint axes at q = 0 in the robot frame; P link vectors [mm]; R_flange a rotation; joint limits
# [deg]; max_speed_deg_s [deg/s]; pulses_per_deg [pulses/deg], pulse_zero [pulses]; base_height_mm [mm];
# max_torque_Nm [N m]; links: mass_kg [kg], com_mm [mm]; capsules_mm radii [mm].
#
"""
TOOL_HEADER = """\
# Tool YAML written by `cellcal init-cell`: the mocap marker rigid body an arm carries.
# Units: position_mm [mm] and quaternion_wxyz (scalar first, w x y z) of the marker in the flange frame (z out of
# the flange); rigid_body is the Motive rigid-body name; geometry [mm], for drawing only.
#
"""


@dataclass(frozen=True)
class CellFolder:
    """What ``init-cell`` wrote: the cell file and every file, relative to the folder."""

    cell: Path
    files: tuple[str, ...]


def _texts(source: Path, cell_name: str) -> dict[str, str]:
    """Relative path -> text of every file of the new folder (the source cell's files with their headers)."""
    load_cell(source)  # the source itself is valid
    raw = yaml.safe_load(source.read_text())
    texts = {"cell.yaml": CELL_HEADER.format(cell=cell_name) + source.read_text()}
    for entry in raw["robots"].values():
        for key, header in (("robot", ROBOT_HEADER), ("tool", TOOL_HEADER)):
            rel = Path(entry[key])
            if rel.is_absolute() or ".." in rel.parts:
                raise CellCalError(f"{source}: robots.*.{key} {entry[key]} lies outside the cell's folder; init-cell "
                                   "copies files from beside the cell file only")
            texts[rel.as_posix()] = header + (source.parent / rel).read_text()
    return texts


def init_cell(folder: str | Path, source: str | Path = DEFAULT_CELL) -> CellFolder:
    """Write the editable cell folder ``folder`` from the cell ``source`` (the packaged one by default).

    The copy is loaded from a scratch folder before anything is written at ``folder``, so a folder that is
    written loads as written.

    Raises:
        CellCalError: ``folder`` is a file, or already holds one of the files (nothing is written).
    """
    folder, source = Path(folder), Path(source)
    try:
        is_file = folder.exists() and not folder.is_dir()
    except OSError as e:  # a name too long, a loop of links
        raise CellCalError(f"{folder}: cannot be a cell folder ({e.strerror or e})") from e
    if is_file:
        raise CellCalError(f"{folder}: is a file; init-cell writes a folder (give a new or empty folder)")
    cell_file = folder / "cell.yaml"
    texts = _texts(source, str(cell_file).encode("unicode_escape").decode("ascii"))  # one comment line
    clash = [rel for rel in texts if (folder / rel).exists() or (folder / rel).is_symlink()]
    if clash:
        raise CellCalError(f"{folder / clash[0]}: already exists; init-cell does not overwrite a cell folder's files "
                           f"({len(clash)} of its {len(texts)} are there); give a new folder")
    with tempfile.TemporaryDirectory(prefix="cellcal_init_") as scratch:
        for rel, text in texts.items():
            (Path(scratch) / rel).parent.mkdir(parents=True, exist_ok=True)
            (Path(scratch) / rel).write_text(text)
        load_cell(Path(scratch) / "cell.yaml")  # a ConfigError here is cellcal's bug, not the user's
    for rel, text in texts.items():
        make_folders((folder / rel).parent)
        atomic_write_text(folder / rel, text)
    return CellFolder(cell_file, tuple(texts))
