"""Safety checks run before any motion: joint limits and the cell's capsule collision model.

The arms' capsules (their spans and radii) are :mod:`cell_config.capsules`'s, the one model the dual planner and the
preview use too; the radii come from the robot YAMLs. A target is refused (:class:`UnsafeTarget`) when a
joint is outside its limits (minus an optional margin), when a moving capsule comes closer than
``floor_clearance_mm`` to the floor plane, or closer than ``clearance_mm`` to any capsule of another arm at
its current pose. Motions are checked along the joint-space path (the sim and MotoROS joint moves are
linear in joint space), sampled every ``path_step_deg``. All geometry is in the cell frame.

Self-collision is not modelled. Radii are deliberately generous; relax a check only with an explicit option.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from calibration.errors import ConfigError, UnsafeTarget
from cell_config.capsules import DEFAULT_FLOOR_Z_MM, FLOOR_CHECKED, SEGMENTS, CellCapsules, segment_distance
from cell_config.loader import CellSpec

__all__ = ["CellSafety", "SafetyConfig", "segment_distance"]  # segment_distance: cell_config.capsules's


#: The batched screen of :meth:`CellSafety.check_dual_path` hands every sample within this of a clearance [mm] to the
#: sample-by-sample check (the batched and the one-pose kinematics may differ in the last bits).
SCREEN_SLACK_MM = 1e-6


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
        allow_unknown_others: proceed when another arm's pose is unknown (its capsules are then ignored).
        process_zone: capsules whose pairs between the two arms are not checked against each other (the dual
            process brings the gun and the workpiece together on purpose, at a planned relative pose; see
            :data:`cell_config.capsules.PROCESS_ZONE`). Empty (everything checked) unless given explicitly.
    """

    joint_margin_deg: float = 0.0
    check_collisions: bool = True
    check_floor: bool = True
    clearance_mm: float = 50.0
    floor_z_mm: float = DEFAULT_FLOOR_Z_MM
    floor_clearance_mm: float = 20.0
    path_step_deg: float = 2.0
    allow_unknown_others: bool = False
    process_zone: tuple[str, ...] = ()


