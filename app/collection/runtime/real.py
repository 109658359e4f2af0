"""The real cell at run time: the counterpart of :class:`app.collection.runtime.sim.SimCell` built from ``cell.yaml``.

:class:`RealCell` connects one :class:`~drivers.motoros.MotorosDriver` per arm (all arms share the
controller's single motion connection through one :class:`~drivers.motoros.MotorosLink`), opens the
collector's Zenoh session (``zenoh.roles.collector``) and subscribes to each arm's tool-marker rigid body as
published by ``cellcal mocap-bridge`` on the mocap PC. Motive reports its own world frame; every frame a
workflow reads goes through the arm's registration (``cellcal register``) into that arm's base frame
(:class:`BaseFrameMocap`), so every stored sample is in the base frame. A collection on an arm with no
registration is refused before anything connects.

When the mocap stream goes silent (the bridge was restarted, the network dropped) the mocap source waits for
it to come back, up to ``stream_wait_s``, instead of failing the measurement at once.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from app.collection.runtime.sim import park_q
from calibration.errors import CellCalError, ConfigError
from calibration.kinematics import so3
from drivers.base import MocapSource, RigidBodyFrame, RobotDriver
from drivers.bus import ZenohMocapSource, open_session
from drivers.errors import DriverDisconnected
from drivers.motoros import MotorosDriver, MotorosLink

log = logging.getLogger("cellcal.app")


class NotRegistered(CellCalError):
    """An arm has no mocap registration, so its measurements cannot be put into its base frame."""

    def __init__(self, robot: str, path: Any) -> None:
        self.robot = robot
        super().__init__(f"{robot} has no registration in {path}: run `cellcal register --robot {robot}` first "
                         "(a collection needs the mocap-world -> base transform)")


class BaseFrameMocap(MocapSource):
    """One arm's tool-marker frames moved from the mocap world into the arm's base frame.

    Args:
        inner: frames of this arm's rigid body only, in the mocap world (a Zenoh subscriber).
        T_world_base: the arm's base in the mocap world (4, 4) [mm], or None to pass frames through unchanged
            (the registration itself measures in the world frame).
        body_id: the id every frame is relabelled with (the collector filters on it).
        silent_after_s: no frame for this long means the stream has stopped (not just a short dropout).
        stream_wait_s: how long a read waits for a stopped stream to come back before DriverDisconnected.
    """

    def __init__(self, inner: MocapSource, T_world_base: np.ndarray | None, body_id: int, *,
                 silent_after_s: float = 1.0, stream_wait_s: float = 30.0) -> None:
        self.inner = inner
        self.body_id = body_id
        self.silent_after_s, self.stream_wait_s = silent_after_s, stream_wait_s
        T = np.eye(4) if T_world_base is None else np.linalg.inv(np.asarray(T_world_base, dtype=float))
        self._R_base_world, self._p_base_world = T[:3, :3], T[:3, 3]
        self._last_frame = time.monotonic()
        self.waits = 0  # times a read waited for a stopped stream

    @property
    def stats(self) -> Any:
        """The inner source's counters."""
        return self.inner.stats  # type: ignore[attr-defined]

    def connect(self) -> None:
        self.inner.connect()
        self._last_frame = time.monotonic()

    def close(self) -> None:
        self.inner.close()

    def read(self, timeout_s: float) -> list[RigidBodyFrame]:
        """Frames since the last call in the base frame; waits for a stopped stream (see the class doc).

        Raises:
            DriverDisconnected: the stream stayed silent for ``stream_wait_s`` more seconds.
        """
        frames = self.inner.read(timeout_s)
        if not frames and timeout_s > 0 and time.monotonic() - self._last_frame > self.silent_after_s:
            frames = self._wait_for_stream()
            if frames:
                return []  # the window in progress spans the outage: let the caller measure again
        if frames:
            self._last_frame = time.monotonic()
        return [self._to_base(f) for f in frames]

    def wait_first_frame(self, timeout_s: float, what: str) -> None:
        """Return once a frame has arrived (dropped: a measurement window starts after a move), or raise.

        Raises:
            DriverDisconnected: no frame of ``what`` within ``timeout_s`` [s].
        """
        if not self._frames_within(timeout_s):
            raise DriverDisconnected("mocap", f"no frames of {what} in {timeout_s:g} s, before any motion: start "
                                              "`cellcal mocap-bridge` on the mocap PC and check that Motive streams "
                                              "that rigid body")

    def _wait_for_stream(self) -> list[RigidBodyFrame]:
        self.waits += 1
        log.warning("mocap stream silent for %.1f s; waiting up to %.0f s for the bridge to come back",
                    time.monotonic() - self._last_frame, self.stream_wait_s)
        frames = self._frames_within(self.stream_wait_s)
        if not frames:
            raise DriverDisconnected("mocap", f"no frames for {self.stream_wait_s:.0f} s more; is `cellcal "
                                              "mocap-bridge` running and Motive streaming?")
        log.warning("mocap stream is back")
        return frames

    def _frames_within(self, timeout_s: float) -> list[RigidBodyFrame]:
        """The first frames the inner source delivers within ``timeout_s`` [s] (mocap-world), or [] at the deadline."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            frames = self.inner.read(min(0.5, max(deadline - time.monotonic(), 0.0)))
            if frames:
                self._last_frame = time.monotonic()
                return frames
        return []

    def _to_base(self, f: RigidBodyFrame) -> RigidBodyFrame:
        if not f.tracking_valid:
            return RigidBodyFrame(self.body_id, f.position_mm, f.quat_wxyz, f.marker_error_mm, False,
                                  f.capture_time, f.frame_number)
        p = self._R_base_world @ np.asarray(f.position_mm, dtype=float) + self._p_base_world
        R = self._R_base_world @ so3.quat_to_R(np.asarray(f.quat_wxyz, dtype=float))
        return RigidBodyFrame(self.body_id, p, so3.R_to_quat(R), f.marker_error_mm, True, f.capture_time,
                              f.frame_number)


class RealCell:
    """The arms on the real controller and the mocap through the bridge. A context manager like SimCell.

    Attributes (after :meth:`open`):
        drivers: robot name -> connected :class:`~drivers.motoros.MotorosDriver` (every arm of the controller:
            the other arms' live poses feed the safety checks).
        body_ids: robot name -> the id its frames carry in :meth:`mocap_for`.

    Args:
        cell: the cell description with ``controller``, ``mocap`` and (for collection) ``registration``.
        robots: arms whose mocap is read (default: every arm of the cell; empty: no mocap at all, e.g. for the
            contact validation, which reads the CAN probe instead).
        registered: True to require a registration of those arms and read their frames in the base frame;
            False to read mocap-world frames (for ``cellcal register``).
        stream_wait_s: how long a read waits for a stopped mocap stream [s]; None: the cell file's
            ``mocap.stream_wait_s`` (30 s by default).
        first_frame_s: how long :meth:`open` waits for the first frame of each arm's rigid body [s]: without the
            mocap an arm would reach its first target and wait ``stream_wait_s`` there before failing. None: the cell
            file's ``mocap.first_frame_s`` (5 s by default).
        reset_alarms: let START_TRAJ_MODE reset a standing controller alarm (MotoROS does); off by default, so a
            standing alarm refuses motion until the operator clears it or asks for the reset (``--reset-alarms``).
    """

    def __init__(self, cell: Any, robots: Sequence[str] | None = None, *, registered: bool = True,
                 stream_wait_s: float | None = None, first_frame_s: float | None = None,
                 reset_alarms: bool = False) -> None:
        self.cell = cell
        self.reset_alarms = reset_alarms
        self.robots = tuple(cell.robots if robots is None else robots)
        self.registered = registered
        if stream_wait_s is None:
            stream_wait_s = cell.mocap.stream_wait_s if cell.mocap is not None else 30.0
        self.stream_wait_s = stream_wait_s
        if first_frame_s is None:
            first_frame_s = cell.mocap.first_frame_s if cell.mocap is not None else 5.0
        self.first_frame_s = first_frame_s
        self.drivers: dict[str, RobotDriver] = {}
        self.body_ids = {name: i + 1 for i, name in enumerate(cell.robots)}
        self._mocap: dict[str, BaseFrameMocap] = {}
        self._session: Any = None
        self._link: Any = None
        self.check()

    def check(self) -> None:
        """Refuse, before anything connects, a cell that lacks a device block or a registration.

        Raises:
            ConfigError: no ``controller`` or ``mocap`` block, or an arm without a motion group or rigid body.
            NotRegistered: ``registered`` and an arm of ``robots`` has no registration.
        """
        cell = self.cell
        for name in self.robots:
            cell.robot(name)
        if cell.controller is None:
            raise ConfigError(cell.path, "controller", "no controller block: the real cell needs the MotoROS "
                                                       "controller's host and motion groups (or run with --sim)")
        if cell.mocap is None and self.robots:
            raise ConfigError(cell.path, "mocap", "no mocap block: the real cell needs Motive's address and each "
                                                  "arm's rigid-body name (or run with --sim)")
        for name in cell.robots:
            if name not in cell.controller.groups:
                raise ConfigError(cell.path, "controller.groups", f"{name} has no motion group; valid keys are the "
                                                                  f"robots {', '.join(cell.robots)}")
        for name in self.robots:
            if name not in cell.mocap.rigid_bodies:
                raise ConfigError(cell.path, "mocap.rigid_bodies", f"{name} has no Motive rigid-body name")
            if self.registered and name not in cell.registration:
                raise NotRegistered(name, cell.registration_path)

    def park_q(self, robot: str) -> np.ndarray:
        """Parking pose [rad] of ``robot`` (6,)."""

        return park_q(robot)

    def open(self) -> RealCell:
        """Connect the controller and the mocap subscription and wait for each arm's first mocap frame; on failure
        whatever was opened is closed (nothing has moved)."""

        c = self.cell.controller
        try:
            self._link = MotorosLink(c.host, c.motion_port, c.state_port, reply_timeout_s=c.reply_timeout_s,
                                     connect_timeout_s=c.connect_timeout_s,
                                     start_traj_timeout_s=c.start_traj_timeout_s, reconnect_attempts=8,
                                     max_backoff_s=1.0)  # rides out a controller restart of a few seconds
            for name in self.cell.robots:
                spec = self.cell.robot(name).robot
                driver = MotorosDriver(self._link, c.groups[name], spec.max_speed_rad_s, name=name,
                                       reset_alarms=self.reset_alarms)
                driver.connect()
                self.drivers[name] = driver
            if self.robots:
                self._session = open_session(self.cell.zenoh_for("collector"))
            for name in self.robots:
                sub = ZenohMocapSource(self.cell.name, session=self._session,
                                       rigid_bodies=[self.cell.mocap.rigid_bodies[name]], max_buffered_frames=100_000)
                T = self.cell.registration[name].T_world_base if self.registered else None
                source = BaseFrameMocap(sub, T, self.body_ids[name], stream_wait_s=self.stream_wait_s)
                source.connect()
                self._mocap[name] = source
            for name, source in self._mocap.items():  # the mocap streams before anything moves
                source.wait_first_frame(self.first_frame_s, f"{name}'s rigid body "
                                                            f"{self.cell.mocap.rigid_bodies[name]!r}")
            log.info("real cell up: controller %s:%d, arms %s, mocap over zenoh", c.host, c.motion_port,
                     ", ".join(self.cell.robots))
        except BaseException:
            self.close()
            raise
        return self

    def mocap_for(self, robot: str) -> MocapSource:
        """The mocap source of ``robot``'s tool marker (base frame when registered)."""
        return self._mocap[robot]

    @property
    def frames_received(self) -> int:
        """Mocap frames received over Zenoh so far."""
        return sum(int(m.stats.received) for m in self._mocap.values())

    def others(self, robot: str) -> dict[str, RobotDriver]:
        """Drivers of every arm but ``robot``."""
        return {n: d for n, d in self.drivers.items() if n != robot}

    def stop_all(self) -> None:
        """Stop every arm now (MotoROS stops every group of the controller)."""
        for d in self.drivers.values():
            try:
                d.stop()
            except CellCalError as e:
                log.warning("could not stop %s: %s", d.name, e)

    def close(self) -> None:
        """Close the mocap subscriptions, the session and the drivers; safe to call twice."""
        for m in self._mocap.values():
            m.close()
        self._mocap.clear()
        if self._session is not None:
            try:
                self._session.close()
            except Exception as e:  # noqa: BLE001 - closing must not mask the error that brought us here
                log.warning("closing the zenoh session failed: %s", e)
            self._session = None
        for d in self.drivers.values():
            d.close()
        self.drivers.clear()

    def __enter__(self) -> RealCell:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()
