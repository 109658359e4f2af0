"""Pose plans for a collection session: the paper's anchor grid, CPA sweeps and random validation poses.

The anchor design (``../shared/data/welding_motoman/README.md``): anchors q = [1, q2, q3, 1, 1, 1] deg on a
(q2, q3) grid, each followed by the anchor with +1 deg on joint 1..6 in turn (7 samples per cluster). The q3
range depends on q2; :func:`paper_q3_bounds` reproduces the recorded design exactly (248 anchors): the bounds
are linear in q2 with a kink at q2 = 0, truncated toward zero to whole degrees, q3 runs from the lower bound
in 5 deg steps and ends on the upper bound, and rows alternate direction (serpentine) to keep moves short.

A plan saves to JSON (``schema: cellcal.plan/1``, ``kind: collection``) with angles in radians written exactly;
:func:`app.collection.plans.reader.read_plan` reads it back.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from app.collection.plans.collection import VALIDATION_CLUSTER, Plan, Target
from calibration.errors import ConfigError, UnsafeTarget

_Q2_KNOTS_DEG = (-55.0, 0.0, 50.0)
_Q3_LOWER_DEG = (-70.0, -50.0, 0.0)
_Q3_UPPER_DEG = (-40.0, 10.0, 50.0)


def paper_q3_bounds(q2_deg: float) -> tuple[float, float]:
    """The paper's q2-dependent q3 range [deg] (reproduces the 248-anchor training design)."""
    lo = float(np.interp(q2_deg, _Q2_KNOTS_DEG, _Q3_LOWER_DEG))
    hi = float(np.interp(q2_deg, _Q2_KNOTS_DEG, _Q3_UPPER_DEG))
    return float(math.trunc(round(lo, 9))), float(math.trunc(round(hi, 9)))


def anchor_grid(q2_range_deg: tuple[float, float] = (-55.0, 50.0), q2_step_deg: float = 5.0,
                q3_step_deg: float = 5.0,
                q3_bounds: Callable[[float], tuple[float, float]] = paper_q3_bounds,
                serpentine: bool = True) -> np.ndarray:
    """Anchor (q2, q3) pairs [deg] in visiting order, shape (M, 2).

    Args:
        q2_range_deg: first and last q2 [deg] (inclusive).
        q2_step_deg: q2 step [deg]; 5 is the paper's, larger steps give reduced grids.
        q3_step_deg: q3 step [deg]; each row starts at its lower bound and ends on its upper bound.
        q3_bounds: q3 range [deg] as a function of q2 [deg].
        serpentine: alternate the q3 direction row by row.
    """
    if not (q2_step_deg > 0 and q3_step_deg > 0) or q2_range_deg[1] < q2_range_deg[0]:
        raise ConfigError("plan", "q2_range_deg/steps", "expected positive steps and first q2 <= last q2")
    q2s = np.arange(q2_range_deg[0], q2_range_deg[1] + 1e-9, q2_step_deg)
    rows = []
    for i, q2 in enumerate(q2s):
        lo, hi = q3_bounds(float(q2))
        if hi < lo:
            raise ConfigError("plan", "q3_bounds", f"empty q3 range [{lo}, {hi}] deg at q2 = {q2} deg")
        q3 = np.arange(lo, hi + 1e-9, q3_step_deg)
        if hi - q3[-1] > 1e-9:
            q3 = np.append(q3, hi)
        if serpentine and i % 2:
            q3 = q3[::-1]
        rows.append(np.column_stack([np.full(q3.size, q2), q3]))
    return np.concatenate(rows)


