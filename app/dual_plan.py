"""Dual-robot planning with a fixed relative tool pose: R1 (gun) follows R2 (workpiece) exactly.

Per waypoint the 12 joint angles solve::

    min  |q - q_prev|^2 / sigma_q^2 + tracking of the workpiece target pose (soft)
         + hinge penalties near joint limits, arm-arm capsule contact and singularities
    s.t. T_wp_gun(q) = T_wp_gun_des        (6 equations, exact)
         lower + margin <= q <= upper - margin

by a Gauss-Newton SQP: one compiled casadi function gives every residual and its exact Jacobian, numpy
solves the 18x18 KKT system, joints that would cross a bound are fixed at it (active set). After the solve
the hard checks are made again on the result (relative-pose residual with the numpy models, limits,
clearance, singularity); a waypoint that fails one is returned with ``converged=False`` and the reason.

"Workpiece" is R2's model tool frame, "gun" R1's; poses are in the cell frame (R1's base), mm and rad.
Singularity measures are the factors of det J for a wrist-partitioned arm: |w4 . (w5 x w6)| (wrist),
sin(upper arm, forearm) (elbow) and the wrist centre's distance from axis 1 over the reach (shoulder).
"""

from __future__ import annotations

import csv
import io
import json
import logging
import os
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from app.casadi_kinematics import buffer_evaluator, casadi_fk, compile_function
from calibration import so3
from calibration.errors import DataError, ModelError, UnsafeTarget
from calibration.models import ConstantModel
from cell_config.loader import CellSpec

logger = logging.getLogger("cellcal.app")
PLAN_SCHEMA = "cellcal.plan/1"
CAPSULES = ("base", "upper", "forearm", "wrist")


@dataclass(frozen=True)
class PlannerOptions:
    """Weights, margins and tolerances of :class:`DualPlanner` (defaults are safe for the cold-spray cell).

    Attributes:
        limit_margin_deg: hard distance kept from every joint limit [deg].
        limit_zone_deg: a penalty starts this far inside the margin [deg].
        clearance_mm: hard minimum surface distance between the arms' capsules [mm].
        clearance_zone_mm: a penalty starts this far above ``clearance_mm`` [mm].
        radii_mm: capsule radius per (robot, capsule) [mm]; capsules: base column, upper arm, forearm, wrist+tool.
        pairs: checked capsule pairs (R1 capsule, R2 capsule); wrist-wrist is the process zone and left out.
        singular_min: hard minimum of each singularity measure (0..1).
        singular_zone: a penalty starts below this value of a measure.
        sigma_q_rad: smoothness scale (distance to the previous solution) [rad].
        track_sigma_mm, track_sigma_rad: how closely the workpiece follows its target pose [mm], [rad].
        tol_mm, tol_rad: relative-pose tolerance; a result beyond it is not converged [mm], [rad].
        step_tol_rad: the iteration stops when the step is below this [rad].
        max_iter: Newton iterations per waypoint.
        max_step_rad: largest joint step per iteration [rad].
        compile: compile the casadi function to C (gcc, cached on disk); interpreted when False or no compiler.
    """

    limit_margin_deg: float = 2.0
    limit_zone_deg: float = 8.0
    clearance_mm: float = 50.0
    clearance_zone_mm: float = 100.0
    radii_mm: dict[str, dict[str, float]] = field(default_factory=lambda: {
        "R1": {"base": 250.0, "upper": 130.0, "forearm": 110.0, "wrist": 90.0},
        "R2": {"base": 200.0, "upper": 100.0, "forearm": 80.0, "wrist": 70.0}})
    pairs: tuple[tuple[str, str], ...] = (
        ("upper", "upper"), ("upper", "forearm"), ("upper", "wrist"), ("forearm", "upper"),
        ("forearm", "forearm"), ("forearm", "wrist"), ("wrist", "upper"), ("wrist", "forearm"),
        ("base", "wrist"), ("base", "forearm"), ("wrist", "base"), ("forearm", "base"))
    singular_min: float = 0.02
    singular_zone: float = 0.15
    sigma_q_rad: float = 0.05
    track_sigma_mm: float = 1.0
    track_sigma_rad: float = 0.01
    tol_mm: float = 1e-6
    tol_rad: float = 1e-8
    step_tol_rad: float = 1e-9
    max_iter: int = 60
    max_step_rad: float = 0.3
    compile: bool = True


