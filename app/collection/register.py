"""``cellcal register``: find where the mocap world is relative to an arm, and where its marker sits.

The arm visits a short registration plan around a centre pose (single-joint rotations of every joint and a
spread of poses, :func:`calibration.frames.registration.registration_plan`), checked against the cell's safety model
before the first motion like every plan. At each pose the tool marker is measured in the **mocap world** (a
dwell window, as in a collection). :class:`~calibration.frames.registration.RegistrationProblem` then solves the
mocap-world -> base and tool-marker -> flange transforms (6 + 6 parameters) with their residuals and
uncertainties; the CLI writes them into the cell's registration file. With both arms registered in one mocap
world, R2's base in R1's frame follows from the data (:func:`relative_bases`).
"""

from __future__ import annotations

import datetime as _dt
import logging
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from tqdm import tqdm

from app.collection.mocap_window import ClockLink, WindowFailed, average_frames, collect_window
from app.collection.motion import move_safely, stop_all
from app.collection.runtime.cell import Cell
from calibration.errors import CellCalError
from calibration.frames.registration import RegistrationProblem, registration_plan, transform_difference
from calibration.kinematics import so3
from cell_config.registration import RobotRegistration

log = logging.getLogger("cellcal.app")


class RegistrationFailed(CellCalError):
    """The registration could not be measured or solved; nothing was written."""


@dataclass(frozen=True)
class RegistrationRun:
    """What one ``register`` run measured and solved.

    Attributes:
        robot: the arm.
        q: joint angles read at each pose [rad], shape (M, 6).
        R_world_marker, p_world_marker: averaged marker poses in the mocap world, (M, 3, 3) and (M, 3) [mm].
        result: the solver's :class:`~calibration.frames.registration.RegistrationResult`.
        skipped: indices of plan poses that could not be measured, with the reason.
    """

    robot: str
    q: np.ndarray
    R_world_marker: np.ndarray
    p_world_marker: np.ndarray
    result: Any
    skipped: tuple[tuple[int, str], ...]

    def registration(self) -> Any:
        """The result as the cell file's :class:`~cell_config.registration.RobotRegistration`."""

        r = self.result
        return RobotRegistration(
            T_world_base=r.T_world_base, T_flange_marker=r.T_flange_marker,
            date=_dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"), rms_mm=float(r.rms_mm),
            rms_deg=float(r.rms_deg), n_samples=int(r.n_samples), sigma_world_base=np.asarray(r.sigma_world_base),
            sigma_flange_marker=np.asarray(r.sigma_flange_marker))


def plan_registration(cell: Any, robot: str, q_center: np.ndarray, safety: Any, others: Mapping[str, np.ndarray],
                      q_start: np.ndarray, *, sweep_deg: float = 20.0, seed: int = 0) -> np.ndarray:
    """The registration poses (M, 6) [rad] around ``q_center``, checked safe from ``q_start``.

    Raises:
        UnsafeTarget: a pose or a path between poses is unsafe (before any motion).
    """

    spec = cell.robot(robot).robot
    lower, upper = safety.limits(robot)
    q_plan = registration_plan(np.maximum(lower, spec.lower_rad), np.minimum(upper, spec.upper_rad),
                               np.asarray(q_center, dtype=float), sweep_deg=sweep_deg, seed=seed)
    safety.check_plan(robot, q_plan, dict(others), np.asarray(q_start, dtype=float))
    return q_plan


