"""The result of comparing calibration methods on one training/test pair (:class:`Comparison`): what the
workflow computes and the reports render, kept here so a report need not import a workflow."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from calibration.data.recording import Recording
from calibration.evaluation.metrics import (
    Errors,
    error_stats,
    errors,
)
from calibration.models import KinematicModel


@dataclass
class Comparison:
    """Everything ``compare`` reports: per-method models, errors and statistics."""

    robot: str
    models: dict[str, KinematicModel] = field(default_factory=dict)
    fit_seconds: dict[str, float | None] = field(default_factory=dict)
    train_errors: dict[str, Errors] = field(default_factory=dict)
    test_errors: dict[str, Errors] = field(default_factory=dict)
    skipped: dict[str, str] = field(default_factory=dict)
    analysis: dict[str, Any] = field(default_factory=dict)
    # The method to use, chosen without the test recording (see issue 10); None until a selection has been made.
    recommended: str | None = None

    def add(self, name: str, model: KinematicModel, seconds: float | None, train: Recording, test: Recording) -> None:
        """A row: the model, its fit time (None: unknown) and its errors on the training and test data."""
        self.models[name] = model
        self.fit_seconds[name] = seconds
        self.train_errors[name] = errors(model, train)
        self.test_errors[name] = errors(model, test)

    def to_json(self) -> dict[str, Any]:
        """The documented ``compare --json`` shape (plus ``skipped`` and ``analysis``)."""
        methods = {}
        for m, model in self.models.items():
            methods[m] = {"fit_seconds": self.fit_seconds[m], "n_parameters": model.n_parameters,
                          "train": error_stats(self.train_errors[m]), "test": error_stats(self.test_errors[m])}
        return {"robot": self.robot, "methods": methods, "recommended": self.recommended,
                "skipped": self.skipped, "analysis": self.analysis}


def comparison_warnings(cmp: Comparison) -> list[str]:
    """The comparison's own warnings, each once: observability, measurement shifts, then each method's own check
    (nls0's other clusters, a CDC fit's held-out and range checks: "fbf13 may be unstable" ...). ``compare``
    prints them; the report lists them among the conditions of its verdict (the demo prints none of them)."""
    a = cmp.analysis
    texts = [a.get("observability", {}).get("warning"), (a.get("measurement_shift") or {}).get("warning")]
    texts += [m.info.get("warning") for m in cmp.models.values()]
    return [t for t in dict.fromkeys(texts) if t]
