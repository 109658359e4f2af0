"""Compensate a Yaskawa job with a calibrated model: every robot position becomes the target that makes the
real (calibrated) arm reach the pose the nominal arm would have reached.

* ``PULSE`` positions: ``q_nom`` from the pulses (the robot YAML's pulse convention), ``T = nominal.fk(q_nom)``,
  ``q`` solves ``calibrated.fk(q) = T`` starting at ``q_nom``, written back as pulses.
* ``ROBOT``/``BASE`` (Cartesian) positions: the controller turns them into joints with its own, nominal,
  kinematics. The programmed pose T is what the arm should reach, so ``q_cal`` solves ``calibrated.fk(q) = T``
  and the position written is ``nominal.fk(q_cal)``: the controller's inverse kinematics of it gives ``q_cal``.
  Assumptions: the pose is that of the cell's tool frame for the arm (the controller's ``///TOOL n`` must hold
  that tool's nominal data); ``BASE`` equals ``ROBOT`` (refused when the group has a base axis, ``BS``); the
  branch is the one the nominal solution reaches from the previous position of the same robot (the job's first
  position of that robot from :data:`HOME_DEG`), or, when that fails, the solution nearest it from a few other
  starts; ``///RCONF``'s flip and R/T/S >= 180 flags must agree with it, its upper/lower-arm and front/rear
  flags are kept as written but not checked (a controller choosing another branch would get a compensation
  computed for a different configuration: program such points in PULSE). ``USER``/``TOOL``/``MTOOL``
  positions are refused.

Both use the configuration-dependent model when the model is one (:class:`app.jobs.arm_ik.ArmIk`). A position
outside the joint limits, or one the calibrated arm cannot reach within them, is refused naming its job line.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from app.dual.export_targets import R_from_rpy_deg, rpy_deg
from app.jobs.arm_ik import ArmIk, IkResult, pose_error
from app.jobs.jbi import Job, JobError, JobPosition, format_values
from calibration.errors import DataError, ModelError
from calibration.models import ConstantModel, load_model
from calibration.models.checks import check_model_for
from cell_config.loader import CellSpec

_ROBOT_SPEC = re.compile(r"^([A-Za-z][A-Za-z0-9_]*)=(.+)$")


def load_job_models(specs: list[str], cell: Any) -> dict[str, Any]:
    """``FILE`` (the robot the model was fitted for) or ``ROBOT=FILE`` per entry -> {robot: model}.

    Raises:
        DataError: unreadable model file, unknown robot, a model fitted for another robot or holding another robot
            type's geometry, or a robot twice.
    """

    models: dict[str, Any] = {}
    for spec in specs:
        m = _ROBOT_SPEC.match(spec)
        robot, path = (m.group(1), m.group(2)) if m and not Path(spec).exists() else (None, spec)
        if robot is not None and robot not in cell.robots:
            raise DataError(spec, None, None, f"unknown robot {robot!r} in --model; valid: {', '.join(cell.robots)}")
        if Path(path).is_dir():
            raise DataError(path, None, None, "expected a model file, found a directory")
        try:
            model = load_model(path)
        except (UnicodeDecodeError, OSError) as e:
            raise DataError(path, None, None, f"not a readable model file ({e.__class__.__name__})") from e
        robot = robot or model.robot
        if model.robot != robot:
            raise DataError(path, None, None, f"model fitted for {model.robot}, given for {robot}")
        if robot not in cell.robots:
            raise ModelError(f"{path}: model of unknown robot {robot!r}; valid: {', '.join(cell.robots)}")
        check_model_for(model, robot, cell.robot(robot).model(), path)  # another robot type's geometry
        if robot in models:
            raise DataError(path, None, None, f"a second model for {robot}; give one --model per robot")
        models[robot] = model
    return models



__all__ = ["HOME_DEG", "NEAR_ORIENTATION_DEG", "Compensation", "JobCompensator", "PointResult"]

#: Start of the nominal solve of a robot's first Cartesian position [deg] (wrist bent: away from q5 = 0).
HOME_DEG = np.array([0.0, 0.0, 0.0, 0.0, -45.0, 0.0])
#: Beyond this joint change [deg] of the exact solution the solution nearest the programmed joints is tried
#: (:meth:`JobCompensator._solve`): a compensation of a millimetre moves a joint by a tenth of a degree elsewhere.
NEAR_SWITCH_DEG = 1.0
#: Orientation [deg] a position at the wrist singularity may be left off its target (the position is reached):
#: moving joints 1-3 by the ~0.1 deg a millimetre's compensation takes turns the tool by as much, and the part of it
#: about the axis normal to joints 4 and 5 the wrist cannot take back there without the swing: under the fbf13 model
#: of 0801 0.025 deg at the home position, up to 0.21 deg at random poses with |q5| < 1 deg; under planted errors of
#: 1 mm / 1 mrad per joint up to 0.44 deg. A welding torch's work and travel angles are held to degrees, and 0.5 deg
#: turns a wire 15 mm beyond the tool point by 0.13 mm; the position itself is reached exactly.
NEAR_ORIENTATION_DEG = 0.5
_RCONF_JOINTS = {3: 3, 4: 5, 5: 0}  # RCONF flag index -> joint index: R >= 180, T >= 180, S >= 180


@dataclass(frozen=True)
class PointResult:
    """One compensated position (the ``--json`` record)."""

    line: int
    name: str
    group: int
    unit: str
    robot: str
    postype: str
    tool: int | None
    before: list[float]  # pulses (int) or X, Y, Z [mm], Rx, Ry, Rz [deg]
    after: list[float]
    q_before_deg: list[float]
    q_after_deg: list[float]
    joint_change_deg: list[float]
    residual_mm: float  # calibrated model at the solved q against the nominal pose
    residual_deg: float
    written_residual_mm: float  # the same after rounding to what the file holds (whole pulses, its decimals)
    written_residual_deg: float
    near_singularity: bool = False  # the position reached, the orientation left residual_deg off (wrist singular)


@dataclass(frozen=True)
class Compensation:
    """The compensated positions of a job and the line replacements that write it."""

    points: tuple[PointResult, ...]
    replacements: dict[int, str]
    models: dict[str, str]

    def to_json(self) -> dict[str, Any]:
        return {"schema": "cellcal.compensated_job/1", "models": self.models,
                "max_residual_mm": max((p.residual_mm for p in self.points), default=0.0),
                "max_written_residual_mm": max((p.written_residual_mm for p in self.points), default=0.0),
                "max_joint_change_deg": max((float(np.abs(p.joint_change_deg).max()) for p in self.points),
                                            default=0.0),
                "points": [asdict(p) for p in self.points]}


class JobCompensator:
    """Built once for a cell and its calibrated models, then applied to jobs.

    Args:
        cell: the cell (pulse conventions, joint limits, nominal geometry and tools).
        models: robot name (R1, R2) -> calibrated model; the job's robots must all have one.
        tol_mm: largest accepted residual of a compensated point under its model [mm].
        max_joint_change_deg: largest accepted change of any joint [deg]; a bigger one is refused rather than
            written.
        near_orientation_deg: largest orientation [deg] a position near the wrist singularity may be left off its
            target by, to keep joints 4 and 6 from swinging (see :meth:`_solve`; its position is reached exactly).
    """

    def __init__(self, cell: CellSpec, models: Mapping[str, Any], tol_mm: float = 1e-6,
                 max_joint_change_deg: float = 5.0, near_orientation_deg: float = NEAR_ORIENTATION_DEG) -> None:
        self.cell, self.models, self.tol_mm = cell, dict(models), tol_mm
        self.max_joint_change_deg, self.near_orientation_deg = max_joint_change_deg, near_orientation_deg
        self.units = {f"RB{i}": name for i, name in enumerate(cell.robots, start=1)}
        self._near_left: dict[int, float] = {}  # job line -> orientation [deg] its nearest solution left
        self._ik: dict[str, tuple[ArmIk, ArmIk]] = {}
        for name, model in self.models.items():
            spec = cell.robot(name)
            nominal = ConstantModel(name, "nominal", spec.model())
            lo, hi = spec.robot.lower_rad, spec.robot.upper_rad
            self._ik[name] = (ArmIk(nominal, lo, hi), ArmIk(model, lo, hi))

    def compensate(self, job: Job) -> Compensation:
        """Compensate every robot position of ``job``; raises :class:`JobError` naming the line otherwise."""
        if any(v.startswith("P") for v, _ in job.variables):
            name, line = next((v, n) for v, n in job.variables if v.startswith("P"))
            raise JobError(job.path, line, f"{name} is a robot position variable, which this tool does not "
                                           "compensate (its value can change at run time); use C positions")
        last: dict[str, np.ndarray] = {}
        points, lines = [], {}
        for pos in job.positions:
            robot = self._robot(job, pos)
            if pos.postype == "PULSE":
                point = self._pulse(job, pos, robot)
            else:
                point = self._cartesian(job, pos, robot, last.get(robot, np.radians(HOME_DEG)))
            change = np.abs(point.joint_change_deg)
            if change.max() > self.max_joint_change_deg:
                j = int(np.argmax(change))
                near = self._near_left.get(pos.line)
                why = ("" if near is None else f"; the solution nearest the programmed joints leaves the orientation "
                       f"{near:.3f} deg off, more than the {self.near_orientation_deg:g} deg allowed")
                raise JobError(job.path, pos.line, f"{pos.name}: compensation moves {robot} joint {j + 1} by "
                                                   f"{change[j]:.2f} deg, more than the {self.max_joint_change_deg:g} "
                                                   f"deg allowed (joint 5 at {point.q_before_deg[4]:.2f} deg; near "
                                                   f"q5 = 0 the wrist is singular{why}); raise "
                                                   "--max-joint-change-deg or --near-orientation-deg")
            last[robot] = np.radians(point.q_after_deg)
            points.append(point)
            lines[pos.line] = f"{pos.name}={format_values(point.after, pos.decimals)}"
        return Compensation(tuple(points), lines, {n: m.method for n, m in self.models.items()})

    def _robot(self, job: Job, pos: JobPosition) -> str:
        if pos.unit not in self.units:
            raise JobError(job.path, pos.line, f"{pos.name} belongs to unknown group unit {pos.unit!r}; valid: "
                           + ", ".join(f"{u} ({r})" for u, r in self.units.items()))
        robot = self.units[pos.unit]
        if robot not in self._ik:
            raise JobError(job.path, pos.line, f"{pos.name} is {robot}'s ({pos.unit}) and no model was given for "
                                               f"{robot}; pass --model {robot}=FILE")
        return robot

    def _limits(self, job: Job, pos: JobPosition, robot: str, q: np.ndarray, what: str) -> None:
        spec = self.cell.robot(robot).robot
        bad = np.flatnonzero((q < spec.lower_rad) | (q > spec.upper_rad))
        if bad.size:
            j = int(bad[0])
            lim = spec.lower_rad[j] if q[j] < spec.lower_rad[j] else spec.upper_rad[j]
            raise JobError(job.path, pos.line, f"{pos.name}: {what} {robot} joint {j + 1} at {np.degrees(q[j]):.6g} "
                                               f"deg is outside the limit {np.degrees(lim):.6g} deg")

    def _solve(self, job: Job, pos: JobPosition, robot: str, ik: ArmIk, R: np.ndarray, p: np.ndarray,
               q0: np.ndarray, what: str) -> IkResult:
        """The calibrated joints for a pose, from the programmed ``q0``: the exact solution, or, when that moves a
        joint by more than :data:`NEAR_SWITCH_DEG` or is not found (the wrist singularity, q5 ~ 0, where the last
        part of the orientation takes a swing of joints 4 and 6 against each other: 74 deg at the home position
        under the fbf13 model of 0801), :meth:`ArmIk.solve_near`'s: the position reached exactly, the orientation
        as near as the wrist allows. That one is taken when it moves every joint less than the exact one (and
        within ``max_joint_change_deg``) and leaves at most ``near_orientation_deg``."""
        res = ik.solve(R, p, q0)
        exact = res.converged and res.residual_mm <= self.tol_mm
        change = np.degrees(np.abs(res.q - q0).max()) if exact else np.inf
        if change > NEAR_SWITCH_DEG:
            near = ik.solve_near(R, p, q0)
            near_change = np.degrees(np.abs(near.q - q0).max())
            if (near.converged and near.residual_mm <= self.tol_mm and near_change < change
                    and near_change <= self.max_joint_change_deg and near.residual_deg <= self.near_orientation_deg):
                return near
            if near.converged and near_change <= self.max_joint_change_deg:
                self._near_left[pos.line] = near.residual_deg  # why the nearest solution was not taken
        if not res.converged or res.residual_mm > self.tol_mm:
            where = (f" (joint {', '.join(map(str, res.at_limit))} held at its limit)" if res.at_limit else "")
            raise JobError(job.path, pos.line, f"{pos.name}: the {what} {robot} cannot reach this pose within its "
                                               f"joint limits{where}: residual {res.residual_mm:.3g} mm, "
                                               f"{res.residual_deg:.3g} deg")
        return res

    def _pulse(self, job: Job, pos: JobPosition, robot: str) -> PointResult:
        spec = self.cell.robot(robot).robot
        nominal, calibrated = self._ik[robot]
        q_nom = spec.from_pulses(np.array(pos.values))
        self._limits(job, pos, robot, q_nom, "programmed")
        R, p = nominal.model.fk(q_nom[None])
        res = self._solve(job, pos, robot, calibrated, R[0], p[0], q_nom, "calibrated")
        pulses = spec.to_pulses(res.q)
        w_mm, w_deg = pose_error(calibrated.model, spec.from_pulses(pulses), R[0], p[0])
        return self._result(pos, robot, q_nom, res, [float(v) for v in pulses], w_mm, w_deg)

    def _cartesian(self, job: Job, pos: JobPosition, robot: str, seed: np.ndarray) -> PointResult:
        if pos.postype not in ("ROBOT", "BASE"):
            raise JobError(job.path, pos.line, f"{pos.name}: ///POSTYPE {pos.postype} positions are not compensated; "
                                               "valid: PULSE, ROBOT, BASE")
        if pos.postype == "BASE" and any(u.startswith("BS") for u in job.groups[pos.group - 1]):
            raise JobError(job.path, pos.line, f"{pos.name}: BASE coordinates with a base axis (BS) in the group "
                                               "are not supported; the base frame is taken as the robot frame")
        nominal, calibrated = self._ik[robot]
        R_t, p_t = R_from_rpy_deg(np.array(pos.values[3:6])), np.array(pos.values[:3])
        q_nom = self._nominal_solution(job, pos, robot, R_t, p_t, seed)
        res = self._solve(job, pos, robot, calibrated, R_t, p_t, q_nom, "calibrated")
        R, p = nominal.model.fk(res.q[None])
        after = [*p[0], *rpy_deg(R[0]), *pos.values[6:]]
        written = [float(f) for f in format_values(after, pos.decimals).split(",")]
        q_ctrl = nominal.solve(R_from_rpy_deg(np.array(written[3:6])), np.array(written[:3]), res.q).q
        w_mm, w_deg = pose_error(calibrated.model, q_ctrl, R_t, p_t)
        return self._result(pos, robot, q_nom, res, written, w_mm, w_deg)

    def _nominal_solution(self, job: Job, pos: JobPosition, robot: str, R_t: np.ndarray, p_t: np.ndarray,
                          seed: np.ndarray) -> np.ndarray:
        """The nominal arm's joints for a Cartesian position: from ``seed`` if that solve converges within the
        RCONF flags, else the converged solution nearest ``seed`` among :func:`_seeds`'s starts."""
        nominal = self._ik[robot][0]
        best: np.ndarray | None = None
        for k, start in enumerate(_seeds(seed, p_t)):
            res = nominal.solve(R_t, p_t, start)
            if not res.converged or res.residual_mm > self.tol_mm or not _rconf_ok(pos.rconf, res.q):
                continue
            if k == 0:
                return res.q
            if best is None or np.abs(res.q - seed).sum() < np.abs(best - seed).sum():
                best = res.q
        if best is None:
            raise JobError(job.path, pos.line, f"{pos.name}: the nominal {robot} reaches this pose nowhere within its "
                                               f"joint limits and ///RCONF {pos.rconf}; check the pose or program it "
                                               "in PULSE")
        return best

    def _result(self, pos: JobPosition, robot: str, q_nom: np.ndarray, res: IkResult, after: list[float],
                w_mm: float, w_deg: float) -> PointResult:
        q0, q1 = np.degrees(q_nom), np.degrees(res.q)
        before = list(pos.values)
        if pos.postype == "PULSE":
            before, after = [int(v) for v in before], [int(v) for v in after]
        return PointResult(pos.line, pos.name, pos.group, pos.unit, robot, pos.postype, pos.tool, before, after,
                           q0.tolist(), q1.tolist(), (q1 - q0).tolist(), res.residual_mm, res.residual_deg,
                           w_mm, w_deg, res.near)