@dataclass(frozen=True)
class WaypointResult:
    """One solved (or refused) waypoint.

    Attributes:
        q_R1, q_R2: joint angles [rad], shape (6,).
        residual_mm, residual_deg: relative-pose error in the models (numpy FK) [mm], [deg].
        track_mm, track_deg: workpiece distance from its target pose [mm], [deg].
        clearance_mm: smallest capsule surface distance between the arms [mm].
        singularity: smallest singularity measure (0 = singular, 1 = far).
        solve_ms: wall time of the solve including the checks [ms].
        iterations: Newton iterations.
        converged: every hard condition holds; only then may the waypoint be executed.
        reason: why not, or "" when converged.
    """

    q_R1: np.ndarray
    q_R2: np.ndarray
    residual_mm: float
    residual_deg: float
    track_mm: float
    track_deg: float
    clearance_mm: float
    singularity: float
    solve_ms: float
    iterations: int
    converged: bool
    reason: str = ""


@dataclass(frozen=True)
class PlanResult:
    """A planned sequence.

    Attributes:
        waypoints: per-waypoint results in path order.
        T_wp_gun: the relative pose that was held, shape (4, 4) [mm].
        models: model kind per robot, e.g. ``{"R1": "cdc", "R2": "constant"}``.
    """

    waypoints: tuple[WaypointResult, ...]
    T_wp_gun: np.ndarray
    models: dict[str, str]

    @property
    def converged(self) -> bool:
        return all(w.converged for w in self.waypoints)

    @property
    def failed(self) -> list[int]:
        """Indices of waypoints that must not be executed."""
        return [i for i, w in enumerate(self.waypoints) if not w.converged]

    def q(self) -> np.ndarray:
        """Joint angles of all waypoints [rad], shape (N, 12): R1 then R2."""
        return np.array([np.concatenate([w.q_R1, w.q_R2]) for w in self.waypoints])

    def to_dict(self) -> dict[str, Any]:
        """The plan file content (schema ``cellcal.plan/1``)."""
        wps = []
        for w in self.waypoints:
            wps.append({"R1": w.q_R1.tolist(), "R2": w.q_R2.tolist(), "converged": w.converged, "reason": w.reason,
                        "residual_mm": w.residual_mm, "residual_deg": w.residual_deg, "track_mm": w.track_mm,
                        "clearance_mm": w.clearance_mm, "solve_ms": w.solve_ms})
        return {"schema": PLAN_SCHEMA, "kind": "dual", "models": self.models, "T_wp_gun": self.T_wp_gun.tolist(),
                "converged": self.converged, "waypoints": wps}


def _pose(T: np.ndarray, name: str) -> np.ndarray:
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4) or not np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-6):
        raise ModelError(f"{name} must be a homogeneous rigid transform of shape (4, 4), got shape {T.shape}")
    return T


def _capsule_distance(ca: Any, a0: Any, a1: Any, b0: Any, b1: Any) -> Any:
    """Distance between segments [a0, a1] and [b0, b1] (Ericson's closest points, clamped)."""
    d1, d2, r = a1 - a0, b1 - b0, a0 - b0
    a, e, f = ca.dot(d1, d1), ca.dot(d2, d2), ca.dot(d2, r)
    c, b = ca.dot(d1, r), ca.dot(d1, d2)
    clamp = lambda v: ca.fmin(ca.fmax(v, 0), 1)  # noqa: E731
    s = clamp((b * f - c * e) / ca.fmax(a * e - b * b, 1e-9))
    t_raw = (b * s + f) / e
    s = ca.if_else(t_raw < 0, clamp(-c / a), ca.if_else(t_raw > 1, clamp((b - c) / a), s))
    t = clamp(t_raw)
    w = a0 + s * d1 - b0 - t * d2
    return ca.sqrt(ca.dot(w, w) + 1e-12)


_LIMIT_J = np.vstack([-np.eye(12), np.eye(12)])


