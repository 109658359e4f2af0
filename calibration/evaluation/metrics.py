"""Accuracy statistics and the paper's analysis tables.

Error statistics (Table IV), paired significance tests between methods, correlation of the nominal error
with each joint angle (Table II), spread of local parameters over clusters (Table V), and the singular
values of the Fourier coefficient matrix (Fig. 9).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calibration.data.recording import Recording
from calibration.kinematics.poe import pose_error
from calibration.models import KinematicModel

PERCENTILES = (50, 90, 95, 99)


@dataclass(frozen=True)
class Errors:
    """Per-sample errors of a model on a recording: position [mm] and orientation [deg], each (N,)."""

    position_mm: np.ndarray
    orientation_deg: np.ndarray


def predict(model: KinematicModel, rec: Recording) -> tuple[np.ndarray, np.ndarray]:
    """The poses ``model`` predicts for ``rec``'s samples, (R (N, 3, 3), p (N, 3) [mm]); models whose effects
    depend on the sample's context (time, approach direction, payload...) get the recording's context columns."""
    return model.fk_context(rec.q, rec.context())


def errors(model: KinematicModel, rec: Recording) -> Errors:
    """Errors of ``model`` on ``rec`` (the measured pose against :func:`predict`)."""
    R, p = predict(model, rec)
    dp, dR = pose_error(rec.R, rec.p, R, p)
    return Errors(dp, dR)


def stats(values: np.ndarray) -> dict[str, float]:
    """mean, std, max, rms and percentiles (``p50``..``p99``) of a sample of errors."""
    v = np.asarray(values, dtype=float)
    out = {"mean": float(v.mean()), "std": float(v.std()), "max": float(v.max()),
           "rms": float(np.sqrt(np.mean(v**2)))}
    out.update({f"p{p}": float(np.percentile(v, p)) for p in PERCENTILES})
    return out


def error_stats(e: Errors) -> dict[str, dict[str, float]]:
    """The ``compare`` JSON shape: ``{"position_mm": {...}, "orientation_deg": {...}}``."""
    return {"position_mm": stats(e.position_mm), "orientation_deg": stats(e.orientation_deg)}


def paired_tests(a: np.ndarray, b: np.ndarray) -> dict[str, float]:
    """Paired t-test and Wilcoxon signed-rank test of per-sample errors of two methods on the same samples.

    Returns:
        ``mean_difference`` (a - b) and both p-values.
    """
    from scipy import stats as st

    a, b = np.asarray(a), np.asarray(b)
    diff = a - b
    if np.allclose(diff, 0):
        return {"mean_difference": 0.0, "t_pvalue": 1.0, "wilcoxon_pvalue": 1.0}
    return {"mean_difference": float(diff.mean()), "t_pvalue": float(st.ttest_rel(a, b).pvalue),
            "wilcoxon_pvalue": float(st.wilcoxon(a, b).pvalue)}


def joint_correlation(position_error: np.ndarray, q: np.ndarray) -> list[float]:
    """Pearson correlation of the position error with each joint angle (Table II); NaN for a constant joint."""
    out = []
    for j in range(q.shape[1]):
        if np.ptp(q[:, j]) < 1e-12:
            out.append(float("nan"))
        else:
            out.append(float(np.corrcoef(position_error, q[:, j])[0, 1]))
    return out


def parameter_spread(x: np.ndarray, names: list[str]) -> dict[str, dict[str, float]]:
    """Spread of local parameters over clusters (Table V): mean, std, min, max per parameter."""
    return {n: {"mean": float(x[:, i].mean()), "std": float(x[:, i].std()),
                "min": float(x[:, i].min()), "max": float(x[:, i].max())} for i, n in enumerate(names)}
