"""Where a model file or a report came from: when, which cellcal, and the sha256 of every input file.

One definition, used by every model file a command writes (``fit``, ``rebase``, ``recalibrate``, ``diagnose
--out``) and by every ``report.html``: ``{"created_utc", "cellcal_version", "inputs": [{"role", "path",
"sha256"}, ...]}``. A Welding_Motoman folder is hashed file by file (the two files the recording reader reads),
so an input listed here can be checked with ``sha256sum``. Model files record it under ``info.provenance``;
files written before it existed simply have none.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
from collections.abc import Iterable
from dataclasses import replace
from pathlib import Path
from typing import Any

from calibration.data.recording import WELDING_LAYOUTS

#: The key of a model file's ``info`` that holds the provenance.
PROVENANCE_KEY = "provenance"


def version() -> str:
    """The installed package's version (the string ``cellcal --version`` prints)."""
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as package_version

    try:
        return package_version("cellcal")
    except PackageNotFoundError:
        return "unknown (not installed)"


def sha256_file(path: str | Path) -> str:
    """Hex sha256 of a file's bytes, read in 1 MiB blocks."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def input_files(path: str | Path) -> list[Path]:
    """The files an input path stands for: itself, or a Welding_Motoman folder's joint and pose files."""

    path = Path(path)
    if not path.is_dir():
        return [path]
    for names in WELDING_LAYOUTS:
        if all((path / n).exists() for n in names):
            return [path / n for n in names]
    return sorted(p for p in path.iterdir() if p.is_file())


def provenance(inputs: Iterable[tuple[str, str | Path | None]], now: _dt.datetime | None = None) -> dict[str, Any]:
    """The provenance record of outputs made from ``inputs``.

    Args:
        inputs: (role, path) pairs, e.g. ``("train", "r1_train.csv")``; a None path is left out.
        now: the creation time (default: the current UTC time).

    Returns:
        ``{"created_utc": ISO 8601 "...Z", "cellcal_version": str, "inputs": [{"role", "path", "sha256"}]}``.
    """
    stamp = (now or _dt.datetime.now(_dt.UTC)).astimezone(_dt.UTC)
    files = []
    for role, path in inputs:
        if path is None:
            continue
        for f in input_files(path):
            files.append({"role": role, "path": str(f), "sha256": sha256_file(f)})
    return {"created_utc": stamp.strftime("%Y-%m-%dT%H:%M:%SZ"), "cellcal_version": version(), "inputs": files}


def with_provenance(model: Any, record: dict[str, Any]) -> Any:
    """A copy of ``model`` whose ``info`` holds ``record`` (the model itself is left as it is)."""
    return replace(model, info={**model.info, PROVENANCE_KEY: record})


def model_provenance(model: Any) -> dict[str, Any] | None:
    """The provenance a model file recorded, or None (a file written before cellcal recorded it)."""
    record = model.info.get(PROVENANCE_KEY)
    return record if isinstance(record, dict) else None
