"""Safety checks run before any motion: joint limits and a capsule collision model of the cell.

Each arm is a chain of capsules along the segments between its POE joint origins (nominal model), plus a
tool capsule from the flange point to the tool marker. A target is refused (:class:`UnsafeTarget`) when a
joint is outside its limits (minus an optional margin), when a moving capsule comes closer than
``floor_clearance_mm`` to the floor plane, or closer than ``clearance_mm`` to any capsule of another arm at
its current pose. Motions are checked along the joint-space path (the sim and MotoROS joint moves are
linear in joint space), sampled every ``path_step_deg``. All geometry is in the cell frame.

Self-collision is not modelled. Radii are deliberately generous; relax a check only with an explicit option.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from calibration.errors import ConfigError, UnsafeTarget
from cell_config.loader import CellSpec

# (name, start origin index, end origin index); index 7 = tool point, -1 = base column foot.
_SEGMENTS: tuple[tuple[str, int, int], ...] = (
    ("base", -1, 0), ("shoulder", 0, 1), ("upper_arm", 1, 2), ("forearm", 2, 3), ("wrist", 3, 6), ("tool", 6, 7),
)
_FLOOR_CHECKED = ("upper_arm", "forearm", "wrist", "tool")
DEFAULT_RADII_MM: dict[str, dict[str, float]] = {
    "MA2010": {"base": 220, "shoulder": 180, "upper_arm": 140, "forearm": 110, "wrist": 90, "tool": 50},
    "MA1440": {"base": 180, "shoulder": 150, "upper_arm": 110, "forearm": 90, "wrist": 70, "tool": 50},
}
_FALLBACK_RADII_MM = {"base": 220, "shoulder": 180, "upper_arm": 140, "forearm": 110, "wrist": 90, "tool": 50}


@dataclass(frozen=True)
class SafetyConfig:
    """What is checked and with which margins.

    Attributes:
        joint_margin_deg: distance kept from every joint limit [deg].
        check_collisions: check the other arms (False only by explicit choice).
        check_floor: check the floor plane (False only by explicit choice).
        clearance_mm: minimum surface distance between capsules of different arms [mm].
        floor_z_mm: height of the floor plane in the cell frame [mm] (default: R1's base plate, 505 mm
            below its joint-2 axis; an assumption, set it from the cell survey).
        floor_clearance_mm: minimum surface distance of a moving capsule above the floor [mm].
        path_step_deg: joint-space sampling of a motion path [deg].
        radii_mm: capsule radii [mm] per robot model name and segment; defaults for MA2010/MA1440.
        allow_unknown_others: proceed when another arm's pose is unknown (its capsules are then ignored).
    """

    joint_margin_deg: float = 0.0
    check_collisions: bool = True
    check_floor: bool = True
    clearance_mm: float = 50.0
    floor_z_mm: float = -505.0
    floor_clearance_mm: float = 20.0
    path_step_deg: float = 2.0
    radii_mm: Mapping[str, Mapping[str, float]] = field(default_factory=lambda: DEFAULT_RADII_MM)
    allow_unknown_others: bool = False


def segment_distance(a0: np.ndarray, a1: np.ndarray, b0: np.ndarray, b1: np.ndarray) -> np.ndarray:
    """Shortest distance between segments [a0, a1] and [b0, b1], broadcast over leading axes (..., 3) -> (...)."""
    d1, d2, r = a1 - a0, b1 - b0, a0 - b0
    a = np.einsum("...i,...i", d1, d1)
    e = np.einsum("...i,...i", d2, d2)
    b = np.einsum("...i,...i", d1, d2)
    c = np.einsum("...i,...i", d1, r)
    f = np.einsum("...i,...i", d2, r)
    eps = 1e-12
    a_s = np.where(a > eps, a, 1.0)
    e_s = np.where(e > eps, e, 1.0)
    denom = a * e - b * b
    ok = denom > eps * np.maximum(a * e, eps)
    s = np.where(ok, np.clip((b * f - c * e) / np.where(ok, denom, 1.0), 0.0, 1.0), 0.0)
    t = (b * s + f) / e_s
    s = np.where(t < 0, np.clip(-c / a_s, 0.0, 1.0), np.where(t > 1, np.clip((b - c) / a_s, 0.0, 1.0), s))
    t = np.clip(t, 0.0, 1.0)
    point_a, point_b = a <= eps, e <= eps
    s = np.where(point_a, 0.0, np.where(point_b, np.clip(-c / a_s, 0.0, 1.0), s))
    t = np.where(point_b, 0.0, np.where(point_a, np.clip(f / e_s, 0.0, 1.0), t))
    gap = a0 + d1 * s[..., None] - (b0 + d2 * t[..., None])
    return np.linalg.norm(gap, axis=-1)


class CellSafety:
    """Checks targets of the cell's arms against joint limits, the floor and the other arms.

    Args:
        cell: the cell (robots, nominal models, limits, base poses).
        config: margins and switches.
    """

    def __init__(self, cell: CellSpec, config: SafetyConfig = SafetyConfig()) -> None:
        self.cell = cell
        self.config = config
        self._radii = {}
        for name, r in cell.robots.items():
            radii = config.radii_mm.get(r.robot.name, _FALLBACK_RADII_MM)
            self._radii[name] = np.array([float(radii[s]) for s, _, _ in _SEGMENTS])

    def limits(self, robot: str) -> tuple[np.ndarray, np.ndarray]:
        """Joint limits with the margin applied [rad]: ``(lower (6,), upper (6,))``."""
        spec = self.cell.robot(robot).robot
        m = math.radians(self.config.joint_margin_deg)
        return spec.lower_rad + m, spec.upper_rad - m

    def check_limits(self, robot: str, q: np.ndarray, index: Sequence[int] | None = None) -> None:
        """Raise UnsafeTarget for the first joint angle outside the limits (or not finite).

        Args:
            robot: robot name.
            q: joint angles [rad], shape (6,) or (N, 6).
            index: target numbers for the message, one per row.
        """
        q = np.atleast_2d(np.asarray(q, dtype=float))
        lower, upper = self.limits(robot)
        bad = ~np.isfinite(q) | (q < lower) | (q > upper)
        if not bad.any():
            return
        i, j = (int(v) for v in np.argwhere(bad)[0])
        where = f"target {index[i]}" if index is not None else ""
        margin = f"margin {self.config.joint_margin_deg:g} deg" if self.config.joint_margin_deg else ""
        reason = ", ".join(s for s in (where, margin) if s)
        value = q[i, j]
        limit = lower[j] if not (value > upper[j]) else upper[j]
        raise UnsafeTarget(robot, j + 1, float(value), float(limit), reason)

    def capsules(self, robot: str, q: np.ndarray) -> np.ndarray:
        """Capsule segments of ``robot`` in the cell frame [mm], shape (N, n_segments, 2, 3)."""
        r = self.cell.robot(robot)
        chain = r.model().chain(np.atleast_2d(q))
        pts = np.concatenate([np.moveaxis(chain.p_base_origin, 0, 1), chain.p_base_tool[:, None]], axis=1)
        foot = pts[:, 0] - np.array([0.0, 0.0, -self.config.floor_z_mm + r.T_cell_base[2, 3]])
        pts = np.concatenate([pts, foot[:, None]], axis=1)  # index -1 = base column foot
        seg = np.stack([np.stack([pts[:, i], pts[:, k]], axis=1) for _, i, k in _SEGMENTS], axis=1)
        return seg @ r.T_cell_base[:3, :3].T + r.T_cell_base[:3, 3]

    def _others(self, robot: str, others: Mapping[str, np.ndarray] | None) -> dict[str, np.ndarray]:
        others = dict(others or {})
        missing = [n for n in self.cell.robots if n != robot and n not in others]
        if missing and self.config.check_collisions and not self.config.allow_unknown_others:
            raise ConfigError("safety", "others", f"pose of {', '.join(missing)} unknown: pass its joint angles "
                                                  "(or set allow_unknown_others / check_collisions=False)")
        return {n: np.asarray(q, dtype=float) for n, q in others.items() if n != robot}

    def check_configs(self, robot: str, q: np.ndarray, others: Mapping[str, np.ndarray] | None,
                      index: Sequence[int] | None = None) -> None:
        """Check configurations (N, 6) against limits, floor and the other arms; raise on the first unsafe one."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        self.check_limits(robot, q, index)
        other_q = self._others(robot, others)
        for name, oq in other_q.items():
            self.check_limits(name, oq)
        segs = self.capsules(robot, q)
        radii = self._radii[robot]
        names = [s for s, _, _ in _SEGMENTS]
        where = (lambda i: f" at target {index[i]}") if index is not None else (lambda i: "")
        if self.config.check_floor:
            cols = [names.index(s) for s in _FLOOR_CHECKED]
            gap = segs[:, cols][..., 2].min(axis=2) - radii[cols] - self.config.floor_z_mm
            bad = gap < self.config.floor_clearance_mm
            if bad.any():
                i, k = (int(v) for v in np.argwhere(bad)[0])
                raise UnsafeTarget(robot, None, float(gap[i, k]), self.config.floor_clearance_mm,
                                   f"{robot} {names[cols[k]]} too close to the floor{where(i)}")
        if self.config.check_collisions:
            for name, oq in other_q.items():
                o_segs = self.capsules(name, oq)[0]  # (M, 2, 3)
                d = segment_distance(segs[:, :, None, 0], segs[:, :, None, 1], o_segs[None, None, :, 0],
                                     o_segs[None, None, :, 1])
                gap = d - radii[None, :, None] - self._radii[name][None, None, :]
                bad = gap < self.config.clearance_mm
                if bad.any():
                    i, k, m = (int(v) for v in np.argwhere(bad)[0])
                    raise UnsafeTarget(robot, None, float(gap[i, k, m]), self.config.clearance_mm,
                                       f"{robot} {names[k]} too close to {name} {names[m]}{where(i)}")

    def path(self, q_from: np.ndarray, q_to: np.ndarray) -> np.ndarray:
        """Joint-space samples of the move from ``q_from`` to ``q_to`` (both included), shape (K, 6)."""
        q_from, q_to = np.asarray(q_from, dtype=float), np.asarray(q_to, dtype=float)
        n = max(1, math.ceil(float(np.max(np.abs(q_to - q_from))) / math.radians(self.config.path_step_deg)))
        s = np.linspace(0.0, 1.0, n + 1)[:, None]
        return q_from + s * (q_to - q_from)

    def check_motion(self, robot: str, q_from: np.ndarray, q_to: np.ndarray,
                     others: Mapping[str, np.ndarray] | None, index: int | None = None) -> None:
        """Check a target and the joint-space path to it; raise UnsafeTarget before any motion."""
        self.check_limits(robot, q_to, None if index is None else [index])
        pts = self.path(q_from, q_to)
        self.check_configs(robot, pts, others, None if index is None else [index] * len(pts))

    def check_plan(self, robot: str, q_targets: np.ndarray, others: Mapping[str, np.ndarray] | None,
                   q_start: np.ndarray | None = None) -> None:
        """Check every target of a plan and the paths between consecutive targets, up front.

        Args:
            robot: robot name.
            q_targets: target joint angles [rad], shape (N, 6), in visiting order.
            others: the other arms' joint angles [rad] (held still during the session).
            q_start: the arm's current joint angles; the path from there to the first target is checked too.
        """
        q_targets = np.atleast_2d(np.asarray(q_targets, dtype=float))
        self.check_limits(robot, q_targets, list(range(len(q_targets))))
        starts = np.concatenate([[q_targets[0] if q_start is None else q_start], q_targets[:-1]])
        pts, owner = [], []
        for i, (a, b) in enumerate(zip(starts, q_targets)):
            p = self.path(a, b)
            pts.append(p)
            owner += [i] * len(p)
        self.check_configs(robot, np.concatenate(pts), others, owner)