def measure_registration(rt: Cell, safety: Any, robot: str, q_plan: np.ndarray, config: Any, *,
                         progress: bool = True, clock: Callable[[], float] = time.monotonic) -> RegistrationRun:
    """Visit every pose, measure the marker in the mocap world, solve; the arm returns to its start pose (after a
    fault or Ctrl-C every arm is stopped instead and nothing moves again).

    Args:
        rt: the open :class:`~app.collection.runtime.cell.Cell` (a RealCell with ``registered=False``, or a
            SimCell reading the mocap world).
        safety: the cell's safety checker (every move is checked against the other arms' live poses).
        robot: the arm to register.
        q_plan: the poses [rad] (M, 6).
        config: :class:`~app.collection.collect.CollectConfig` (speed, dwell window, retries).
        clock: the host clock the settle instants are read on, unless the source keeps its own (a simulated one).

    Raises:
        RegistrationFailed: fewer than 6 poses measured, or the solver did not converge.
    """

    driver, others = rt.drivers[robot], rt.others(robot)
    mocap, body = rt.mocap_for(robot), rt.body_ids[robot]
    q_home = driver.read_joints().q
    link = ClockLink(mocap.stamp_clock() or clock)
    qs, Rs, ps, skipped = [], [], [], []
    try:
        for i, q_target in enumerate(tqdm(q_plan, desc=f"{robot} register", unit="pose", disable=not progress)):
            move_safely(driver, q_target, safety, others, config.speed_fraction, config.settle_timeout_s)
            settled_at = link.clock()
            for attempt in range(config.mocap_retries + 1):
                try:
                    frames = collect_window(mocap, body, config, link, settled_at)
                    break
                except WindowFailed as e:
                    reason = str(e)
                    log.warning("registration pose %d: %s (attempt %d)", i, reason, attempt + 1)
            else:
                skipped.append((i, reason))
                continue
            p, quat, *_ = average_frames(frames)
            qs.append(driver.read_joints().q)
            Rs.append(so3.quat_to_R(quat))
            ps.append(p)
    except BaseException:  # an alarm, a lost controller, Ctrl-C: stop every arm, never start another move
        stop_all({robot: driver, **others})
        raise
    move_safely(driver, q_home, safety, others, config.speed_fraction, config.settle_timeout_s)
    if len(qs) < 6:
        raise RegistrationFailed(f"{robot}: only {len(qs)} of {len(q_plan)} registration poses measured "
                                 f"({'; '.join(r for _, r in skipped[:3])})")
    q, R, p = np.array(qs), np.array(Rs), np.array(ps)
    result = RegistrationProblem(rt.cell.robot(robot).model(), q, R, p).solve()  # the tool YAML: a second start
    if not result.converged:
        raise RegistrationFailed(f"{robot}: the registration did not converge (rms {result.rms_mm:.3f} mm after "
                                 f"{result.iterations} iterations); nothing written")
    return RegistrationRun(robot, q, R, p, result, tuple(skipped))


def relative_bases(cell: Any, registrations: Mapping[str, Any], reference: str = "R1") -> dict[str, dict[str, Any]]:
    """Each other arm's base in ``reference``'s base frame from the registrations, against ``cell.yaml``.

    Returns:
        robot -> ``{"T_ref_base": 4x4 list, "cell_yaml_diff_mm": float, "cell_yaml_diff_deg": float}`` for every
        registered arm other than ``reference`` (empty when ``reference`` is not registered).
    """

    if reference not in registrations:
        return {}
    T_w_ref = np.asarray(registrations[reference].T_world_base, dtype=float)
    T_cell_ref = np.asarray(cell.robot(reference).T_cell_base, dtype=float)
    out = {}
    for name, reg in registrations.items():
        if name == reference:
            continue
        T = np.linalg.inv(T_w_ref) @ np.asarray(reg.T_world_base, dtype=float)
        T_yaml = np.linalg.inv(T_cell_ref) @ np.asarray(cell.robot(name).T_cell_base, dtype=float)
        d_mm, d_deg = transform_difference(T, T_yaml)
        out[name] = {"T_ref_base": T.tolist(), "cell_yaml_diff_mm": float(d_mm), "cell_yaml_diff_deg": float(d_deg)}
    return out


#: A registered base that differs from cell.yaml's by more than this gets a hint to update the cell file [mm, deg]:
#: well above a registration's uncertainty (its sigma_world_base, hundredths of a mm on the rehearsal cell) and the
#: size at which the planner's relative pose, the safety checks and the preview (all from cell.yaml) are visibly off.
BASE_HINT_MM, BASE_HINT_DEG = 0.5, 0.05


def base_update_hint(cell: Any, name: str, diff: Mapping[str, Any], reference: str = "R1") -> str | None:
    """What to do when ``name``'s registered base differs from cell.yaml's (``diff``: a :func:`relative_bases`
    entry): the block to put into cell.yaml as ``robots.<name>.T_cell_base`` (the registered base in the cell
    frame, ``T_cell_ref @ T_ref_base``) and where. None when the difference is within BASE_HINT_MM/DEG."""
    if diff["cell_yaml_diff_mm"] <= BASE_HINT_MM and diff["cell_yaml_diff_deg"] <= BASE_HINT_DEG:
        return None
    T_cell_base = np.asarray(cell.robot(reference).T_cell_base, dtype=float) @ np.asarray(diff["T_ref_base"])
    rows = "\n".join(f"      - [{', '.join(f'{v:.9g}' if j < 3 else f'{v:.6f}' for j, v in enumerate(row))}]"
                     for row in T_cell_base[:3])
    return (f"{name}'s registered base differs from {cell.path}'s by {diff['cell_yaml_diff_mm']:.3f} mm / "
            f"{diff['cell_yaml_diff_deg']:.4f} deg (hint above {BASE_HINT_MM:g} mm / {BASE_HINT_DEG:g} deg): the "
            f"planner, the safety checks and the preview use the cell file's. Update it: in {cell.path}, replace "
            f"robots.{name}.T_cell_base with\n"
            f"    T_cell_base:  # {name}'s base in the cell frame, from cellcal register\n{rows}\n"
            f"      - [0, 0, 0, 1]\n"
            f"then check it: cellcal --cell {cell.path} plan-dual --path sweep:10 --out /tmp/check_plan.json")