def _eq_qp(H: np.ndarray, g: np.ndarray, J: np.ndarray, e: np.ndarray) -> np.ndarray:
    """argmin 0.5 dq'H dq + g'dq  s.t.  J dq = -e, by the null-space method (exact on the constraint rows).

    A rank-deficient J (joints fixed at bounds, singular arm) gets the least-squares constraint step.
    """
    U, S, Vt = np.linalg.svd(J)
    r = int(np.sum(S > 1e-9 * S[0])) if S.size and S[0] > 0 else 0
    dq = -Vt[:r].T @ ((U[:, :r].T @ e) / S[:r])
    N = Vt[r:].T
    if N.shape[1]:
        dq = dq + N @ np.linalg.solve(N.T @ H @ N, -N.T @ (g + H @ dq))
    return dq


class DualPlanner:
    """Build once for a cell and two models, then solve waypoints or whole paths.

    Args:
        cell: the loaded cell (robot limits and R2's base pose in the cell frame).
        model_R1, model_R2: kinematic models (``ConstantModel``, ``CdcModel``, ...); nominal when None.
        options: weights, margins and tolerances.
    """

    def __init__(self, cell: CellSpec, model_R1: Any = None, model_R2: Any = None,
                 options: PlannerOptions = PlannerOptions()) -> None:
        import casadi as ca

        self.cell, self.options = cell, options
        self.models = {n: m if m is not None else ConstantModel(n, "nominal", cell.robot(n).model())
                       for n, m in (("R1", model_R1), ("R2", model_R2))}
        self.fks = {n: casadi_fk(m) for n, m in self.models.items()}
        self.T_cell_base = {n: cell.robot(n).T_cell_base for n in ("R1", "R2")}
        margin = np.radians(options.limit_margin_deg)
        self.lower = np.concatenate([cell.robot(n).robot.lower_rad for n in ("R1", "R2")]) + margin
        self.upper = np.concatenate([cell.robot(n).robot.upper_rad for n in ("R1", "R2")]) - margin
        self._build(ca)

    def _arm(self, ca: Any, name: str, q: Any, x: Any) -> tuple[Any, Any, dict[str, tuple[Any, Any]], Any]:
        R, p, O, A = self.fks[name].function(q, x)
        T = self.T_cell_base[name]
        Rb, pb = ca.DM(T[:3, :3]), ca.DM(T[:3, 3])
        R, p, O, A = Rb @ R, Rb @ p + pb, Rb @ O + ca.repmat(pb, 1, O.shape[1]), Rb @ A
        foot = O[:, 0] - 700.0 * A[:, 0]
        caps = {"base": (foot, O[:, 0]), "upper": (O[:, 1], O[:, 2]), "forearm": (O[:, 2], O[:, 3]),
                "wrist": (O[:, 3], p)}
        wc, up, fore = O[:, 3], O[:, 2] - O[:, 1], O[:, 3] - O[:, 2]
        reach = float(np.linalg.norm(self.cell.robot(name).robot.P[:, 1:4].sum(axis=1)))
        sing = ca.vertcat(ca.dot(A[:, 3], ca.cross(A[:, 4], A[:, 5])),
                          ca.norm_2(ca.cross(up, fore)) / (ca.norm_2(up) * ca.norm_2(fore)),
                          ca.norm_2(ca.cross(A[:, 0], wc - O[:, 0])) / reach)
        return R, p, caps, sing

    def _build(self, ca: Any) -> None:
        o = self.options
        n1, n2 = self.fks["R1"].n_frozen, self.fks["R2"].n_frozen
        z = ca.SX.sym("z", 36 + n1 + n2)  # q (12), T_rel (3x4), T_tgt (3x4), frozen parameters
        q, T_rel, T_tgt = z[:12], ca.reshape(z[12:24], 3, 4), ca.reshape(z[24:36], 3, 4)
        R1, p1, caps1, s1 = self._arm(ca, "R1", q[:6], z[36:36 + n1])
        R2, p2, caps2, s2 = self._arm(ca, "R2", q[6:], z[36 + n1:])
        R_des, p_des = R2 @ T_rel[:, :3], p2 + R2 @ T_rel[:, 3]
        e = ca.vertcat(p1 - p_des, 0.5 * ca.inv_skew(R_des.T @ R1 - R1.T @ R_des))
        t = ca.vertcat(p2 - T_tgt[:, 3], 0.5 * ca.inv_skew(T_tgt[:, :3].T @ R2 - R2.T @ T_tgt[:, :3]))
        rad = o.radii_mm
        c = ca.vertcat(*[_capsule_distance(ca, *caps1[a], *caps2[b]) - rad["R1"][a] - rad["R2"][b]
                         for a, b in o.pairs])
        s = ca.vertcat(s1, s2)
        outs, self._layout, k = [], {}, 0
        for name, v in (("e", e), ("t", t), ("c", c), ("s", s)):
            n = v.shape[0]
            for key, val, size in ((name, v, n), ("J" + name, ca.jacobian(v, q), n * 12)):
                outs.append(ca.vec(val))
                self._layout[key] = (k, size, n)
                k += size
        outs.append(ca.vertcat(ca.vec(R1), p1, ca.vec(R2), p2))
        self._layout["poses"] = (k, 24, 24)
        F = ca.Function("cellcal_dual", [z], [ca.densify(ca.vertcat(*outs))])
        self._F = compile_function(ca, F) if o.compile else F
        self._z, self._out = np.zeros(z.shape[0]), np.zeros(k + 24)
        self._eval = buffer_evaluator(self._F, self._z, self._out)

    def evaluate(self, q: np.ndarray, T_wp_gun: np.ndarray, T_cell_target: np.ndarray) -> dict[str, np.ndarray]:
        """Residuals and Jacobians at q [rad] (12,).

        Returns:
            ``e`` relative-pose residual (6,) [mm; rad], ``t`` tracking residual (6,), ``c`` capsule clearances
            (k,) [mm], ``s`` singularity measures (6,), each with its Jacobian ``J<name>`` (n, 12), and
            ``poses`` (R1 column-major (9,), p1, R2, p2) in the cell frame.
        """
        z = self._z
        z[:12] = q
        z[12:24] = T_wp_gun[:3].ravel(order="F")
        z[24:36] = T_cell_target[:3].ravel(order="F")
        n1 = self.fks["R1"].n_frozen
        if n1:
            z[36:36 + n1] = self.fks["R1"].x0(q[:6])
        if self.fks["R2"].n_frozen:
            z[36 + n1:] = self.fks["R2"].x0(q[6:])
        self._eval()
        out = {}
        for key, (k, size, n) in self._layout.items():
            v = self._out[k:k + size]
            out[key] = v.reshape(12, n).T.copy() if key[0] == "J" else v.copy()
        return out

    def _step(self, q: np.ndarray, q_ref: np.ndarray, ev: dict[str, np.ndarray]) -> np.ndarray:
        """One SQP step: Gauss-Newton model of the cost, linearised pose equations solved exactly (null space)."""
        o = self.options
        w_q = 1.0 / o.sigma_q_rad**2
        wt = np.array([1 / o.track_sigma_mm] * 3 + [1 / o.track_sigma_rad] * 3)
        Jt = ev["Jt"] * wt[:, None]
        H = Jt.T @ Jt + w_q * np.eye(12)
        g = Jt.T @ (ev["t"] * wt) + w_q * (q - q_ref)
        zone_q = np.radians(o.limit_zone_deg)
        viol = np.concatenate([zone_q - (q - self.lower), zone_q - (self.upper - q)])
        pen = [(viol, _LIMIT_J, 10.0 / zone_q),
               (o.clearance_mm + o.clearance_zone_mm - ev["c"], -ev["Jc"], 10.0 / o.clearance_zone_mm),
               (o.singular_zone - np.abs(ev["s"]), -np.sign(ev["s"])[:, None] * ev["Js"], 10.0 / o.singular_zone)]
        for v, J, w in pen:
            act = v > 0
            if act.any():
                Ja = J[act] * w
                H += Ja.T @ Ja
                g += Ja.T @ (v[act] * w)
        e, Je = ev["e"], ev["Je"]
        dq = _eq_qp(H, g, Je, e)  # fast path: no bound crossed
        free = np.ones(12, dtype=bool)
        for _ in range(12):
            qn = q + dq
            out = free & ((qn < self.lower) | (qn > self.upper))
            if not out.any():
                break
            dq[out] = np.clip(qn[out], self.lower[out], self.upper[out]) - q[out]
            free &= ~out
            fixed = ~free
            Hf = H[np.ix_(free, free)]
            dq[free] = _eq_qp(Hf, g[free] + H[np.ix_(free, fixed)] @ dq[fixed], Je[:, free],
                              e + Je[:, fixed] @ dq[fixed])
        big = np.abs(dq).max()
        return dq * (o.max_step_rad / big) if big > o.max_step_rad else dq

    def solve_waypoint(self, T_cell_target: np.ndarray, T_wp_gun: np.ndarray, q_guess: np.ndarray,
                       q_ref: np.ndarray | None = None) -> WaypointResult:
        """Solve one waypoint.

        Args:
            T_cell_target: target pose of the workpiece (R2 tool) in the cell frame, shape (4, 4) [mm].
            T_wp_gun: pose of the gun (R1 tool) in the workpiece frame to hold, shape (4, 4) [mm].
            q_guess: start [rad], shape (12,) (R1 then R2); the previous waypoint's solution when warm.
            q_ref: configuration to stay close to [rad], shape (12,); ``q_guess`` when None.

        Returns:
            The :class:`WaypointResult`; check ``converged`` before executing it.
        """
        t0 = time.perf_counter()
        T_cell_target, T_wp_gun = _pose(T_cell_target, "T_cell_target"), _pose(T_wp_gun, "T_wp_gun")
        q = np.asarray(q_guess, dtype=float).copy()
        if q.shape != (12,) or not np.all(np.isfinite(q)):
            raise ModelError(f"q_guess must be 12 finite joint angles [rad] (R1 then R2), got shape {q.shape}")
        q = np.clip(q, self.lower, self.upper)
        q_ref = q.copy() if q_ref is None else np.asarray(q_ref, dtype=float)
        o = self.options
        frozen = self.fks["R1"].frozen or self.fks["R2"].frozen
        it = 0
        for it in range(1, o.max_iter + 1):
            ev = self.evaluate(q, T_wp_gun, T_cell_target)
            dq = self._step(q, q_ref, ev)
            q = q + dq
            small = np.abs(dq).max()
            e_mm, e_rad = np.linalg.norm(ev["e"][:3]), np.linalg.norm(ev["e"][3:])
            if frozen:  # fixed point: the parameters move after the step, so require e small before it
                done = e_mm < 0.1 * o.tol_mm and e_rad < 0.1 * o.tol_rad and small < 1e-5
            else:  # e was small before this step; the (exact Newton) step makes it quadratically smaller
                done = e_mm < 1e-3 and small < 1e-5
            if done or small < o.step_tol_rad:
                break
        return self._check(q, T_wp_gun, T_cell_target, it, t0)

    def _check(self, q: np.ndarray, T_wp_gun: np.ndarray, T_cell_target: np.ndarray, it: int,
               t0: float) -> WaypointResult:
        o = self.options
        ev = self.evaluate(q, T_wp_gun, T_cell_target)
        P = ev["poses"]
        Rg, pg, Rw, pw = P[:9].reshape(3, 3).T, P[9:12], P[12:21].reshape(3, 3).T, P[21:24]
        res_mm = float(np.linalg.norm(Rw.T @ (pg - pw) - T_wp_gun[:3, 3]))
        res_deg = float(np.degrees(np.linalg.norm(so3.log(T_wp_gun[:3, :3].T @ Rw.T @ Rg))))
        trk_mm = float(np.linalg.norm(pw - T_cell_target[:3, 3]))
        trk_deg = float(np.degrees(np.linalg.norm(so3.log(T_cell_target[:3, :3].T @ Rw))))
        clear, sing = float(ev["c"].min()), float(np.abs(ev["s"]).min())
        reasons = []
        if res_mm > o.tol_mm or res_deg > np.degrees(o.tol_rad):
            reasons.append(f"relative pose not reached ({res_mm:.3g} mm, {res_deg:.3g} deg)")
        bad = np.flatnonzero((q < self.lower - 1e-12) | (q > self.upper + 1e-12))
        if bad.size:
            reasons.append("joint limit: " + ", ".join(f"{'R1' if j < 6 else 'R2'} J{j % 6 + 1}" for j in bad))
        if clear < o.clearance_mm:
            a, b = o.pairs[int(np.argmin(ev["c"]))]
            reasons.append(f"collision: R1 {a} vs R2 {b} clearance {clear:.1f} mm < {o.clearance_mm:.1f} mm")
        if sing < o.singular_min:
            k = int(np.argmin(np.abs(ev["s"])))
            reasons.append(f"near singularity: {'R1' if k < 3 else 'R2'} {('wrist', 'elbow', 'shoulder')[k % 3]} "
                           f"measure {sing:.3f} < {o.singular_min}")
        ms = (time.perf_counter() - t0) * 1e3
        return WaypointResult(q[:6].copy(), q[6:].copy(), res_mm, res_deg, trk_mm, trk_deg, clear, sing, ms, it,
                              not reasons, "; ".join(reasons))

    def plan(self, path: np.ndarray, T_wp_gun: np.ndarray, q_start: np.ndarray, warm: bool = True) -> PlanResult:
        """Solve a path, each waypoint warm-started from the previous solution.

        Args:
            path: workpiece target poses in the cell frame, shape (N, 4, 4) [mm].
            T_wp_gun: gun pose in the workpiece frame to hold, shape (4, 4) [mm].
            q_start: guess for the first waypoint [rad], shape (12,).
            warm: start each waypoint from the previous solution (a failed one restarts from the last good one);
                when False every waypoint starts from ``q_start`` (the cold benchmark).
        """
        path = np.asarray(path, dtype=float)
        if path.ndim != 3 or path.shape[1:] != (4, 4) or path.shape[0] == 0:
            raise ModelError(f"path must be workpiece poses of shape (N, 4, 4), got {path.shape}")
        out: list[WaypointResult] = []
        q = np.asarray(q_start, dtype=float)
        for T in path:
            r = self.solve_waypoint(T, T_wp_gun, q if warm else q_start)
            if r.converged and warm:
                q = np.concatenate([r.q_R1, r.q_R2])
            out.append(r)
        n_bad = sum(not r.converged for r in out)
        if n_bad:
            logger.warning("%d of %d waypoints not solved; first: %s", n_bad, len(out),
                           next(r.reason for r in out if not r.converged))
        return PlanResult(tuple(out), np.asarray(T_wp_gun, dtype=float),
                          {n: self.fks[n].kind for n in ("R1", "R2")})


