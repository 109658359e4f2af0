"""A simulated arm with configuration-dependent error of the CDC paper's size, and its recordings.

The CDC paper reports its largest gain on R2 (the MA1440): nominal 1.08 / 3.07 mm (mean / max on its test path),
FBF 0.42 / 0.99 mm. Nothing in the project measured R2; this module makes a recording of such an arm, so that
``scripts/benchmarks/bench_days.py`` shows a regression of the configuration-dependent (CDC) methods on R2 before it lands.

The error model is written here on purpose, independent of :mod:`calibration.physics` and of the pi model's
blocks (:mod:`calibration.physics.extended`), so that the recording is not a twin of what it is fitted with:

- **geometry**: every link vector shifted and every joint axis tilted (seeded draws), joint zero offsets;
- **own-weight compliance**: joints 2, 3 and 5 twist under gravity torques computed from point masses placed
  along and off each link (masses drawn within +-50 % of the robot YAML's, centres at 0.3-0.7 of each link, a
  payload at the tool), through this module's own forward kinematics;
- **configuration-dependent error** (``cdc_mm``): what a cycloidal or harmonic reducer and its bearings add on the
  shoulder and elbow: cyclic transmission errors of joints 2 and 3 at 2 and 3 cycles per joint turn, and a wobble
  of their axes (a tilt that turns with the joint). Smooth in (q2, q3), so local geometric fits interpolated over
  (q2, q3) can follow it, but outside the span of pi's compliance and deflection terms (first harmonics of q2, q3
  and q2 + q3), so pi alone cannot.

Each effect is planted by its RMS tool displacement over the test path (``*_mm``), so magnitudes read in
millimetres whatever the draw. The defaults (:data:`PAPER_SIZE`) were chosen on this simulation alone, toward the
paper's R2 figures: on 5 seeds drawn at run time the test path's nominal error is 0.95-1.55 mm mean, 2.1-2.6 mm max
(paper 1.08 / 3.07), the paper's fbf13 0.30-0.48 / 1.06-1.46 mm on 2 of them (paper 0.42 / 0.99), pi 0.27-0.54 mm
mean and the pi-based CDC methods 7-30 % below pi (``scripts/benchmarks/bench_days.py --r2-only``).

Designs like the paper's R2 recordings: a training grid of anchors over (q2, q3) (5 deg steps, the q3 range
depending on q2), each anchor followed by +1 deg on joints 1..6 in turn (clusters of 7), joints 1, 4, 5, 6 within
6 deg; a test path of stop-and-go poses along straight joint-space lines through waypoints that move every
joint widely, q2 and q3 within the grid.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from calibration.data.recording import Recording
from calibration.kinematics import so3

#: Cycles per joint turn of the planted transmission errors of joints 2 and 3.
GEAR_CYCLES = (3.0, 5.0)
#: Gravity [N/kg] in the base frame (z up).
GRAVITY = np.array([0.0, 0.0, -9.81])


@dataclass(frozen=True)
class CdcSize:
    """RMS tool displacement [mm] over the test path of each planted effect.

    Attributes:
        geometry_mm: link-vector shifts, axis tilts and zero offsets together.
        compliance_mm: own-weight joint compliance (joints 2, 3, 5).
        cdc_mm: the configuration-dependent error (transmission errors and axis wobble of joints 2, 3); 0: none.
        noise_mm: measurement noise per axis [mm]; noise_deg: orientation noise per axis [deg].
        backlash_deg: lost motion of every joint [deg]: each pose is reached from one side, the same for a
            cluster's poses (and along a test-path line), drawn per cluster, line and joint.
        gross: training poses given a gross marker error (a mocap glitch: ``gross_mm`` in a random direction), as
            a real recording has a few.
    """

    geometry_mm: float = 1.1
    compliance_mm: float = 0.35
    cdc_mm: float = 0.7
    noise_mm: float = 0.04
    noise_deg: float = 0.01
    backlash_deg: float = 0.0
    gross: int = 3
    gross_mm: float = 2.0


#: The paper's R2 size (see the module docstring).
PAPER_SIZE = CdcSize()


@dataclass(frozen=True)
class Grid:
    """The training design.

    Attributes:
        q2_deg: (first, last) anchor q2 [deg]; q3 runs over a q2-dependent range (:func:`grid_anchors`).
        step_deg: anchor spacing in q2 and q3 [deg].
        spread_deg: joints 1, 4, 5, 6 of each anchor drawn within +-spread_deg [deg] (as the shared R1 days
            0524, 0613 and 0620, which see the wrist a little).
        n_test: test poses.
    """

    q2_deg: tuple[float, float] = (-40.0, 50.0)
    step_deg: float = 5.0
    spread_deg: float = 6.0
    n_test: int = 600


def _rot(h: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Rodrigues rotations about unit axes h (N, 3) by angles q (N,), shape (N, 3, 3)."""
    K = np.zeros((len(q), 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -h[:, 2], h[:, 1], -h[:, 0]
    K = K - np.swapaxes(K, 1, 2)
    s, c = np.sin(q)[:, None, None], np.cos(q)[:, None, None]
    R: np.ndarray = np.eye(3) + s * K + (1.0 - c) * (K @ K)
    return R


def _unit(v: np.ndarray) -> np.ndarray:
    u: np.ndarray = v / np.linalg.norm(v, axis=-1, keepdims=True)
    return u


@dataclass(frozen=True)
class ConcealedArm:
    """The true arm: a serial chain (axes H, link vectors P at q = 0) with the errors of :class:`CdcSize`.

    Attributes:
        H, P: nominal axes (3, 6) and link vectors (3, 7) [mm]; R_6_tool (3, 3), p_6_tool (3,) [mm]: the tool in
            the last link frame.
        dH, dP: geometric errors added to H (re-normalised) and P.
        offset_rad: joint zero offsets (6,).
        mass_link: link (0..5, the joint it moves with) of each point mass (M,); mass_kg (M,); mass_frac (M,):
            where along that link's vector it sits; mass_off_mm (M, 3): its offset in the link's frame.
        compliance: rad per N mm on each joint (6,).
        gear: (joint, cycles, amplitude rad, phase rad) rows of the transmission errors.
        wobble: (joint, amplitude rad, phase rad, tilt axis (3,) perpendicular to the joint's) of the axis wobble.
    """

    H: np.ndarray
    P: np.ndarray
    R_6_tool: np.ndarray
    p_6_tool: np.ndarray
    dH: np.ndarray
    dP: np.ndarray
    offset_rad: np.ndarray
    mass_link: np.ndarray
    mass_kg: np.ndarray
    mass_frac: np.ndarray
    mass_off_mm: np.ndarray
    compliance: np.ndarray
    gear: tuple[tuple[int, float, float, float], ...]
    wobble: tuple[tuple[int, float, float, np.ndarray], ...]
    info: dict[str, Any] = field(default_factory=dict, compare=False)

    def _chain(self, q: np.ndarray, H: np.ndarray, P: np.ndarray, tilts: list[np.ndarray | None] | None = None
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Frames of the chain at joint angles q (N, 6): link rotations (7, N, 3, 3) (base, after each joint),
        joint origins (6, N, 3), base-frame axes (6, N, 3), tool R (N, 3, 3) and p (N, 3)."""
        N = len(q)
        R = np.broadcast_to(np.eye(3), (N, 3, 3)).copy()
        p = np.broadcast_to(P[:, 0], (N, 3)).copy()
        Rs, origins, axes = [R], [], []
        for i in range(6):
            tilt = None if tilts is None else tilts[i]
            if tilt is not None:
                R = R @ tilt
            h = np.broadcast_to(H[:, i], (N, 3))
            origins.append(p.copy())
            axes.append((R @ h[..., None])[..., 0])
            R = R @ _rot(h, q[:, i])
            p = p + (R @ P[:, i + 1])
            Rs.append(R)
        return np.stack(Rs), np.stack(origins), np.stack(axes), R @ self.R_6_tool, p + R @ self.p_6_tool

    def gravity_torque(self, q: np.ndarray) -> np.ndarray:
        """Gravity torque about each joint [N mm] at q (N, 6) from the point masses, shape (N, 6)."""
        Rs, origins, axes, _, _ = self._chain(q, self.H, self.P)
        tau = np.zeros((len(q), 6))
        for link, m, s, off in zip(self.mass_link, self.mass_kg, self.mass_frac, self.mass_off_mm):
            R = Rs[link + 1]
            r = origins[link] + s * (R @ self.P[:, link + 1]) + R @ off  # (N, 3) [mm]
            force = m * GRAVITY
            for j in range(link + 1):
                tau[:, j] += np.einsum("ni,ni->n", axes[j], np.cross(r - origins[j], force))
        return tau

    def joint_error(self, q: np.ndarray, parts: tuple[str, ...] = ("offset", "compliance", "gear")) -> np.ndarray:
        """The joint-angle error [rad] (N, 6) of the chosen parts at commanded q (N, 6)."""
        dq = np.zeros_like(q)
        if "offset" in parts:
            dq += self.offset_rad
        if "compliance" in parts:
            dq += self.compliance * self.gravity_torque(q)
        if "gear" in parts:
            for j, cycles, amp, phase in self.gear:
                dq[:, j] += amp * np.sin(cycles * q[:, j] + phase)
        return dq

    def _tilts(self, q: np.ndarray) -> list[np.ndarray | None]:
        tilts: list[np.ndarray | None] = [None] * 6
        for j, amp, phase, axis in self.wobble:
            angle = amp * np.cos(q[:, j] + phase)
            t = _rot(np.broadcast_to(axis, (len(q), 3)), angle)
            tilts[j] = t if tilts[j] is None else tilts[j] @ t
        return tilts

    def pose(self, q: np.ndarray, parts: tuple[str, ...] = ("geometry", "offset", "compliance", "gear", "wobble")
             ) -> tuple[np.ndarray, np.ndarray]:
        """True tool pose ``(R (N, 3, 3), p (N, 3) [mm])`` at commanded q (N, 6) [rad], with the chosen parts of
        the error (all by default)."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        H, P = (_unit((self.H + self.dH).T).T, self.P + self.dP) if "geometry" in parts else (self.H, self.P)
        tilts = self._tilts(q) if "wobble" in parts else None
        _, _, _, R, p = self._chain(q + self.joint_error(q, parts), H, P, tilts)
        return R, p

    def nominal_pose(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The nominal arm's tool pose (no error) at q (N, 6)."""
        _, _, _, R, p = self._chain(np.atleast_2d(q), self.H, self.P)
        return R, p


def _rms_displacement(arm: ConcealedArm, q: np.ndarray, parts: tuple[str, ...]) -> float:
    """RMS tool displacement [mm] of ``parts`` over q."""
    _, p0 = arm.nominal_pose(q)
    _, p1 = arm.pose(q, parts)
    return float(np.sqrt(np.mean(np.sum((p1 - p0) ** 2, axis=1))))


def draw_arm(robot: Any, tool_R: np.ndarray, tool_p: np.ndarray, size: CdcSize, q_ref: np.ndarray,
             rng: np.random.Generator) -> ConcealedArm:
    """A concealed arm for ``robot`` (a :class:`cell_config.loader.RobotSpec`) carrying the tool ``(tool_R, tool_p)``
    (flange frame), each effect scaled to its size in ``size`` over the poses ``q_ref`` (N, 6)."""
    H, P = np.asarray(robot.H, dtype=float), np.asarray(robot.P, dtype=float)
    R_6_tool, p_6_tool = robot.R_flange @ tool_R, robot.R_flange @ tool_p
    masses = np.array([link.mass_kg for link in robot.links]) if robot.links else np.full(6, 20.0)
    # point masses: two per link, within +-50 % of half the link's mass, along its vector and off it; the wrist
    # links' vectors are zero, so their masses sit off the axis; a payload at the tool (link 6)
    link = np.repeat(np.arange(6), 2)
    kg = np.repeat(masses / 2.0, 2) * rng.uniform(0.5, 1.5, 12)
    frac = rng.uniform(0.3, 0.7, 12)
    off = rng.normal(0.0, 40.0, (12, 3))
    payload_kg = float(robot.payload_kg or 5.0) * rng.uniform(0.3, 0.8)
    link = np.append(link, 5)
    kg = np.append(kg, payload_kg)
    frac = np.append(frac, 0.0)
    off = np.vstack([off, p_6_tool + rng.normal(0.0, 30.0, 3)])
    tilt_axis = [_unit(np.cross(H[:, j], rng.normal(size=3))) for j in (1, 2)]
    unit = ConcealedArm(H, P, R_6_tool, p_6_tool,
                        dH=rng.normal(0.0, 1.0, H.shape) * 1e-3, dP=rng.normal(0.0, 1.0, P.shape),
                        offset_rad=rng.normal(0.0, 1e-3, 6), mass_link=link, mass_kg=kg, mass_frac=frac,
                        mass_off_mm=off, compliance=np.array([0, 1.0, 1.0, 0, 0.3, 0]) * 1e-9,
                        gear=tuple((j, c, 1e-4 * rng.uniform(0.5, 1.5), rng.uniform(0, 2 * np.pi))
                                   for j in (1, 2) for c in GEAR_CYCLES),
                        wobble=((1, 1e-4, rng.uniform(0, 2 * np.pi), tilt_axis[0]),
                                (2, 1e-4, rng.uniform(0, 2 * np.pi), tilt_axis[1])))
    # scale each effect to its planted size on q_ref
    geo = _rms_displacement(unit, q_ref, ("geometry", "offset"))
    comp = _rms_displacement(unit, q_ref, ("compliance",))
    cdc = _rms_displacement(unit, q_ref, ("gear", "wobble"))
    k_geo, k_comp, k_cdc = size.geometry_mm / geo, size.compliance_mm / comp, size.cdc_mm / cdc
    # the transmission errors and the wobble are small angles: their displacement is linear in the amplitudes
    arm = ConcealedArm(H, P, R_6_tool, p_6_tool, unit.dH * k_geo, unit.dP * k_geo, unit.offset_rad * k_geo, link,
                       kg, frac, off, unit.compliance * k_comp,
                       tuple((j, c, a * k_cdc, ph) for j, c, a, ph in unit.gear),
                       tuple((j, a * k_cdc, ph, ax) for j, a, ph, ax in unit.wobble),
                       info={"size": size.__dict__, "payload_kg": payload_kg})
    return arm


def grid_anchors(grid: Grid, lower_rad: np.ndarray, upper_rad: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Anchor joint angles [rad] (K, 6): q2 over ``grid.q2_deg`` and q3 over a q2-dependent range (the elbow folds
    less when the shoulder leans back), both in ``grid.step_deg`` steps, within the joint limits less 5 deg;
    joints 1, 4, 5, 6 drawn within +-spread. Visited in q2-major order (as the paper's grids)."""
    anchors = []
    step = grid.step_deg
    lo_deg, hi_deg = np.degrees(lower_rad) + 5.0, np.degrees(upper_rad) - 5.0
    for q2 in np.arange(grid.q2_deg[0], grid.q2_deg[1] + 1e-9, step):
        q3_lo = max(-45.0 + 0.5 * q2, lo_deg[2])
        q3_hi = min(20.0 + 0.4 * q2, hi_deg[2])
        for q3 in np.arange(q3_lo, q3_hi + 1e-9, step):
            anchors.append([0.0, q2, q3, 0.0, 0.0, 0.0])
    q = np.radians(np.array(anchors))
    wide = [0, 3, 4, 5]
    q[:, wide] = np.radians(rng.uniform(-grid.spread_deg, grid.spread_deg, (len(q), 4)))
    return q


def cluster_design(anchors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each anchor then +1 deg on joints 1..6 in turn: q (7 K, 6), cluster (7 K,)."""
    q = np.repeat(anchors, 7, axis=0)
    for j in range(6):
        q[j + 1::7, j] += np.radians(1.0)
    return q, np.repeat(np.arange(len(anchors)), 7)


def test_path(anchors: np.ndarray, n: int, lower_rad: np.ndarray, upper_rad: np.ndarray,
              rng: np.random.Generator) -> np.ndarray:
    """Stop-and-go poses [rad] (n, 6) along straight joint-space lines through waypoints that move every joint
    widely (q1 +-40, q4 +-80, q5 -45..35, q6 +-90 deg), q2 and q3 taken at random anchors (so within the grid)."""
    n_way = max(4, n // 40)
    way = np.radians(rng.uniform([-40, 0, 0, -80, -45, -90], [40, 0, 0, 80, 35, 90], (n_way, 6)))
    pick = anchors[rng.integers(0, len(anchors), n_way)]
    way[:, 1:3] = pick[:, 1:3] + np.radians(rng.uniform(-2.0, 2.0, (n_way, 2)))
    s = np.linspace(0.0, n_way - 1, n)
    i = np.minimum(s.astype(int), n_way - 2)
    f = (s - i)[:, None]
    q = (1 - f) * way[i] + f * way[i + 1]
    clipped: np.ndarray = np.clip(q, lower_rad, upper_rad)
    return clipped


def measure(arm: ConcealedArm, q: np.ndarray, size: CdcSize, rng: np.random.Generator, source: str,
            side: np.ndarray, extra: dict[str, np.ndarray] | None = None) -> Recording:
    """A recording of the arm at q with Gaussian position and orientation noise, each pose reached from the side
    ``side`` (N, 6) (+-1: half the lost motion :attr:`CdcSize.backlash_deg` one way or the other)."""
    R, p = arm.pose(q + side * np.radians(size.backlash_deg) / 2.0)
    p = p + rng.normal(0.0, size.noise_mm, p.shape)
    R = so3.exp(rng.normal(0.0, np.radians(size.noise_deg), p.shape)) @ R
    return Recording(q, p, so3.R_to_quat(R), dict(extra or {}), source)


@dataclass(frozen=True)
class SimDay:
    """A simulated day: training and test recordings of one concealed arm.

    Attributes:
        seed: the seed everything was drawn from.
        arm: the truth.
        train: the cluster grid (with a ``cluster`` column); test: the test path.
    """

    seed: int
    arm: ConcealedArm
    train: Recording
    test: Recording


def simulated_day(robot: Any, tool: Any, seed: int | None = None, size: CdcSize = PAPER_SIZE, grid: Grid = Grid(),
                  label: str = "sim") -> SimDay:
    """A training grid and a test path of a concealed arm of ``robot`` carrying ``tool``.

    Args:
        robot: :class:`cell_config.loader.RobotSpec` (e.g. ``load_cell().robot("R2").robot``, the MA1440).
        tool: :class:`cell_config.loader.ToolSpec` (its ``R_flange_tool``, ``p_flange_tool``).
        seed: draws the arm, the grid's wrist angles, the test path and the noise; None draws one.
        size: the planted effects' sizes.
        grid: the design.
    """
    if seed is None:
        seed = int(np.random.default_rng().integers(0, 2 ** 31))
    rng = np.random.default_rng(seed)
    anchors = grid_anchors(grid, robot.lower_rad, robot.upper_rad, rng)
    q_train, cluster = cluster_design(anchors)
    q_test = test_path(anchors, grid.n_test, robot.lower_rad, robot.upper_rad, rng)
    arm = draw_arm(robot, tool.R_flange_tool, tool.p_flange_tool, size, q_test, rng)
    side_train = rng.choice([-1.0, 1.0], (len(anchors), 6))[cluster]
    n_lines = max(4, grid.n_test // 40) - 1
    side_test = rng.choice([-1.0, 1.0], (n_lines, 6))[np.minimum(np.arange(grid.n_test) * n_lines // grid.n_test,
                                                                   n_lines - 1)]
    train = measure(arm, q_train, size, rng, f"{label} training (seed {seed})", side_train,
                    {"cluster": cluster.astype(float)})
    glitch = rng.choice(len(train), size.gross, replace=False)
    train.p[glitch] += size.gross_mm * _unit(rng.normal(size=(size.gross, 3)))
    test = measure(arm, q_test, size, rng, f"{label} test (seed {seed})", side_test)
    return SimDay(seed, arm, train, test)
