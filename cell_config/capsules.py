"""The cell's collision model: every arm as a chain of capsules, defined once for safety, planner and preview.

Each arm is six capsules (:data:`SEGMENTS`) spanning points of its kinematic skeleton: the joint-axis points
``O0..O5`` and the flange point ``O6`` of the model's chain, the tool point, and the foot of the base column
(on the floor, straight below ``O0`` along the base z axis)::

    base       foot -> O0        the column the arm stands on
    shoulder   O0   -> O1        joint 1 to joint 2
    upper_arm  O1   -> O2        joint 2 to joint 3
    forearm    O2   -> O3        joint 3 to the wrist centre
    wrist      O3   -> O6        wrist centre to the flange
    tool       O6   -> tool      flange to the tool (marker) point

The radii come from the robot YAML (``capsules_mm``) and nowhere else. :class:`CellCapsules` gives the
capsules as numpy arrays (:meth:`~CellCapsules.segments`, for the safety checks and the preview) and as
casadi expressions (:meth:`~CellCapsules.casadi_segments`, for the dual planner's clearance constraint),
both from :data:`SPANS`; surface gaps are segment distance minus both radii.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from calibration.errors import ConfigError
from cell_config.loader import CAPSULE_SEGMENTS, CellRobot, CellSpec

#: Capsule names, in the order of every array of capsules.
SEGMENTS: tuple[str, ...] = CAPSULE_SEGMENTS
#: Skeleton point indices: 0..5 joint-axis points, 6 flange, then the tool point and the base column's foot.
FLANGE, TOOL, FOOT = 6, 7, 8
#: The two skeleton points each capsule spans.
SPANS: dict[str, tuple[int, int]] = {
    "base": (FOOT, 0), "shoulder": (0, 1), "upper_arm": (1, 2), "forearm": (2, 3), "wrist": (3, FLANGE),
    "tool": (FLANGE, TOOL),
}
#: Capsules that move low enough to reach the floor (the base column stands on it; the shoulder cannot).
FLOOR_CHECKED: tuple[str, ...] = ("upper_arm", "forearm", "wrist", "tool")
#: The ends of the arms that a dual plan brings together on purpose (gun at the workpiece).
PROCESS_ZONE: tuple[str, ...] = ("wrist", "tool")
#: Height of the floor plane in the cell frame [mm]: R1's base plate, 505 mm below its joint-2 axis (an
#: assumption; set it from the cell survey).
DEFAULT_FLOOR_Z_MM = -505.0

if set(SPANS) != set(SEGMENTS):  # the robot YAML's capsule names and the spans here must be one list
    raise ImportError(f"capsule spans {sorted(SPANS)} do not match the robot YAML's segments {sorted(SEGMENTS)}")


@dataclass(frozen=True)
class ArmCapsules:
    """One arm's capsules in the cell frame.

    Attributes:
        robot: robot name in the cell (R1).
        radii_mm: capsule radii in :data:`SEGMENTS` order, shape (6,) [mm].
        T_cell_base: the arm's base in the cell frame, shape (4, 4) [mm].
        column_mm: length of the base column below ``O0`` along the base z axis, down to the floor [mm].
    """

    robot: str
    radii_mm: np.ndarray
    T_cell_base: np.ndarray
    column_mm: float

    @classmethod
    def of(cls, robot: CellRobot, floor_z_mm: float) -> ArmCapsules:
        caps = robot.robot.capsules_mm
        missing = [s for s in SEGMENTS if s not in caps]
        if missing:
            raise ConfigError(robot.robot.name, "capsules_mm", f"no radius for {', '.join(missing)}; "
                                                               f"expected {', '.join(SEGMENTS)}")
        column = float(robot.T_cell_base[2, 3] - floor_z_mm)
        if column <= 0:
            raise ConfigError("safety", "floor_z_mm", f"the floor ({floor_z_mm:g} mm) is not below {robot.name}'s "
                                                      f"base ({robot.T_cell_base[2, 3]:g} mm)")
        return cls(robot.name, np.array([float(caps[s]) for s in SEGMENTS]), robot.T_cell_base, column)

    def radius(self, segment: str) -> float:
        """Radius of one capsule [mm]."""
        return float(self.radii_mm[SEGMENTS.index(segment)])

    def segments(self, origins_base: np.ndarray, tool_base: np.ndarray) -> np.ndarray:
        """Capsule end points in the cell frame [mm], shape (N, 6, 2, 3).

        Args:
            origins_base: joint-axis points and flange point in the base frame, shape (7, N, 3) [mm]
                (``Chain.p_base_origin``).
            tool_base: tool point in the base frame, shape (N, 3) [mm].
        """
        pts = np.concatenate([np.moveaxis(origins_base, 0, 1), tool_base[:, None]], axis=1)  # (N, 8, 3)
        foot = pts[:, 0] - np.array([0.0, 0.0, self.column_mm])
        pts = np.concatenate([pts, foot[:, None]], axis=1)
        seg = np.stack([np.stack([pts[:, SPANS[s][0]], pts[:, SPANS[s][1]]], axis=1) for s in SEGMENTS], axis=1)
        seg_cell: np.ndarray = seg @ self.T_cell_base[:3, :3].T + self.T_cell_base[:3, 3]
        return seg_cell

    def casadi_segments(self, ca: Any, origins_cell: Any, tool_cell: Any) -> dict[str, tuple[Any, Any]]:
        """Capsule end points as casadi columns, cell frame.

        Args:
            origins_cell: joint-axis points and flange point in the cell frame, casadi (3, 7) [mm].
            tool_cell: tool point in the cell frame, casadi (3, 1) [mm].
        """
        z_cell = ca.DM(self.T_cell_base[:3, 2])
        pts = [origins_cell[:, i] for i in range(FLANGE + 1)] + [tool_cell]
        pts.append(pts[0] - self.column_mm * z_cell)
        return {s: (pts[SPANS[s][0]], pts[SPANS[s][1]]) for s in SEGMENTS}


class CellCapsules:
    """The capsules of every arm of a cell.

    Args:
        cell: the cell (robot YAMLs give the radii, the cell the base poses).
        floor_z_mm: height of the floor plane in the cell frame [mm]; the base columns stand on it.
    """

    def __init__(self, cell: CellSpec, floor_z_mm: float = DEFAULT_FLOOR_Z_MM) -> None:
        self.cell = cell
        self.floor_z_mm = float(floor_z_mm)
        self.arms = {name: ArmCapsules.of(r, self.floor_z_mm) for name, r in cell.robots.items()}

    def arm(self, robot: str) -> ArmCapsules:
        self.cell.robot(robot)  # the error names the valid robots
        return self.arms[robot]

    def radii(self, robot: str) -> np.ndarray:
        """Capsule radii of ``robot`` in :data:`SEGMENTS` order, shape (6,) [mm]."""
        return self.arm(robot).radii_mm

    def segments(self, robot: str, q: np.ndarray, model: Any = None) -> np.ndarray:
        """Capsules of ``robot`` at joint angles q [rad] (6,) or (N, 6), cell frame [mm], shape (N, 6, 2, 3).

        Args:
            model: anything with ``chain(q)`` (a PoeModel); the arm's nominal model when None.
        """
        model = self.cell.robot(robot).model() if model is None else model
        chain = model.chain(np.atleast_2d(np.asarray(q, dtype=float)))
        return self.arm(robot).segments(chain.p_base_origin, chain.p_base_tool)

    def casadi_segments(self, ca: Any, robot: str, origins_cell: Any, tool_cell: Any) -> dict[str, tuple[Any, Any]]:
        """Capsules of ``robot`` as casadi expressions (see :meth:`ArmCapsules.casadi_segments`)."""
        return self.arm(robot).casadi_segments(ca, origins_cell, tool_cell)

    def gaps(self, robot: str, segs: np.ndarray, other: str, other_segs: np.ndarray) -> np.ndarray:
        """Surface distances between the capsules of two arms [mm], shape (N, 6, 6).

        Args:
            segs: ``robot``'s capsules, shape (N, 6, 2, 3) [mm].
            other_segs: ``other``'s capsules at one pose, shape (6, 2, 3), or pose by pose, (N, 6, 2, 3): sample k
                of ``robot`` against sample k of ``other`` [mm].
        """
        o = other_segs[None] if other_segs.ndim == 3 else other_segs
        d = segment_distance(segs[:, :, None, 0], segs[:, :, None, 1], o[:, None, :, 0], o[:, None, :, 1])
        gaps: np.ndarray = d - self.radii(robot)[None, :, None] - self.radii(other)[None, None, :]
        return gaps

    def floor_gaps(self, robot: str, segs: np.ndarray, names: Sequence[str] = FLOOR_CHECKED) -> np.ndarray:
        """Height of the named capsules' lowest surface point above the floor [mm], shape (N, len(names))."""
        cols = [SEGMENTS.index(s) for s in names]
        gaps: np.ndarray = segs[:, cols][..., 2].min(axis=2) - self.radii(robot)[cols] - self.floor_z_mm
        return gaps

    def casadi_gaps(self, ca: Any, caps: dict[str, dict[str, tuple[Any, Any]]],
                    pairs: Sequence[tuple[str, str]], robots: tuple[str, str] = ("R1", "R2")) -> Any:
        """Surface distances of the capsule ``pairs`` (segment of robots[0], segment of robots[1]) [mm], casadi (k,).

        Args:
            caps: robot name -> its :meth:`casadi_segments`.
        """
        a, b = robots
        ra, rb = self.arm(a), self.arm(b)
        return ca.vertcat(*[segment_distance_casadi(ca, *caps[a][sa], *caps[b][sb]) - ra.radius(sa) - rb.radius(sb)
                            for sa, sb in pairs])


