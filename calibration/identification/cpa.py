"""Circular point analysis (CPA): joint axes from single-joint sweeps.

When one joint moves alone, the tool point traces a circle about that joint's axis: the circle's normal
is the axis direction and its centre a point on the axis. Axes are identified in order (joint 1 first) so
each sweep can be mapped back to the zero configuration through the joints already identified.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calibration.data.recording import Recording
from calibration.errors import ModelError
from calibration.kinematics import so3
from calibration.kinematics.arrays import FloatArray
from calibration.kinematics.parameterisation import MinimalParameterisation

MIN_SWEEP_SAMPLES = 4
MIN_SWEEP_RAD = np.radians(5.0)


@dataclass(frozen=True)
class Circle:
    """A circle in space: centre [mm] (3,), unit normal (3,), radius [mm], RMS residual [mm]."""

    centre: np.ndarray
    normal: np.ndarray
    radius: float
    rms_mm: float


def fit_circle(points: np.ndarray) -> Circle:
    """Least-squares 3D circle through points (K, 3): best plane by SVD, then an algebraic circle fit in it."""
    points = np.asarray(points, dtype=float)
    if points.shape[0] < 3:
        raise ModelError(f"a circle needs at least 3 points, got {points.shape[0]}")
    c0 = points.mean(axis=0)
    _, _, Vt = np.linalg.svd(points - c0)
    u, v, n = Vt
    xy = np.stack([(points - c0) @ u, (points - c0) @ v], axis=1)
    A = np.column_stack([2 * xy, np.ones(len(xy))])
    sol, *_ = np.linalg.lstsq(A, np.sum(xy**2, axis=1), rcond=None)
    centre2 = sol[:2]
    radius = float(np.sqrt(sol[2] + centre2 @ centre2))
    centre = c0 + centre2[0] * u + centre2[1] * v
    in_plane = np.linalg.norm(xy - centre2, axis=1) - radius
    out_plane = (points - c0) @ n
    return Circle(centre, n, radius, float(np.sqrt(np.mean(in_plane**2 + out_plane**2))))


def split_sweeps(rec: Recording) -> dict[int, Recording]:
    """Single-joint sweeps of a recording, keyed by 1-based joint.

    Samples are grouped by the ``cluster`` column (one id per sweep); in each group exactly one joint must
    move by at least 5 deg.
    """
    if "cluster" not in rec.extra:
        raise ModelError(f"{rec.source}: CPA needs a cluster column with one id per single-joint sweep")
    sweeps: dict[int, Recording] = {}
    for cid in np.unique(rec.extra["cluster"]):
        sub = rec.subset(rec.extra["cluster"] == cid)
        span = np.ptp(sub.q, axis=0)
        moving = np.flatnonzero(span >= MIN_SWEEP_RAD)
        if len(moving) != 1 or len(sub) < MIN_SWEEP_SAMPLES:
            raise ModelError(f"{rec.source}: cluster {int(cid)} is not a single-joint sweep "
                             f"(joints moving >= 5 deg: {(moving + 1).tolist()}, samples {len(sub)})")
        sweeps[int(moving[0]) + 1] = sub
    return sweeps


def identify_cpa(par: MinimalParameterisation, sweeps: dict[int, Recording]) -> tuple[np.ndarray, list[Circle]]:
    """Minimal parameters from one sweep per joint.

    Returns:
        ``(x (m,), circles)``; the flange point keeps its nominal offset from the last joint origin.
    """
    n = par.n_joints
    missing = [j for j in range(1, n + 1) if j not in sweeps]
    if missing:
        raise ModelError(f"CPA needs a sweep of every joint; missing joints {missing}")
    nominal = par.nominal
    axes: list[FloatArray] = []
    points: list[FloatArray] = []
    circles = []
    for j in range(n):
        sweep = sweeps[j + 1]
        circle = fit_circle(sweep.p)
        # Direction: the rotation must carry the first point toward the later ones with increasing q.
        order = np.argsort(sweep.q[:, j])
        a, b = sweep.p[order[0]] - circle.centre, sweep.p[order[-1]] - circle.centre
        w = circle.normal if np.dot(np.cross(a, b), circle.normal) > 0 else -circle.normal
        # Undo the motion of the joints already identified (others are constant within the sweep).
        q_fixed = sweep.q[order[0]]
        R, t = np.eye(3), np.zeros(3)
        for i in range(j):
            Ri = so3.rot(axes[i], q_fixed[i])
            R, t = R @ Ri, R @ (points[i] - Ri @ points[i]) + t
        h = R.T @ w
        if np.dot(h, nominal.H[:, j]) < 0.9:
            raise ModelError(f"CPA: joint {j + 1} axis {np.round(h, 3).tolist()} is far from nominal "
                             f"{nominal.H[:, j].tolist()}; check the sweep data")
        axes.append(h / np.linalg.norm(h))
        points.append(R.T @ (circle.centre - t))
        circles.append(circle)
    H = np.array(axes).T
    O = np.array(points)
    # Slide each point along its axis into the plane normal to the nominal axis through the nominal origin.
    slide = -np.einsum("ij,ij->i", O - par.origins, nominal.H.T) / np.einsum("ij,ij->i", H.T, nominal.H.T)
    O = O + slide[:, None] * H.T
    flange = O[-1] + (np.cumsum(nominal.P, axis=1)[:, n] - par.origins[-1])
    P = np.diff(np.vstack([np.zeros(3), O, flange]), axis=0).T
    if par.fit_tool:
        return par.from_geometry(H, P), circles
    P[:, -1] = np.cumsum(nominal.P, axis=1)[:, n] - O[-1]
    return par.from_geometry(H, P), circles