def plan_anchor_grid(robot: str = "R1", *, q2_range_deg: tuple[float, float] = (-55.0, 50.0),
                     q2_step_deg: float = 5.0, q3_step_deg: float = 5.0,
                     fixed_deg: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0),
                     perturb_deg: float = 1.0, first_cluster: int = 0) -> list[Target]:
    """The anchor design: every anchor then the anchor with ``perturb_deg`` on joint 1..6 in turn.

    Args:
        robot: robot name.
        q2_range_deg, q2_step_deg, q3_step_deg: see :func:`anchor_grid`.
        fixed_deg: q1, q4, q5, q6 of every anchor [deg].
        perturb_deg: the per-joint perturbation [deg]; 0 gives anchors only.
        first_cluster: cluster id of the first anchor.

    Returns:
        7 targets per anchor (1 when ``perturb_deg`` is 0).
    """
    grid = anchor_grid(q2_range_deg, q2_step_deg, q3_step_deg)
    q1, q4, q5, q6 = fixed_deg
    targets = []
    for k, (q2, q3) in enumerate(grid):
        anchor = np.radians([q1, q2, q3, q4, q5, q6])
        cluster = first_cluster + k
        targets.append(Target(robot, anchor, cluster, "anchor"))
        if perturb_deg:
            for j in range(6):
                q = anchor.copy()
                q[j] += math.radians(perturb_deg)
                targets.append(Target(robot, q, cluster, "perturb"))
    return targets


def plan_cpa_sweeps(robot: str, ranges_deg: Sequence[tuple[float, float] | None], *, step_deg: float = 5.0,
                    base_deg: Sequence[float] = (1.0, 0.0, 0.0, 1.0, 1.0, 1.0), first_cluster: int = 0
                    ) -> list[Target]:
    """Single-joint sweeps (circle point analysis): each joint swept alone, the others at ``base_deg``.

    Args:
        robot: robot name.
        ranges_deg: per joint, the (first, last) angle [deg] of its sweep, or None to skip that joint.
        step_deg: sweep step [deg].
        base_deg: the other joints' angles [deg], shape (6,).
        first_cluster: cluster id of the first sweep (one cluster per swept joint).
    """
    if len(ranges_deg) != 6 or len(base_deg) != 6 or not step_deg > 0:
        raise ConfigError("plan", "cpa", "expected 6 ranges (or None), 6 base angles and a positive step")
    targets = []
    cluster = first_cluster
    for j, rng in enumerate(ranges_deg):
        if rng is None:
            continue
        for v in np.arange(rng[0], rng[1] + 1e-9, step_deg):
            q = np.radians(np.asarray(base_deg, dtype=float))
            q[j] = math.radians(v)
            targets.append(Target(robot, q, cluster, "cpa"))
        cluster += 1
    return targets


def plan_validation(robot: str, lower_rad: np.ndarray, upper_rad: np.ndarray, n: int, *, seed: int = 0,
                    margin_deg: float = 5.0, accept: Callable[[np.ndarray], bool] | None = None,
                    max_tries: int = 100) -> list[Target]:
    """Random validation poses spread uniformly over the joint ranges (seeded).

    Args:
        robot: robot name.
        lower_rad, upper_rad: joint limits [rad], shape (6,).
        n: number of poses.
        seed: random seed.
        margin_deg: distance kept from every limit [deg].
        accept: returns False for a pose to draw again (e.g. a collision check); every pose accepted when None.
        max_tries: draws allowed per pose before giving up.

    Raises:
        UnsafeTarget: no acceptable pose found in ``max_tries`` draws.
    """
    lo = np.asarray(lower_rad, dtype=float) + math.radians(margin_deg)
    hi = np.asarray(upper_rad, dtype=float) - math.radians(margin_deg)
    if np.any(hi <= lo):
        raise ConfigError("plan", "margin_deg", f"a margin of {margin_deg} deg leaves no joint range")
    rng = np.random.default_rng(seed)
    targets = []
    for _ in range(n):
        for _ in range(max_tries):
            q = rng.uniform(lo, hi)
            if accept is None or accept(q):
                break
        else:
            raise UnsafeTarget(robot, None, float("nan"), 0.0,
                               f"no safe random validation pose in {max_tries} draws")
        targets.append(Target(robot, q, VALIDATION_CLUSTER, "validation"))
    return targets


def build_plan(targets: Sequence[Target], **params: Any) -> Plan:
    """A plan from target lists joined in order; ``params`` are recorded in the file."""
    if not targets:
        raise ConfigError("plan", "targets", "a plan needs at least one target")
    return Plan(tuple(targets), dict(params))
