"""The dispatch table of the methods: a method's name -> the function that fits it. Each method family's module fills
it with :func:`register` (:mod:`calibration.methods.constant`, ``pi``, ``cdc_fit``, ``diagnosed``); the fitter
(:class:`calibration.methods.fitter.Fitter`) looks a method up with :func:`fit_function`. Imports nothing of the
package, so a family needs only this to add a method; its name goes to :mod:`calibration.method_names`, the names a
model file may carry."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

#: ``fit(fitter, method) -> model``: the fit of ``method`` on ``fitter``'s training recording and shared fits.
FitFunction = Callable[[Any, str], Any]

_TABLE: dict[str, FitFunction] = {}


def register(*names: str) -> Callable[[FitFunction], FitFunction]:
    """Decorator: ``fit`` fits the methods ``names``.

    Raises:
        ValueError: a name is registered already (two families claiming one method).
    """

    def add(fit: FitFunction) -> FitFunction:
        for name in names:
            if name in _TABLE:
                raise ValueError(f"method {name!r} is registered twice: {_TABLE[name].__module__}."
                                 f"{_TABLE[name].__qualname__} and {fit.__module__}.{fit.__qualname__}")
            _TABLE[name] = fit
        return fit

    return add


def fit_function(name: str) -> FitFunction:
    """The function registered for method ``name``.

    Raises:
        KeyError: no family registered it (the caller checks the name against the valid ones first).
    """
    return _TABLE[name]


def registered() -> tuple[str, ...]:
    """Every registered method name, in registration order."""
    return tuple(_TABLE)