def _rconf_ok(flags: tuple[int, ...] | None, q: np.ndarray) -> bool:
    """The ///RCONF flags this module checks agree with q [rad]: flip (flag 1) and R, T, S >= 180 deg (4-6).

    Flip (0) is the R axis within (-90, 90], (270, 360] or (-360, -270] deg, no-flip (1) otherwise (Yaskawa NX100
    operator's manual, "Manipulator Types"); flags 2 (upper/lower arm) and 3 (front/rear) are not checked.
    """
    flags = flags or ()
    r = float(np.degrees(q[3]))
    flip = -90.0 < r <= 90.0 or 270.0 < r <= 360.0 or -360.0 < r <= -270.0
    if flags and flags[0] != int(not flip):
        return False
    return all(flags[k] == int(abs(np.degrees(q[j])) >= 180.0) for k, j in _RCONF_JOINTS.items() if k < len(flags))


def _seeds(seed: np.ndarray, p_t: np.ndarray) -> list[np.ndarray]:
    """Starts of the nominal solve: ``seed`` first, then it and :data:`HOME_DEG` turned towards the target
    (joint 1), each with joint 6 turned by 0/+-180 deg and with the wrist flipped (q4 + 180, -q5, q6 + 180)."""
    toward = float(np.arctan2(p_t[1], p_t[0]))
    bases = [seed, np.r_[toward, seed[1:]], np.r_[toward, np.radians(HOME_DEG[1:])]]
    out = []
    for b in bases:
        for flip in (False, True):
            f = b + (np.array([0, 0, 0, np.pi, 0, np.pi]) if flip else 0.0)
            if flip:
                f[3], f[4] = np.arctan2(np.sin(f[3]), np.cos(f[3])), -f[4]
            out += [f + np.array([0, 0, 0, 0, 0, d]) for d in (0.0, np.pi, -np.pi)]
    return out
