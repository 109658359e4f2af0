"""Small device interfaces: a robot driver and a motion-capture source.

Workflows depend only on these; each device kind has a simulated implementation that ships in the
package and real protocol adapters (MotoROS, NatNet).
"""

from __future__ import annotations

import abc
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class JointState:
    """Joint angles read from a controller.

    Attributes:
        q: joint angles [rad], shape (6,).
        stamp: time of the reading [s] (``time.monotonic()`` clock of the reader unless stated).
    """

    q: np.ndarray
    stamp: float


@dataclass(frozen=True)
class RobotStatus:
    """Controller status flags."""

    servo_on: bool
    alarm: bool
    e_stopped: bool
    in_motion: bool
    error_code: int = 0

    @property
    def ready(self) -> bool:
        """True when a motion may be commanded."""
        return self.servo_on and not self.alarm and not self.e_stopped


@dataclass(frozen=True)
class RigidBodyFrame:
    """One motion-capture measurement of one rigid body.

    Attributes:
        body_id: rigid-body id of the mocap system.
        position_mm: position [mm], shape (3,).
        quat_wxyz: unit quaternion (w, x, y, z), shape (4,).
        marker_error_mm: mean marker residual [mm].
        tracking_valid: False when the mocap system lost the body.
        capture_time: capture time [s] on the source's clock.
        frame_number: the source's frame counter.
    """

    body_id: int
    position_mm: np.ndarray
    quat_wxyz: np.ndarray
    marker_error_mm: float
    tracking_valid: bool
    capture_time: float
    frame_number: int = 0


class RobotDriver(abc.ABC):
    """One arm behind a controller. Use as a context manager."""

    name: str

    @abc.abstractmethod
    def connect(self) -> None:
        """Open the connection; raises DriverError on failure."""

    @abc.abstractmethod
    def read_joints(self) -> JointState:
        """Latest joint angles [rad] with their timestamp."""

    @abc.abstractmethod
    def status(self) -> RobotStatus:
        """Latest controller status."""

    @abc.abstractmethod
    def move_to(self, q: np.ndarray, speed_fraction: float) -> None:
        """Start a joint move to ``q`` [rad], shape (6,), at ``speed_fraction`` (0, 1] of the maximum speed.

        Safety checks (joint limits, collisions) belong to the caller's planner and must run before this.
        """

    @abc.abstractmethod
    def wait_settled(self, timeout_s: float, tolerance_rad: float = 1e-4) -> JointState:
        """Block until the arm stands still at its target; raises DriverTimeout."""

    @abc.abstractmethod
    def stop(self) -> None:
        """Stop any motion now."""

    @abc.abstractmethod
    def close(self) -> None:
        """Release the connection; safe to call twice."""

    def __enter__(self) -> RobotDriver:
        self.connect()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class MocapSource(abc.ABC):
    """A stream of rigid-body frames. Use as a context manager."""

    @abc.abstractmethod
    def connect(self) -> None:
        """Open the stream; raises DriverError on failure."""

    @abc.abstractmethod
    def read(self, timeout_s: float) -> list[RigidBodyFrame]:
        """Frames received since the last call, waiting up to ``timeout_s`` for at least one."""

    def stamp_clock(self) -> Callable[[], float] | None:
        """The clock whose rate the capture stamps keep, when it is not the host's: a simulated source's own clock
        (it may run faster or slower than real time). None: the stamps advance with the host's monotonic clock
        (a real mocap system, up to a constant offset). A wrapper answers for the source it wraps (``inner``)."""
        inner = getattr(self, "inner", None)
        return inner.stamp_clock() if isinstance(inner, MocapSource) else None

    @abc.abstractmethod
    def close(self) -> None:
        """Release the stream; safe to call twice."""

    def __enter__(self) -> MocapSource:
        self.connect()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