def pairs_outside(zone: Sequence[str] = PROCESS_ZONE) -> tuple[tuple[str, str], ...]:
    """Every capsule pair of two arms except those with both capsules in ``zone``."""
    return tuple((a, b) for a in SEGMENTS for b in SEGMENTS if not (a in zone and b in zone))


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
    distance: np.ndarray = np.linalg.norm(gap, axis=-1)
    return distance


def segment_distance_casadi(ca: Any, a0: Any, a1: Any, b0: Any, b1: Any) -> Any:
    """Distance between segments [a0, a1] and [b0, b1] as a casadi expression (Ericson's closest points, clamped).

    Both segments must have non-zero length (every capsule of :data:`SPANS` has); the square root is smoothed
    by 1e-12 mm^2 so its derivative exists at contact.
    """
    d1, d2, r = a1 - a0, b1 - b0, a0 - b0
    a, e, f = ca.dot(d1, d1), ca.dot(d2, d2), ca.dot(d2, r)
    c, b = ca.dot(d1, r), ca.dot(d1, d2)

    def clamp(v: Any) -> Any:
        return ca.fmin(ca.fmax(v, 0), 1)

    s = clamp((b * f - c * e) / ca.fmax(a * e - b * b, 1e-9))
    t_raw = (b * s + f) / e
    s = ca.if_else(t_raw < 0, clamp(-c / a), ca.if_else(t_raw > 1, clamp((b - c) / a), s))
    t = clamp(t_raw)
    w = a0 + s * d1 - b0 - t * d2
    return ca.sqrt(ca.dot(w, w) + 1e-12)
