"""Where the model and the recordings disagree: candidate drivers of the residual and their correlations.

A driver is one per-sample quantity that a left-out effect would follow: a joint angle, the gravity torque
on a joint, the payload torque, time, temperature, an approach direction, a joint speed. The residual of
the model in use is a 6-vector per sample (``[p (mm); w * rotation (rad)]``, see
:func:`calibration.identification.weighted_residuals`); its *multiple correlation* with a driver ``d`` is

    rho(d) = sqrt( sum_k cov(d, r_k)^2 / (var(d) sum_k var(r_k)) )   in [0, 1],

the fraction (square root) of the residual variance a per-component straight line in ``d`` explains.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calibration.errors import ModelError
from calibration.kinematics.poe import PoeModel
from calibration.physics.context import Context
from calibration.physics.gravity import GravityModel, point_mass_torque

N_JOINTS = 6


@dataclass(frozen=True)
class Driver:
    """One candidate driver of the residual.

    Attributes:
        name: plain-language name (``gravity torque joint 2``).
        values: per-sample values, shape (N,).
        unit: unit of ``values`` (``deg``, ``N m``, ``s``, ...).
    """

    name: str
    values: np.ndarray
    unit: str


@dataclass(frozen=True)
class Mismatch:
    """A driver the residual follows.

    Attributes:
        regressor: the driver's name.
        correlation: multiple correlation of the residual 6-vector with the driver, in [0, 1].
        where: the part of the driver's range where the position residual is largest, in words.
        rms_mm_there: position residual RMS in that part [mm].
    """

    regressor: str
    correlation: float
    where: str
    rms_mm_there: float


def drivers(model: PoeModel, q: np.ndarray, context: Context, gravity: GravityModel | None = None) -> list[Driver]:
    """Every candidate driver available on the data.

    Args:
        model: the geometry in use (places the links for the torques).
        q: joint angles [rad], shape (N, 6).
        context: per-sample context (see :meth:`Recording.context`).
        gravity: link masses; without it no gravity-torque drivers.
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    out = [Driver(f"joint {j + 1} angle", np.degrees(q[:, j]), "deg") for j in range(q.shape[1])]
    if gravity is not None:
        tau = gravity.torque(model, q)
        out += [Driver(f"gravity torque joint {j + 1}", tau[:, j], "N m") for j in range(1, q.shape[1])
                if np.ptp(tau[:, j]) > 1e-9]
    if "payload_kg" in context:
        tau_p = point_mass_torque(model, q, np.asarray(context["payload_kg"], dtype=float))
        out.append(Driver("payload x reach (payload torque joint 2)", tau_p[:, 1], "N m"))
    if "t" in context:
        out.append(Driver("time", np.asarray(context["t"], dtype=float), "s"))
    if "temp_c" in context:
        out.append(Driver("temperature", np.asarray(context["temp_c"], dtype=float), "deg C"))
    for i in range(1, 7):
        if f"dir{i}" in context:
            out.append(Driver(f"approach direction joint {i}", np.asarray(context[f"dir{i}"], dtype=float), "sign"))
    if "qd" in context:
        qd = np.asarray(context["qd"], dtype=float)
        out += [Driver(f"joint {j + 1} speed", np.degrees(qd[:, j]), "deg/s") for j in range(qd.shape[1])]
    return out


def multiple_correlation(residual: np.ndarray, d: np.ndarray) -> float:
    """Multiple correlation of residual vectors (N, k) with one driver (N,); 0 for a constant driver."""
    r = residual - residual.mean(axis=0)
    d = np.asarray(d, dtype=float) - np.mean(d)
    vd, vr = float(d @ d), float(np.sum(r * r))
    if vd <= 1e-12 * max(1.0, d.size) or vr <= 0:
        return 0.0
    cov = d @ r
    return float(np.sqrt(np.sum(cov**2) / (vd * vr)))


def _where(values: np.ndarray, err2: np.ndarray, unit: str, bins: int = 4) -> tuple[str, float]:
    """Describe the bin of ``values`` with the largest position RMS, and that RMS [mm]."""
    levels = np.unique(values)
    if levels.size <= 3:  # discrete driver: one bin per value
        groups = [(f"= {v:g}", values == v) for v in levels]
    else:
        edges = np.quantile(values, np.linspace(0, 1, bins + 1))
        idx = np.clip(np.searchsorted(edges, values, side="right") - 1, 0, bins - 1)
        groups = [(f"in [{edges[b]:.4g}, {edges[b + 1]:.4g}] {unit}", idx == b) for b in range(bins)]
    rms = [(float(np.sqrt(err2[m].mean())), label) for label, m in groups if m.any()]
    best, label = max(rms)
    return label, best


def locate_mismatch(residual: np.ndarray, candidates: list[Driver], top: int = 5, min_correlation: float = 0.1
                    ) -> list[Mismatch]:
    """Rank the drivers by their multiple correlation with the residual.

    Args:
        residual: weighted residuals ``[p (mm); w * rotation]``, shape (N, 6).
        candidates: drivers from :func:`drivers`.
        top: at most this many are returned.
        min_correlation: drivers below it are left out.

    Returns:
        The strongest drivers, strongest first.
    """
    residual = np.asarray(residual, dtype=float)
    if residual.ndim != 2 or residual.shape[1] != 6:
        raise ModelError(f"residual must have shape (N, 6), got {residual.shape}")
    err2 = np.sum(residual[:, :3] ** 2, axis=1)
    scored = sorted(((multiple_correlation(residual, d.values), d) for d in candidates), key=lambda s: -s[0])
    out = []
    for rho, d in scored[:top]:
        if rho < min_correlation:
            break
        label, rms = _where(d.values, err2, d.unit)
        out.append(Mismatch(d.name, rho, f"{d.name} {label}: position RMS {rms:.3f} mm "
                                         f"(overall {np.sqrt(err2.mean()):.3f} mm)", rms))
    return out