#: Reference configuration of the cell [deg]: tools about 410 mm apart, facing, 300 mm arm clearance.
Q_REF_DEG = np.array([0.0, 15.0, 5.0, 0.0, 30.0, 0.0, 0.0, 0.0, 0.0, 0.0, -30.0, 0.0])


def tool_pose(planner: DualPlanner, name: str, q: np.ndarray) -> np.ndarray:
    """Tool pose of robot ``name`` in the cell frame for joint angles q [rad] (6,), shape (4, 4) [mm]."""
    R, p = planner.models[name].fk(np.asarray(q, dtype=float)[None])
    T = planner.T_cell_base[name]
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = T[:3, :3] @ R[0], T[:3, :3] @ p[0] + T[:3, 3]
    return out


def relative_pose(planner: DualPlanner, q: np.ndarray) -> np.ndarray:
    """Gun pose in the workpiece frame at q [rad] (12,), shape (4, 4) [mm]: a relative pose known to be reachable."""
    q = np.asarray(q, dtype=float)
    return np.linalg.inv(tool_pose(planner, "R2", q[6:])) @ tool_pose(planner, "R1", q[:6])


def sweep_path(planner: DualPlanner, n: int = 200, q_inward_deg: np.ndarray | None = None,
               q_outward_deg: np.ndarray | None = None) -> np.ndarray:
    """Workpiece poses sweeping R2 from tucked-in to outstretched (joint-space interpolation of R2).

    Args:
        planner: gives R2's model and base pose.
        n: number of waypoints.
        q_inward_deg, q_outward_deg: R2 end configurations [deg], shape (6,).

    Returns:
        Workpiece target poses in the cell frame, shape (n, 4, 4) [mm].
    """
    if n < 2:
        raise ModelError(f"a sweep needs n >= 2 waypoints, got {n}")
    qa = np.radians([-5.0, -5.0, 5.0, -10.0, -35.0, 10.0] if q_inward_deg is None else q_inward_deg)
    qb = np.radians([10.0, 25.0, -5.0, 10.0, -20.0, -10.0] if q_outward_deg is None else q_outward_deg)
    s = 0.5 - 0.5 * np.cos(np.linspace(0.0, np.pi, n))  # rest-to-rest timing
    return np.array([tool_pose(planner, "R2", qa + si * (qb - qa)) for si in s])


