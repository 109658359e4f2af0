"""The names of the calibration methods, and so of what a model file's ``method`` may say: static tuples, no
imports, so the model checks (a lower layer) and the fitting methods read the same list."""

from __future__ import annotations

from calibration.errors import ModelError

CONSTANT_METHODS = ("nominal", "base", "cpa", "nls0", "nls1")


#: The interpolators of the CDC methods (calibration.interpolation).
CDC_INTERPOLATORS = ("nearest", "linear", "cubic", "rbf", "fbf13", "fbf7", "nn", "ae")


#: What the local fits of a CDC method vary around: the paper's purely geometric reference, or the pi model.
CDC_REFERENCES = ("geometric", "pi")


PAPER_CDC_METHODS = CDC_INTERPOLATORS


PI_CDC_METHODS = tuple(f"pi+{k}" for k in CDC_INTERPOLATORS)


CDC_METHODS = PAPER_CDC_METHODS + PI_CDC_METHODS


PHYSICS_METHODS = ("pi", "diagnosed")


#: CDC methods whose fit is a network training (seconds): their held-out folds train in parallel worker processes.
NEURAL_METHODS = ("nn", "ae", "pi+nn", "pi+ae")


#: The constant fit each CDC reference is (what a CDC method's held-out figures are set against).
REFERENCE_FITS = {"geometric": "nls1", "pi": "pi"}


METHODS = CONSTANT_METHODS + PAPER_CDC_METHODS + PHYSICS_METHODS + PI_CDC_METHODS


def cdc_method(method: str) -> tuple[str, str]:
    """``(reference, interpolator)`` of a CDC method: ``fbf13`` -> ``("geometric", "fbf13")``, ``pi+fbf13`` ->
    ``("pi", "fbf13")``.

    Raises:
        ModelError: not a CDC method.
    """
    reference, _, kind = method.rpartition("+")
    reference = reference or "geometric"
    if reference not in CDC_REFERENCES or kind not in CDC_INTERPOLATORS:
        raise ModelError(f"{method!r} is not a CDC method; valid: {', '.join(CDC_METHODS)}")
    return reference, kind
