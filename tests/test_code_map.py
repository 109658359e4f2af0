"""The code map (docs/code-map.md) has one line per folder of the product, and only folders that exist: a folder
added, moved or removed without its line fails here, so the map a newcomer reads stays the tree on disk."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("calibration", "cell_config", "drivers", "app")


def _folders_on_disk() -> set[str]:
    found = {f"{p}/" for p in PACKAGES}
    for package in PACKAGES:
        found |= {f"{d.relative_to(ROOT).as_posix()}/" for d in (ROOT / package).rglob("*")
                  if d.is_dir() and (d / "__init__.py").exists()}
    found |= {f"{d.relative_to(ROOT).as_posix()}/" for d in (ROOT / "scripts").iterdir()
              if d.is_dir() and any(d.glob("*.py"))}
    return found | {"tests/"}


def _folders_on_the_map() -> set[str]:
    text = (ROOT / "docs" / "code-map.md").read_text()
    return set(re.findall(r"^\| `([a-z_/]+/)` \|", text, flags=re.MULTILINE))


def test_every_folder_has_its_line_on_the_code_map_and_every_line_a_folder():
    on_disk, on_map = _folders_on_disk(), _folders_on_the_map()
    assert on_disk - on_map == set(), f"folders without a line in docs/code-map.md: {sorted(on_disk - on_map)}"
    assert on_map - on_disk == set(), f"lines of docs/code-map.md naming no folder: {sorted(on_map - on_disk)}"


def test_the_loose_modules_the_map_names_exist():
    """Every ``name.py`` the map names in a folder's line is a module of that folder (or one of its subfolders)."""
    text = (ROOT / "docs" / "code-map.md").read_text()
    missing = []
    for folder, line in re.findall(r"^\| `([a-z_/]+/)` \| (.*)$", text, flags=re.MULTILINE):
        if folder in ("tests/",):
            continue
        for name in re.findall(r"`([a-z_0-9]+\.py)`", line):
            if not list((ROOT / folder).rglob(name)):
                missing.append(f"{folder}{name}")
    assert not missing, f"docs/code-map.md names modules that do not exist: {missing}"
