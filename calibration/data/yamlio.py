"""YAML parsed by libyaml under PyYAML's safe constructor: the same objects as ``yaml.safe_load`` in a seventh of
the time (a cell and its four robot and tool files: 45 ms -> 8 ms), PyYAML's pure-Python parser where libyaml is
not built in. Model files (:mod:`calibration.models.base`) and cell files (:mod:`cell_config`) are read with it."""

from __future__ import annotations

from typing import IO, Any

import yaml

#: The loader every cellcal YAML input is parsed with.
SAFE_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def safe_load(stream: str | bytes | IO[str]) -> Any:
    """``yaml.safe_load(stream)`` with :data:`SAFE_LOADER`; raises yaml.YAMLError as it does."""
    return yaml.load(stream, Loader=SAFE_LOADER)
