"""Guarded motion of the cell's arms: every move goes through the same cell-safety check.

A move is commanded only after :meth:`~app.collection.safety.CellSafety.check_motion` accepted the joint-space path from
the arm's live (finite) joint reading to the target, with the other arms at their live poses. Joint feedback
that is not six finite numbers is a :class:`NonFiniteFeedback` (a :class:`~drivers.errors.DriverError`), so it
never reaches the safety check's arithmetic nor ``move_to``. :func:`stop_all` stops every arm it is given and
reports which ones it could not stop.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping

import numpy as np

from app.collection.safety import CellSafety
from drivers.base import RobotDriver
from drivers.errors import DriverError

log = logging.getLogger("cellcal.app")


class NonFiniteFeedback(DriverError):
    """A controller reported joint angles that are not six finite numbers; the arm's pose is unknown.

    Attributes:
        robot: the robot name.
        q: what was read.
    """

    def __init__(self, device: str, robot: str, q: np.ndarray) -> None:
        self.robot = robot
        self.q = q
        super().__init__(device, f"{robot} joint feedback is not 6 finite numbers ({np.array2string(q, precision=4)}); "
                                 "its pose is unknown, no motion is commanded")


def device_name(driver: RobotDriver) -> str:
    """The driver's device label (``sim:R1``, ``motoros@host``), or its robot name."""
    return str(getattr(driver, "device", driver.name))


def read_q(driver: RobotDriver) -> np.ndarray:
    """The arm's joint angles [rad], shape (6,).

    Raises:
        NonFiniteFeedback: the reading is not 6 finite numbers (NaN, inf, wrong shape).
        DriverError: the driver failed to read.
    """
    q = np.asarray(driver.read_joints().q, dtype=float)
    if q.shape != (6,) or not np.all(np.isfinite(q)):
        raise NonFiniteFeedback(device_name(driver), driver.name, q)
    return q


def live_poses(drivers: Mapping[str, RobotDriver]) -> dict[str, np.ndarray]:
    """Joint angles [rad] (6,) of every arm in ``drivers``, read now (each through :func:`read_q`)."""
    return {name: read_q(d) for name, d in drivers.items()}


def move_safely(driver: RobotDriver, q: np.ndarray, safety: CellSafety, others: Mapping[str, RobotDriver],
                speed_fraction: float = 0.5, timeout_s: float = 60.0, tolerance_rad: float = 1e-4,
                index: int | None = None) -> np.ndarray:
    """Check the joint-space path to ``q`` against limits, floor and the other arms' live poses, then move.

    Args:
        driver: the arm to move.
        q: target joint angles [rad], shape (6,).
        safety: the cell's :class:`~app.collection.safety.CellSafety`.
        others: drivers of the other arms (their live poses feed the collision check).
        speed_fraction: fraction (0, 1] of the maximum joint speeds.
        timeout_s: longest wait for the arm to settle [s].
        tolerance_rad: standstill tolerance passed to the driver [rad].
        index: target number for the error messages.

    Returns:
        The settled joint angles [rad], shape (6,).

    Raises:
        UnsafeTarget: the move is refused before any motion.
        NonFiniteFeedback: an arm's joint feedback is not finite (nothing moves).
    """
    q = np.asarray(q, dtype=float)
    q_now = read_q(driver)
    safety.check_motion(driver.name, q_now, q, live_poses(others), index)
    driver.move_to(q, speed_fraction)
    driver.wait_settled(timeout_s, tolerance_rad)
    return read_q(driver)


def stop_all(drivers: Mapping[str, RobotDriver]) -> list[str]:
    """Stop every arm in ``drivers`` (each tried even when another fails).

    Returns:
        Names of the arms that could not be stopped (each failure is logged).
    """
    failed = []
    for name, d in drivers.items():
        try:
            d.stop()
        except DriverError as e:
            log.warning("could not stop %s: %s", name, e)
            failed.append(name)
    return failed


__all__ = ["NonFiniteFeedback", "device_name", "live_poses", "move_safely", "read_q", "stop_all"]