class CellSafety:
    """Checks targets of the cell's arms against joint limits, the floor and the other arms.

    Args:
        cell: the cell (robots, nominal models, limits, base poses).
        config: margins and switches.
    """

    def __init__(self, cell: CellSpec, config: SafetyConfig = SafetyConfig()) -> None:
        self.cell = cell
        self.config = config
        self.capsule_model = CellCapsules(cell, config.floor_z_mm)
        unknown = [z for z in config.process_zone if z not in SEGMENTS]
        if unknown:
            raise ConfigError("SafetyConfig", "process_zone", f"unknown capsules {unknown}; valid: {', '.join(SEGMENTS)}")
        zone = np.array([s in config.process_zone for s in SEGMENTS])
        self._zone_pairs = zone[:, None] & zone[None, :]  # (6, 6): pairs left to the process's own planning

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
        return self.capsule_model.segments(robot, q)

    def _others(self, robot: str, others: Mapping[str, np.ndarray] | None) -> dict[str, np.ndarray]:
        others = dict(others or {})
        missing = [n for n in self.cell.robots if n != robot and n not in others]
        if missing and self.config.check_collisions and not self.config.allow_unknown_others:
            raise ConfigError("safety", "others", f"pose of {', '.join(missing)} unknown: pass its joint angles "
                                                  "(or set allow_unknown_others / check_collisions=False)")
        return {n: np.asarray(q, dtype=float) for n, q in others.items() if n != robot}

    def check_configs(self, robot: str, q: np.ndarray, others: Mapping[str, np.ndarray] | None,
                      index: Sequence[int] | None = None, *, paired: bool = False, slack_mm: float = 0.0) -> None:
        """Check configurations (N, 6) against limits, floor and the other arms; raise on the first unsafe one.

        Args:
            others: the other arms' joint angles: one pose each (6,), or with ``paired`` one per configuration
                (N, 6), configuration k against the others' k-th pose (both arms moving together).
            slack_mm: added to every clearance (a screen that hands near misses to a finer check).
        """
        q = np.atleast_2d(np.asarray(q, dtype=float))
        self.check_limits(robot, q, index)
        other_q = self._others(robot, others)
        for name, oq in other_q.items():
            self.check_limits(name, oq)
            if paired and np.atleast_2d(oq).shape != q.shape:
                raise ConfigError("safety", "others", f"paired poses of {name} must be shaped like {robot}'s "
                                                      f"{q.shape}, got {np.shape(oq)}")
        segs = self.capsules(robot, q)

        def where(i: int) -> str:
            return f" at target {index[i]}" if index is not None else ""

        if self.config.check_floor:
            gap = self.capsule_model.floor_gaps(robot, segs, FLOOR_CHECKED)
            bad = gap < self.config.floor_clearance_mm + slack_mm
            if bad.any():
                i, k = (int(v) for v in np.argwhere(bad)[0])
                raise UnsafeTarget(robot, None, float(gap[i, k]), self.config.floor_clearance_mm,
                                   f"{FLOOR_CHECKED[k]} too close to the floor{where(i)}")
        if self.config.check_collisions:
            for name, oq in other_q.items():
                other_segs = self.capsules(name, oq)
                gap = self.capsule_model.gaps(robot, segs, name, other_segs if paired else other_segs[0])
                bad = (gap < self.config.clearance_mm + slack_mm) & ~self._zone_pairs
                if bad.any():
                    i, k, m = (int(v) for v in np.argwhere(bad)[0])
                    raise UnsafeTarget(robot, None, float(gap[i, k, m]), self.config.clearance_mm,
                                       f"{SEGMENTS[k]} too close to {name} {SEGMENTS[m]}{where(i)}")

    def path(self, q_from: np.ndarray, q_to: np.ndarray) -> np.ndarray:
        """Joint-space samples of the move from ``q_from`` to ``q_to`` (both included), shape (K, 6)."""
        q_from, q_to = np.asarray(q_from, dtype=float), np.asarray(q_to, dtype=float)
        n = max(1, math.ceil(float(np.max(np.abs(q_to - q_from))) / math.radians(self.config.path_step_deg)))
        s = np.linspace(0.0, 1.0, n + 1)[:, None]
        q: np.ndarray = q_from + s * (q_to - q_from)
        return q

    def check_motion(self, robot: str, q_from: np.ndarray, q_to: np.ndarray,
                     others: Mapping[str, np.ndarray] | None, index: int | None = None) -> None:
        """Check a target and the joint-space path to it; raise UnsafeTarget before any motion."""
        self.check_limits(robot, q_to, None if index is None else [index])
        pts = self.path(q_from, q_to)
        self.check_configs(robot, pts, others, None if index is None else [index] * len(pts))

    def check_dual_motion(self, q_from: np.ndarray, q_to: np.ndarray, index: int | None = None) -> None:
        """Check both arms moving together along the joint-space path from ``q_from`` to ``q_to`` (R1 then R2,
        shape (12,) [rad]): at every sample each arm against limits, floor and the other arm at the same sample.

        Raises:
            UnsafeTarget: before any motion.
        """
        q_from, q_to = np.asarray(q_from, dtype=float), np.asarray(q_to, dtype=float)
        where = None if index is None else [index]
        self.check_limits("R1", q_to[:6], where)  # before the path: a non-finite target has none
        self.check_limits("R2", q_to[6:], where)
        pts = self.path(q_from, q_to)
        for k in range(len(pts)):
            self.check_configs("R1", pts[k, :6], {"R2": pts[k, 6:]}, where)
            self.check_configs("R2", pts[k, 6:], {"R1": pts[k, :6]}, where)

    def check_dual_path(self, q: np.ndarray) -> None:
        """:meth:`check_dual_motion` of every move of a dual plan, waypoint ``i - 1`` to ``i`` (the first from
        itself), with its waypoint's number: both arms' limits, floor and each other, at every path sample.

        All samples are screened in one batch; only a plan that fails the screen, or comes within
        :data:`SCREEN_SLACK_MM` of a clearance, is checked move by move by :meth:`check_dual_motion`, which
        raises for the first unsafe sample exactly as it always did. So a safe plan costs one batched
        kinematics pass, not four per sample (200 waypoints: ~1.3 s less in ``plan-dual``).

        Args:
            q: waypoints, R1 then R2 [rad], shape (W, 12).

        Raises:
            UnsafeTarget: before any motion, naming the waypoint.
        """
        q = np.atleast_2d(np.asarray(q, dtype=float))
        if not np.isfinite(q).all():  # no path to screen: the move-by-move check names the first bad waypoint
            pts = None
        else:
            pts = np.concatenate([self.path(q[max(i - 1, 0)], q[i]) for i in range(len(q))]) if len(q) else q
        if pts is None or (len(pts) and not self._dual_screen(pts[:, :6], pts[:, 6:])):
            for i in range(len(q)):
                self.check_dual_motion(q[max(i - 1, 0)], q[i], i)

    def _dual_screen(self, q1: np.ndarray, q2: np.ndarray) -> bool:
        """Whether every paired sample (R1 at q1[k], R2 at q2[k]; (K, 6) each) passes :meth:`check_configs` with
        :data:`SCREEN_SLACK_MM` added to every clearance, for each arm against the other."""
        try:
            self.check_configs("R1", q1, {"R2": q2}, paired=True, slack_mm=SCREEN_SLACK_MM)
            self.check_configs("R2", q2, {"R1": q1}, paired=True, slack_mm=SCREEN_SLACK_MM)
        except UnsafeTarget:
            return False
        return True

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
