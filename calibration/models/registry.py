"""The model-kind registry: kind -> class, filled when a kind's module is imported; kind -> module, to import
it on first load. Imports nothing of :mod:`calibration.models` (a kind registers itself through
:meth:`calibration.models.base.KinematicModel.__init_subclass__`)."""

from __future__ import annotations

import importlib
from typing import Any

from calibration.errors import ModelError

#: Where each model kind is defined; imported on first load. Model files store the kind, never these paths.
KIND_MODULES = {"constant": "calibration.models.constant", "cdc": "calibration.models.cdc",
                "pi": "calibration.models.pi", "physics": "calibration.models.physics",
                "diagnosed": "calibration.models.diagnosed", "rebased": "calibration.models.rebased"}
#: kind -> class, filled by KinematicModel.__init_subclass__.
KINDS: dict[str, type[Any]] = {}


def model_class(kind: Any) -> type[Any]:
    """The class of a model kind, imported on first use.

    Raises:
        ModelError: the kind is unknown (the message lists the valid ones).
    """
    if kind in KIND_MODULES and kind not in KINDS:
        importlib.import_module(KIND_MODULES[kind])  # defining the class registers the kind
    if kind not in KINDS:
        raise ModelError(f"unknown model kind {kind!r}; valid: {', '.join(sorted(KIND_MODULES))}")
    return KINDS[kind]
