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

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal, get_args

import numpy as np

from app.collection.plans.dual import PlanResult, WaypointResult
from app.dual.casadi_kinematics import buffer_evaluator, casadi_fk, start_compile
from calibration.errors import ModelError
from calibration.kinematics import so3
from calibration.models import ConstantModel
from cell_config.capsules import PROCESS_ZONE, SEGMENTS, CellCapsules, pairs_outside
from cell_config.loader import CellSpec

logger = logging.getLogger("cellcal.app")
__all__ = ["DualPlanner", "PlanResult", "PlannerOptions", "WaypointResult"]


CompileMode = Literal["auto", "wait", "off"]


@dataclass(frozen=True)
class PlannerOptions:
    """Weights, margins and tolerances of :class:`DualPlanner` (defaults are safe for the cold-spray cell).

    Attributes:
        limit_margin_deg: hard distance kept from every joint limit [deg].
        limit_zone_deg: a penalty starts this far inside the margin [deg].
        clearance_mm: hard minimum surface distance between the arms' capsules [mm].
        clearance_zone_mm: a penalty starts this far above ``clearance_mm`` [mm].
        pairs: checked capsule pairs (R1 capsule, R2 capsule) of :mod:`cell_config.capsules` (the cell's one capsule
            model; radii from the robot YAMLs): every pair but the process zone's (wrist and tool of both arms,
            which the relative pose brings together on purpose).
        singular_min: hard minimum of each singularity measure (0..1).
        singular_zone: a penalty starts below this value of a measure.
        sigma_q_rad: smoothness scale (distance to the previous solution) [rad].
        track_sigma_mm, track_sigma_rad: how closely the workpiece follows its target pose [mm], [rad].
        tol_mm, tol_rad: relative-pose tolerance [mm], [rad]: the iteration stops only once it is met (or at
            ``max_iter``), and a result beyond it is not converged; the residual is the gun's distance from the pose
            the workpiece asks of it, in the cell frame, as the solver's equations measure it.
        step_tol_rad: the iteration stops when the step is below this [rad].
        max_iter: Newton iterations per waypoint.
        max_step_rad: largest joint step per iteration [rad].
        compile: how the casadi function is evaluated. ``"auto"``: the compiled library when it is in the cache
            (gcc, cached on disk); otherwise interpreted while gcc builds it in the background, the compiled one
            from the first waypoint after the build is done (a short plan ends before it, and interpreted it is
            as fast: gcc takes ~2.5 s, the compiled function saves ~0.6 ms per waypoint). ``"wait"``: build
            first, then plan. ``"off"``: interpreted. Interpreted whenever there is no compiler.
    """

    limit_margin_deg: float = 2.0
    limit_zone_deg: float = 8.0
    clearance_mm: float = 50.0
    clearance_zone_mm: float = 100.0
    pairs: tuple[tuple[str, str], ...] = pairs_outside(PROCESS_ZONE)
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
    compile: CompileMode = "auto"


def _pose(T: np.ndarray, name: str) -> np.ndarray:
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4) or not np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-6):
        raise ModelError(f"{name} must be a homogeneous rigid transform of shape (4, 4), got shape {T.shape}")
    return T


_LIMIT_J = np.vstack([-np.eye(12), np.eye(12)])


#: Gauss-Newton steps on the pose equations alone after a penalised iteration that stopped short of the tolerance,
#: and the largest joint change such a step may make [rad] (a polish, never a new solution).
POLISH_STEPS = 5
POLISH_MAX_RAD = 1e-3


def _eq_qp(H: np.ndarray, g: np.ndarray, J: np.ndarray, e: np.ndarray) -> np.ndarray:
    """argmin 0.5 dq'H dq + g'dq  s.t.  J dq = -e, by the null-space method (exact on the constraint rows).

    A rank-deficient J (joints fixed at bounds, singular arm) gets the least-squares constraint step.
    """
    U, S, Vt = np.linalg.svd(J)
    r = int(np.sum(S > 1e-9 * S[0])) if S.size and S[0] > 0 else 0
    dq: np.ndarray = -Vt[:r].T @ ((U[:, :r].T @ e) / S[:r])
    N = Vt[r:].T
    if N.shape[1]:
        dq = dq + N @ np.linalg.solve(N.T @ H @ N, -N.T @ (g + H @ dq))
    return dq


