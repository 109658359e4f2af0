"""The results of a diagnosis as frozen dataclasses, and their ``cellcal.diagnose/1`` JSON form.

The JSON keys are documented in ``docs/formats/diagnose-json.md``. Beyond the first report's keys, keys say what
the data could not show: ``not_identifiable`` (candidates the geometric fit absorbs or the data barely excite),
``untested`` (candidates whose driving column is missing from the data) and ``rejected_on_heldout``
(selected on the fit data, not confirmed on the held-out data), plus ``noise_estimates_mm`` and ``notes``; the orientation channel's floor (``noise_floor_deg``,
``noise_estimates_deg``) and the weight both channels were weighed with (``orientation_weight``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from calibration.diagnosis.candidates import Untested
from calibration.diagnosis.drivers import Driver, Mismatch
from calibration.diagnosis.noise import NoiseFloor
from calibration.models import KinematicModel

SCHEMA = "cellcal.diagnose/1"


@dataclass(frozen=True)
class Accuracy:
    """Held-out accuracy of one model.

    Attributes:
        model: its name (``geometric``, ``geometric+joint_compliance``).
        rms_mm, max_mm: position error RMS and max [mm].
        rms_deg, max_deg: orientation error RMS and max [deg].
    """

    model: str
    rms_mm: float
    max_mm: float
    rms_deg: float
    max_deg: float

    @classmethod
    def of(cls, model: str, position_mm: np.ndarray, orientation_deg: np.ndarray) -> Accuracy:
        return cls(model, float(np.sqrt(np.mean(position_mm**2))), float(np.max(position_mm)),
                   float(np.sqrt(np.mean(orientation_deg**2))), float(np.max(orientation_deg)))

    def to_json(self) -> dict[str, Any]:
        return {"model": self.model, "heldout_rms_mm": self.rms_mm, "heldout_max_mm": self.max_mm,
                "heldout_rms_deg": self.rms_deg, "heldout_max_deg": self.max_deg}


@dataclass(frozen=True)
class EffectEvidence:
    """Why an effect was kept or rejected, as reported (the rule reads
    :class:`calibration.diagnosis.selection.Evidence`).

    Attributes:
        delta_bic: BIC of the final model minus that of the final model without this effect (fit data).
        f_pvalue: nested F-test p-value of the same comparison.
        cv_z: z-score of the cross-validated held-out improvement when the effect was selected (None when the
            selection judged the fit data only).
        before, after: held-out accuracy of the model with the effects kept before it, and with it too.
        heldout_z: z-score of the per-sample held-out improvement (the confirmation on held-out data).
    """

    delta_bic: float
    f_pvalue: float
    cv_z: float | None
    before: Accuracy
    after: Accuracy
    heldout_z: float = float("nan")

    def to_json(self) -> dict[str, Any]:
        return {"delta_bic": self.delta_bic, "f_pvalue": self.f_pvalue, "cv_z": self.cv_z, "heldout_z": self.heldout_z,
                "heldout_rms_mm_before": self.before.rms_mm, "heldout_rms_mm_after": self.after.rms_mm,
                "heldout_max_mm_before": self.before.max_mm, "heldout_max_mm_after": self.after.max_mm}


@dataclass(frozen=True)
class FoundEffect:
    """One left-out effect, modelled.

    Attributes:
        kind: effect kind.
        joints: 1-based joints (empty for links or latency).
        links: link names (thermal drift).
        parameters: fitted values, units in the names.
        uncertainty: one-sigma uncertainty per parameter (None when not estimated).
        evidence: the selection evidence.
        explanation: one plain-language sentence.
    """

    kind: str
    joints: tuple[int, ...]
    links: tuple[str, ...]
    parameters: dict[str, float]
    uncertainty: dict[str, float | None]
    evidence: EffectEvidence
    explanation: str

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"kind": self.kind, "joints": list(self.joints)}
        if self.links:
            out["links"] = list(self.links)
        out.update(parameters=dict(self.parameters), uncertainty=dict(self.uncertainty),
                   evidence=self.evidence.to_json(), explanation=self.explanation)
        return out


@dataclass(frozen=True)
class PlotData:
    """Arrays for the report's plots.

    Attributes:
        fit_residual_mm: baseline position residual norm on the fit data [mm] (N,).
        drivers: the drivers, aligned with ``fit_residual_mm``.
        heldout_before_mm, heldout_after_mm: held-out position errors of baseline and final model [mm] (M,).
    """

    fit_residual_mm: np.ndarray
    drivers: tuple[Driver, ...]
    heldout_before_mm: np.ndarray
    heldout_after_mm: np.ndarray


@dataclass(frozen=True)
class Diagnosis:
    """Everything a diagnosis found.

    Attributes:
        robot: robot name.
        n_fit, n_heldout: sample counts.
        heldout_source: ``"given"`` (a separate recording) or ``"split"`` (clusters set aside from the data).
        noise: noise-floor estimates.
        baseline, final: held-out accuracy of the model in use and of the model with the effects.
        mismatch: the drivers the baseline residual follows, strongest first.
        effects: the effects found.
        not_identifiable: candidates the data cannot identify, with reasons.
        untested: candidates the data cannot test (missing columns), with reasons.
        verdict: plain-language summary.
        model: the refitted model (physics, pi, cdc or diagnosed; see :func:`.model.result_model`).
        notes: further plain-language remarks (observability of the geometry).
        plots: arrays for plots.
        rejected: effects the fit data selected but the held-out data did not confirm (they would not
            extrapolate), with their figures; they are not in ``model``.
        orientation_weight_a: the orientation weight the evidence was weighed with.
        weighting: ``noise`` (from the per-channel noise floors) or ``fixed``.
        days: with several recordings (days), what differs between them
            (:class:`calibration.frames.daydiff.DaysResult`), else None.
        extrapolation: the held-out poses against the saved model's training range
            (:func:`calibration.models.guard.extrapolation`: how many lie outside, by how much, whether the guard
            acted), or None.
    """

    robot: str
    n_fit: int
    n_heldout: int
    heldout_source: str
    noise: NoiseFloor
    baseline: Accuracy
    final: Accuracy
    mismatch: tuple[Mismatch, ...]
    effects: tuple[FoundEffect, ...]
    not_identifiable: tuple[Untested, ...]
    untested: tuple[Untested, ...]
    verdict: str
    model: KinematicModel
    notes: tuple[str, ...] = ()
    plots: PlotData | None = field(default=None, repr=False)
    rejected: tuple[FoundEffect, ...] = ()
    orientation_weight_a: float = float("nan")
    weighting: str = "fixed"
    days: Any = None
    extrapolation: dict[str, Any] | None = None

    def to_json(self) -> dict[str, Any]:
        """The ``cellcal.diagnose/1`` report as plain Python (finite floats; NaN becomes None)."""
        out = {
            "schema": SCHEMA, "robot": self.robot,
            "samples": {"fit": self.n_fit, "heldout": self.n_heldout, "heldout_source": self.heldout_source},
            "noise_floor_mm": self.noise.floor_mm,
            "noise_estimates_mm": {"within_cluster": self.noise.within_cluster_mm,
                                   "fit_residual": self.noise.fit_residual_mm},
            "noise_floor_deg": self.noise.floor_deg,
            "noise_estimates_deg": {"within_cluster": self.noise.within_cluster_deg,
                                    "fit_residual": self.noise.fit_residual_deg},
            "orientation_weight": {"a": self.orientation_weight_a, "source": self.weighting},
            "baseline": self.baseline.to_json(),
            "mismatch": [{"regressor": m.regressor, "correlation": m.correlation, "where": m.where}
                         for m in self.mismatch],
            "effects": [e.to_json() for e in self.effects],
            "rejected_on_heldout": [e.to_json() for e in self.rejected],
            "not_identifiable": [_skipped(u) for u in self.not_identifiable],
            "untested": [_skipped(u) for u in self.untested],
            "final": self.final.to_json(),
            "verdict": self.verdict,
            "notes": list(self.notes),
        }
        if self.days is not None:
            out["days"] = self.days.to_json()
        if self.extrapolation is not None:
            out["extrapolation"] = self.extrapolation
        finite: dict[str, Any] = _finite(out)
        return finite


def _skipped(u: Untested) -> dict[str, Any]:
    return {"kind": u.kind, "on": u.label, "joints": list(u.joints), "reason": u.reason}


def _finite(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    if isinstance(obj, (float, np.floating)):
        return float(obj) if math.isfinite(obj) else None
    if isinstance(obj, np.integer):
        return int(obj)
    return obj