def save_plan(plan: PlanResult, path: str | Path) -> None:
    """Write the plan file (JSON, schema ``cellcal.plan/1``) atomically."""
    _write_atomic(Path(path), json.dumps(plan.to_dict(), indent=1))


def _write_atomic(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def rpy_deg(R: np.ndarray) -> np.ndarray:
    """Yaskawa fixed-axis angles ``(Rx, Ry, Rz)`` [deg] with ``R = Rz @ Ry @ Rx``, shape (..., 3)."""
    rx = np.arctan2(R[..., 2, 1], R[..., 2, 2])
    ry = np.arctan2(-R[..., 2, 0], np.hypot(R[..., 0, 0], R[..., 1, 0]))
    rz = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    return np.degrees(np.stack([rx, ry, rz], axis=-1))


def export_rows(plan: PlanResult, cell: CellSpec, frame: str = "flange", skip_failed: bool = False
                ) -> list[dict[str, Any]]:
    """Controller targets of a plan: joint angles, encoder pulses and "filtered" nominal poses.

    The pose of each row is what the controller's nominal kinematics gives at the planned q, in the robot's
    base frame: sent as a Cartesian target, the controller's inverse kinematics returns the planned q, so the
    real arm lands where the calibrated model says (the program is filtered through the model).

    Args:
        plan: a planned sequence.
        cell: gives pulses per radian, limits and the nominal geometry.
        frame: ``"flange"`` (tool 0 of the controller) or ``"tool"`` (the cell's tool marker frame).
        skip_failed: leave out waypoints that did not converge instead of refusing the export.

    Returns:
        One dict per (waypoint, robot): ``index, robot, q_rad (6), pulses (6), p_mm (3), rpy_deg (3)``.

    Raises:
        UnsafeTarget: a waypoint did not converge (unless ``skip_failed``) or is outside the joint limits.
        ModelError: unknown frame.
    """
    if frame not in ("flange", "tool"):
        raise ModelError(f"unknown frame {frame!r}; valid: flange, tool")
    rows: list[dict[str, Any]] = []
    for i, w in enumerate(plan.waypoints):
        if not w.converged:
            if skip_failed:
                continue
            raise UnsafeTarget("R1+R2", None, w.clearance_mm, 0.0, f"waypoint {i} was not solved: {w.reason}")
        for name, q in (("R1", w.q_R1), ("R2", w.q_R2)):
            spec = cell.robot(name)
            bad = np.flatnonzero((q < spec.robot.lower_rad) | (q > spec.robot.upper_rad))
            if bad.size:
                j = int(bad[0])
                lim = spec.robot.lower_rad[j] if q[j] < spec.robot.lower_rad[j] else spec.robot.upper_rad[j]
                raise UnsafeTarget(name, j + 1, float(q[j]), float(lim), f"waypoint {i}")
            nominal = spec.robot.model(spec.tool if frame == "tool" else None)
            R, p = nominal.fk(q[None])
            rows.append({"index": i, "robot": name, "q_rad": q.tolist(),
                         "pulses": np.rint(q * spec.robot.pulses_per_rad).astype(int).tolist(),
                         "p_mm": p[0].tolist(), "rpy_deg": rpy_deg(R[0]).tolist()})
    return rows


def write_targets(rows: list[dict[str, Any]], path: str | Path, frame: str = "flange") -> None:
    """Write export rows as CSV (one line per waypoint and robot) or JSON (by suffix), atomically."""
    path = Path(path)
    if path.suffix.lower() == ".json":
        _write_atomic(path, json.dumps({"schema": "cellcal.targets/1", "frame": frame, "rows": rows}, indent=1))
        return
    if path.suffix.lower() != ".csv":
        raise ModelError(f"unknown target file type {path.suffix!r}; valid: .csv, .json")
    buf = io.StringIO()
    wr = csv.writer(buf, lineterminator="\n")
    wr.writerow(["index", "robot"] + [f"q{j}_rad" for j in range(1, 7)] + [f"pulse{j}" for j in range(1, 7)]
                + ["x_mm", "y_mm", "z_mm", "rx_deg", "ry_deg", "rz_deg"])
    for r in rows:
        wr.writerow([r["index"], r["robot"]] + [repr(v) for v in r["q_rad"]] + r["pulses"]
                    + [f"{v:.4f}" for v in r["p_mm"] + r["rpy_deg"]])
    _write_atomic(path, buf.getvalue())


def plan_from_dict(d: dict[str, Any], source: str | Path = "<plan>") -> PlanResult:
    """A :class:`PlanResult` from a plan file's content; entries without ``converged: true`` count as unsolved.

    Raises:
        DataError: not a dual plan, or joint vectors that are not 6 finite numbers.
    """
    if not isinstance(d, dict) or d.get("schema") != PLAN_SCHEMA or not isinstance(d.get("waypoints"), list):
        raise DataError(source, None, None, f"expected a dual plan (schema {PLAN_SCHEMA!r} with 'waypoints')")
    out = []
    for i, w in enumerate(d["waypoints"]):
        try:
            q1, q2 = np.asarray(w["R1"], dtype=float), np.asarray(w["R2"], dtype=float)
        except (KeyError, TypeError, ValueError) as e:
            raise DataError(source, None, None, f"waypoint {i}: expected R1 and R2 with 6 numbers each [rad]") from e
        if q1.shape != (6,) or q2.shape != (6,) or not np.all(np.isfinite(np.r_[q1, q2])):
            raise DataError(source, None, None, f"waypoint {i}: expected R1 and R2 with 6 finite numbers each [rad]")
        ok = w.get("converged") is True
        nan = float("nan")
        out.append(WaypointResult(q1, q2, float(w.get("residual_mm", nan)), float(w.get("residual_deg", nan)),
                                  float(w.get("track_mm", nan)), nan, float(w.get("clearance_mm", nan)), nan,
                                  float(w.get("solve_ms", nan)), 0, ok,
                                  w.get("reason", "") if ok else (w.get("reason") or "not marked converged")))
    return PlanResult(tuple(out), np.asarray(d.get("T_wp_gun", np.eye(4)), dtype=float), dict(d.get("models", {})))


def load_plan_result(path: str | Path) -> PlanResult:
    """Read a plan file written by :func:`save_plan`."""
    path = Path(path)
    try:
        return plan_from_dict(json.loads(path.read_text(encoding="utf-8")), path)
    except FileNotFoundError:
        raise DataError(path, None, None, "plan file not found") from None
    except json.JSONDecodeError as e:
        raise DataError(path, None, None, f"not a JSON plan ({e})") from e


def plan_dual(cell: CellSpec, model_R1: Any = None, model_R2: Any = None, path: np.ndarray | None = None,
              T_wp_gun: np.ndarray | None = None, n: int = 200, q_start: np.ndarray | None = None,
              options: PlannerOptions | None = None) -> PlanResult:
    """Plan a dual-robot path in one call (what ``cellcal plan-dual`` runs).

    Args:
        cell: the loaded cell.
        model_R1, model_R2: kinematic models (``load_model`` results); nominal when None.
        path: workpiece poses in the cell frame (N, 4, 4) [mm]; the inward-to-outstretched sweep when None.
        T_wp_gun: gun pose in the workpiece frame (4, 4) [mm]; the reference one (:data:`Q_REF_DEG`) when None.
        n: waypoints of the default sweep.
        q_start: first guess (12,) [rad]; the reference configuration when None.
        options: planner options.
    """
    planner = DualPlanner(cell, model_R1, model_R2, options or PlannerOptions())
    q0 = np.radians(Q_REF_DEG) if q_start is None else np.asarray(q_start, dtype=float)
    T_rel = relative_pose(planner, np.radians(Q_REF_DEG)) if T_wp_gun is None else T_wp_gun
    return planner.plan(sweep_path(planner, n) if path is None else path, T_rel, q0)


def export_targets(plan: PlanResult | str | Path, cell: CellSpec, out: str | Path, frame: str = "flange",
                   skip_failed: bool = False) -> int:
    """Export a plan (object or plan file) as controller targets to ``out`` (.csv or .json).

    Returns:
        The number of rows written (waypoints x 2 robots).

    Raises:
        UnsafeTarget: an unsolved waypoint (unless ``skip_failed``) or a joint beyond its limit; nothing is written.
        DataError, ModelError: unreadable plan, unknown frame or file type.
    """
    if not isinstance(plan, PlanResult):
        plan = load_plan_result(plan)
    if Path(out).suffix.lower() not in (".csv", ".json"):
        raise ModelError(f"unknown target file type {Path(out).suffix!r}; valid: .csv, .json")
    rows = export_rows(plan, cell, frame, skip_failed)
    write_targets(rows, out, frame)
    return len(rows)