def _relative_residual(P: np.ndarray, T_wp_gun: np.ndarray) -> tuple[float, float]:
    """How far the gun is from the pose the workpiece asks of it: position [mm] and angle [deg], from the
    cell-frame ``poses`` of :meth:`DualPlanner.evaluate` (R1 column-major (9,), p1, R2, p2).

    The gun's target is taken forward from the workpiece (``p2 + R2 p_wp_gun``, ``R2 R_wp_gun``) and compared in
    the cell frame, as the solver's equations ``e`` do: the workpiece frame's rotation is not inverted, so a cell
    file whose ``T_cell_base`` rotation is orthonormal only to its printed digits (the loader accepts 1e-5) does not
    add its rounding times the gun's distance (~400 mm) to a residual the solver drove to zero.
    """
    Rg, pg, Rw, pw = P[:9].reshape(3, 3).T, P[9:12], P[12:21].reshape(3, 3).T, P[21:24]
    R_des, p_des = Rw @ T_wp_gun[:3, :3], pw + Rw @ T_wp_gun[:3, 3]
    res_mm = float(np.linalg.norm(pg - p_des))
    res_deg = float(np.degrees(np.linalg.norm(so3.log(R_des.T @ Rg))))
    return res_mm, res_deg


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
        if options.compile not in get_args(CompileMode):
            raise ModelError(f"PlannerOptions.compile must be one of {', '.join(get_args(CompileMode))}; "
                             f"got {options.compile!r}")
        bad = [p for p in options.pairs if len(p) != 2 or not set(p) <= set(SEGMENTS)]
        if bad or not options.pairs:
            raise ModelError(f"PlannerOptions.pairs must be (R1 capsule, R2 capsule) pairs of {', '.join(SEGMENTS)}; "
                             f"got {bad or 'none'}")
        self.models = {n: m if m is not None else ConstantModel(n, "nominal", cell.robot(n).model())
                       for n, m in (("R1", model_R1), ("R2", model_R2))}
        self.fks = {n: casadi_fk(m) for n, m in self.models.items()}
        self.T_cell_base = {n: cell.robot(n).T_cell_base for n in ("R1", "R2")}
        self.capsule_model = CellCapsules(cell)
        margin = np.radians(options.limit_margin_deg)
        self.lower = np.concatenate([cell.robot(n).robot.lower_rad for n in ("R1", "R2")]) + margin
        self.upper = np.concatenate([cell.robot(n).robot.upper_rad for n in ("R1", "R2")]) - margin
        self._build(ca)

    def _arm(self, ca: Any, name: str, q: Any, x: Any) -> tuple[Any, Any, dict[str, tuple[Any, Any]], Any]:
        R, p, O, A = self.fks[name].function(q, x)
        T = self.T_cell_base[name]
        Rb, pb = ca.DM(T[:3, :3]), ca.DM(T[:3, 3])
        R, p, O, A = Rb @ R, Rb @ p + pb, Rb @ O + ca.repmat(pb, 1, O.shape[1]), Rb @ A
        caps = self.capsule_model.casadi_segments(ca, name, O, p)
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
        c = self.capsule_model.casadi_gaps(ca, {"R1": caps1, "R2": caps2}, o.pairs)
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
        self._F, self._build_job = (F, None) if o.compile == "off" else start_compile(ca, F)
        if o.compile == "wait" and self._build_job is not None:
            self._F = self._build_job.wait() or F
            self._build_job = None
        self._z, self._out = np.zeros(z.shape[0]), np.zeros(k + 24)
        self._eval = buffer_evaluator(self._F, self._z, self._out)
        #: Whether the casadi function is evaluated from the compiled library (so far).
        self.compiled = self._F is not F
        #: Calls of the casadi function so far, by how it was evaluated ("compiled", "interpreted").
        self.evaluations = {"compiled": 0, "interpreted": 0}

    def _take_build(self) -> None:
        """Switch to the compiled function once the background build has finished (between waypoints, so each
        waypoint is solved with one evaluator)."""
        job = self._build_job
        if job is None:
            return
        compiled = job.poll()
        if compiled is not None:
            self._F, self._build_job, self.compiled = compiled, None, True
            self._eval = buffer_evaluator(self._F, self._z, self._out)
        elif job.failed is not None:
            self._build_job = None

    def wait_for_build(self, timeout: float = 300.0) -> bool:
        """Block until a background build has finished and switch to it; whether the function is compiled."""
        if self._build_job is not None:
            self._build_job.wait(timeout)
            self._take_build()
        return self.compiled

    def close(self) -> None:
        """Cancel a background build still running (the cache is left as it was); the planner stays usable,
        interpreted."""
        if self._build_job is not None:
            logger.info("compiled build of the planner cancelled before it finished; %d evaluations interpreted",
                        self.evaluations["interpreted"])
            self._build_job.cancel()
            self._build_job = None

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
        self.evaluations["compiled" if self.compiled else "interpreted"] += 1
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
        self._take_build()
        t0 = time.perf_counter()
        T_cell_target, T_wp_gun = _pose(T_cell_target, "T_cell_target"), _pose(T_wp_gun, "T_wp_gun")
        q = np.asarray(q_guess, dtype=float).copy()
        if q.shape != (12,) or not np.all(np.isfinite(q)):
            raise ModelError(f"q_guess must be 12 finite joint angles [rad] (R1 then R2), got shape {q.shape}")
        q = np.clip(q, self.lower, self.upper)
        q_ref = q.copy() if q_ref is None else np.asarray(q_ref, dtype=float)
        o = self.options
        frozen = self.fks["R1"].frozen or self.fks["R2"].frozen
        it, done, ev = 0, False, None
        while it < o.max_iter:
            ev = self.evaluate(q, T_wp_gun, T_cell_target)
            if done and self._reached(*_relative_residual(ev["poses"], T_wp_gun)):
                break  # the tolerance _check applies is met at q (else the iteration goes on, up to max_iter)
            it += 1
            dq = self._step(q, q_ref, ev)
            e_mm, e_rad = np.linalg.norm(ev["e"][:3]), np.linalg.norm(ev["e"][3:])
            q, ev = q + dq, None
            small = np.abs(dq).max()
            if frozen:  # fixed point: the parameters move after the step, so require e small before it
                if e_mm < 0.1 * o.tol_mm and e_rad < 0.1 * o.tol_rad and small < 1e-5:
                    break
            else:  # e was small before this step; the (exact Newton) step makes it quadratically smaller
                done = bool(e_mm < 1e-3 and small < 1e-5)
            if small < o.step_tol_rad:
                break
        if ev is None or not self._reached(*_relative_residual(ev["poses"], T_wp_gun)):
            q, ev, it = self._polish(q, T_wp_gun, T_cell_target, ev, it)
        return self._check(q, T_wp_gun, T_cell_target, it, t0, ev)

    def _polish(self, q: np.ndarray, T_wp_gun: np.ndarray, T_cell_target: np.ndarray,
                ev: dict[str, np.ndarray] | None, it: int) -> tuple[np.ndarray, dict[str, np.ndarray] | None, int]:
        """At most :data:`POLISH_STEPS` minimum-norm Gauss-Newton steps on the relative-pose equations alone, each
        below :data:`POLISH_MAX_RAD` in every joint: the penalised iteration can stall a few hundredths of a micron
        short of the tolerance when its step is capped (one waypoint far from the start: 5e-05 mm after 60
        iterations, new-user run), and the pose equations alone converge quadratically from there."""
        for _ in range(POLISH_STEPS):
            if ev is None:
                ev = self.evaluate(q, T_wp_gun, T_cell_target)
            if self._reached(*_relative_residual(ev["poses"], T_wp_gun)):
                break
            dq = -np.linalg.lstsq(ev["Je"], ev["e"], rcond=None)[0]
            if not np.abs(dq).max() <= POLISH_MAX_RAD:  # more than a polish: leave the result to the checks
                break
            q, ev, it = np.clip(q + dq, self.lower, self.upper), None, it + 1
        return q, ev, it

    def _reached(self, res_mm: float, res_deg: float) -> bool:
        """Whether a relative-pose residual is within the tolerance (``tol_mm``, ``tol_rad``): the one test the
        iteration stops on and the result is checked against."""
        return res_mm <= self.options.tol_mm and res_deg <= np.degrees(self.options.tol_rad)

    def _check(self, q: np.ndarray, T_wp_gun: np.ndarray, T_cell_target: np.ndarray, it: int,
               t0: float, ev: dict[str, np.ndarray] | None = None) -> WaypointResult:
        """The hard checks on the result ``q`` (``ev``: its :meth:`evaluate`, when the iteration has it)."""
        o = self.options
        if ev is None:
            ev = self.evaluate(q, T_wp_gun, T_cell_target)
        P = ev["poses"]
        Rw, pw = P[12:21].reshape(3, 3).T, P[21:24]
        res_mm, res_deg = _relative_residual(P, T_wp_gun)
        trk_mm = float(np.linalg.norm(pw - T_cell_target[:3, 3]))
        trk_deg = float(np.degrees(np.linalg.norm(so3.log(T_cell_target[:3, :3].T @ Rw))))
        clear, sing = float(ev["c"].min()), float(np.abs(ev["s"]).min())
        reasons = []
        if not self._reached(res_mm, res_deg):
            reasons.append(f"relative pose not reached: {res_mm:.3g} mm, {res_deg:.3g} deg off (tolerance "
                           f"{o.tol_mm:.3g} mm, {np.degrees(o.tol_rad):.3g} deg)")
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

    def plan(self, path: np.ndarray, T_wp_gun: np.ndarray, q_start: np.ndarray, warm: bool = True,
             on_waypoint: Callable[[WaypointResult], None] | None = None) -> PlanResult:
        """Solve a path, each waypoint warm-started from the previous solution.

        Args:
            path: workpiece target poses in the cell frame, shape (N, 4, 4) [mm].
            T_wp_gun: gun pose in the workpiece frame to hold, shape (4, 4) [mm].
            q_start: guess for the first waypoint [rad], shape (12,).
            warm: start each waypoint from the previous solution (a failed one restarts from the last good one);
                when False every waypoint starts from ``q_start`` (the cold benchmark).
            on_waypoint: called with each waypoint's result as it is solved (a progress bar).
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
            if on_waypoint is not None:
                on_waypoint(r)
        n_bad = sum(not r.converged for r in out)
        if n_bad:
            logger.info("%d of %d waypoints not solved; first: %s", n_bad, len(out),
                           next(r.reason for r in out if not r.converged))
        return PlanResult(tuple(out), np.asarray(T_wp_gun, dtype=float),
                          {n: self.fks[n].kind for n in ("R1", "R2")})

