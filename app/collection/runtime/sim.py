"""The simulated cell at run time: both arms, the mocap, and the Zenoh link between mocap and collector.

:class:`SimCell` builds, from a :class:`~cell_config.loader.CellSpec`, one simulated arm per robot (each
carrying a physics twin with its own planted geometric errors and a gravity-like joint compliance), a
simulated mocap seeing every arm's tool marker, and two real Zenoh sessions on loopback: the bridge session
(listening) publishes the mocap frames through a :class:`~drivers.bus.MocapBridge`, the collector session
(connecting to it) reads them through a :class:`~drivers.bus.ZenohMocapSource`. The collector therefore
consumes exactly what it would consume from the real NatNet bridge.

With multicast scouting off two sessions only meet when one connects to an endpoint the other listens on.
A listen endpoint with port 0 in ``cell.yaml`` means "any free port": the bridge session is given a free
port on that host and the collector session connects to it.
"""

from __future__ import annotations

import logging
import math
import socket
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from app.collection.motion import move_safely  # noqa: F401  (re-exported: the cell's guarded move)
from calibration.errors import ConfigError
from calibration.physics import PlantedErrors
from cell_config.devices import ZenohConfig
from cell_config.loader import CellSpec
from drivers.base import MocapSource, RobotDriver
from drivers.bus import MocapBridge, ZenohMocapSource, mocap_key, open_session, wait_for_subscriber
from drivers.errors import DriverError, DriverTimeout
from drivers.sim import SimClock, SimMocapConfig, SimMocapSource, SimRobotConfig, SimRobotDriver, cell_truths
from drivers.sim.rehearsal import hidden_frames

log = logging.getLogger("cellcal.app")

#: Parking poses [deg]: each arm turned away from the other, so the other arm can sweep its workspace.
PARK_DEG: dict[str, tuple[float, ...]] = {"R1": (-90.0, -20.0, -20.0, 0.0, 0.0, 0.0),
                                          "R2": (90.0, 0.0, 0.0, 0.0, 0.0, 0.0)}


#: Mocap frame periods a stepped simulated clock moves on per wait for frames (see :class:`SettledFrames`).
FRAMES_PER_STEP = 4


def park_q(robot: str) -> np.ndarray:
    """Parking pose [rad] of ``robot`` (6,): turned away from the other arm (zeros for an unknown name)."""
    return np.radians(PARK_DEG.get(robot, (0.0,) * 6))


@dataclass(frozen=True)
class SimCellOptions:
    """How the simulated cell behaves: the one set of options of every simulated cell (``demo``,
    ``collect --sim``, ``validate-dual --sim``, the tests).

    Attributes:
        time_scale: simulated seconds per real second (the arms, the mocap and every timeout follow it).
        mocap_rate_hz: mocap frame rate [Hz].
        noise_pos_mm: per-frame (per-sample) measurement position noise, per axis [mm].
        noise_rot_deg: per-frame (per-sample) measurement orientation noise, per axis [deg].
        errors: how wrong each arm is (planted by :func:`calibration.physics.planted_twin`).
        settle_time_s: simulated settling time after each move [s].
        seed: seed of everything planted or random; each robot gets its own derived seed.
        mocap_world: report the markers in a hidden mocap world frame derived from ``seed`` (as a real Motive
            does; what ``cellcal register --sim`` registers) instead of each arm's base frame.
        deterministic: run the simulated clock in steps of the workflow thread (``SimClock(stepped=True)``) and
            hand the collector every frame due by then before it reads on (``SettledFrames``): each dwell
            window then holds the same frames on every run, so the same seed measures the same values. The
            workflow must run in the thread that opens the cell.
    """

    time_scale: float = 20.0
    mocap_rate_hz: float = 60.0
    noise_pos_mm: float = 0.02
    noise_rot_deg: float = 0.005
    errors: PlantedErrors = PlantedErrors(compliance_mm=1.0)
    settle_time_s: float = 0.15
    seed: int = 0
    mocap_world: bool = False
    deterministic: bool = False


class SettledFrames(MocapSource):
    """The collector's view of a time-scaled simulated mocap: frames captured before a flush are dropped.

    The collector flushes (``read(0.0)``) once the arm has settled and then trusts the frames that follow. On
    the real cell frames are in flight for a few milliseconds against settling times of tenths of a second;
    with the simulated clock running many times faster than real time, a thread switch of the interpreter
    (5 ms real) is a tenth of a simulated second, so frames captured while the arm was still moving could
    arrive after the flush. This wrapper drops them by capture time (the simulated mocap stamps frames with
    the simulated clock), which restores the real cell's timing.

    On a stepped clock (``SimClock(stepped=True)``) a read also waits, in real time, until every frame captured
    up to the present simulated instant has come through Zenoh (``in_sync``), and moves the clock on by ``step_s``
    at a time while it waits for frames: what a read returns is then a function of simulated time only, not of
    when the bridge thread or Zenoh happened to deliver (they are not faked, only waited for).

    Args:
        inner: the mocap source the collector would read (the Zenoh subscriber).
        clock: the simulated clock the frames are stamped with.
        latency_s: the simulated mocap's capture-to-delivery latency [s].
        step_s: how far a stepped clock moves on per wait for frames [s]: a few frame periods, so a dwell window
            costs a few round trips to the bridge thread; which frames a window holds is decided by their
            stamps (:func:`~app.collection.mocap_window.collect_window`), not by how many each read returns.
        in_sync: whether every frame due by now has reached ``inner`` (needed with a stepped clock).
        sync_timeout_s: longest real wait for that [s]; then the read fails as a driver timeout.
    """

    def __init__(self, inner: MocapSource, clock: SimClock, latency_s: float, step_s: float | None = None,
                 in_sync: Callable[[], bool] | None = None, sync_timeout_s: float = 10.0) -> None:
        if clock.stepped and (in_sync is None or step_s is None):
            raise ConfigError("SimCell", "mocap", "a stepped clock needs a step and an in-sync check")
        self.inner = inner
        self.clock = clock
        self.latency_s = latency_s
        self.step_s = step_s
        self.in_sync = in_sync
        self.sync_timeout_s = sync_timeout_s
        self._not_before = -math.inf

    @property
    def stats(self) -> Any:
        """The inner source's counters."""
        return self.inner.stats  # type: ignore[attr-defined]

    def connect(self) -> None:
        self.inner.connect()

    def stamp_clock(self) -> Callable[[], float]:
        """The simulated clock the frames are stamped with."""
        return self.clock.now

    def read(self, timeout_s: float) -> list[Any]:
        """Frames captured since the last flush, waiting up to ``timeout_s`` simulated seconds for one."""
        if timeout_s == 0.0:
            self._not_before = self.clock.now() - self.latency_s
        if self.clock.stepped:
            return self._read_stepped(timeout_s)
        deadline = self.clock.now() + timeout_s
        while True:
            remaining = max(0.0, deadline - self.clock.now())
            got = self.inner.read(remaining / self.clock.time_scale)
            frames = [f for f in got if f.capture_time >= self._not_before]
            if frames or remaining <= 0.0:
                return frames

    def _read_stepped(self, timeout_s: float) -> list[Any]:
        """Every frame due by now, in capture order; while none, the clock steps ``step_s`` (to the deadline)."""
        deadline = self.clock.now() + timeout_s
        while True:
            self.wait_in_sync()
            frames = [f for f in self.inner.read(0.0) if f.capture_time >= self._not_before]
            if frames or self.clock.now() >= deadline:
                return sorted(frames, key=lambda f: (f.frame_number, f.body_id))
            self.clock.advance(min(self._step_s(), deadline - self.clock.now()))

    def _step_s(self) -> float:
        """The stepped clock's step [s] (``__init__`` refuses a stepped clock without one)."""
        if self.step_s is None:
            raise ConfigError("SimCell", "mocap", "a stepped clock needs a step and an in-sync check")
        return self.step_s

    def wait_in_sync(self) -> None:
        """Stepped clock: wait (in real time) until every frame captured up to now has come through Zenoh.

        Raises:
            DriverTimeout: not within ``sync_timeout_s`` [s, real time].
        """

        limit = time.monotonic() + self.sync_timeout_s
        while not self.in_sync():  # type: ignore[misc]
            if time.monotonic() > limit:
                raise DriverTimeout("sim:mocap", "the frames due by now to come through zenoh", self.sync_timeout_s)
            time.sleep(2e-4)

    def close(self) -> None:
        self.inner.close()


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port that was free on ``host`` a moment ago."""
    with socket.socket() as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def loopback_pair(config: ZenohConfig) -> tuple[ZenohConfig, ZenohConfig]:
    """Session settings of the bridge (listens) and the collector (connects to the bridge).

    Listen endpoints ``tcp/<host>:0`` get a free port; the collector connects to every bridge endpoint
    (plus the cell's own connect endpoints, e.g. a router).

    Raises:
        ConfigError: the cell listens nowhere and connects nowhere (the two sessions could not meet).
    """
    listen = list(config.listen) or ["tcp/127.0.0.1:0"]
    resolved = []
    for endpoint in listen:
        proto, _, rest = endpoint.partition("/")
        host, _, port = rest.rpartition(":")
        if proto == "tcp" and port == "0" and host:
            endpoint = f"tcp/{host}:{free_port(host)}"
        resolved.append(endpoint)
    if config.mode == "client":
        if not config.connect:
            raise ConfigError("cell.yaml", "zenoh.connect", "client mode needs a router endpoint to connect to")
        return config, config
    connect = [e.replace("0.0.0.0", "127.0.0.1") for e in resolved]
    bridge = replace(config, listen=tuple(resolved))
    collector = replace(config, listen=(), connect=tuple(connect) + tuple(config.connect))
    return bridge, collector


class SimCell:
    """Both simulated arms, the simulated mocap and the Zenoh bridge/subscriber pair. A context manager.

    Attributes (after :meth:`open`):
        drivers: robot name -> :class:`~drivers.sim.SimRobotDriver` (connected, at its parking pose).
        body_ids: robot name -> rigid-body id of its tool marker.
        subscriber: the :class:`~drivers.bus.ZenohMocapSource` reading the bridge's frames.
        mocap: the collector's mocap source: ``subscriber`` behind :class:`SettledFrames`.
        bridge: the :class:`~drivers.bus.MocapBridge` publishing the simulated mocap.
        truths: robot name -> the twin behind its simulated arm (for tests; never read by a workflow).

    Args:
        cell: the cell description.
        config: simulation options.
        robots: the arms to simulate (default: every arm of the cell).
    """

    def __init__(self, cell: CellSpec, config: SimCellOptions = SimCellOptions(),
                 robots: tuple[str, ...] | None = None) -> None:
        self.cell = cell
        self.config = config
        self.robots = tuple(robots or cell.robots)
        for name in self.robots:
            cell.robot(name)
        self.drivers: dict[str, Any] = {}
        self.truths: dict[str, Any] = {}
        self.body_ids = {name: i + 1 for i, name in enumerate(self.robots)}
        self.mocap: MocapSource | None = None
        self.subscriber: ZenohMocapSource | None = None
        self.bridge: MocapBridge | None = None
        self._sim_mocap: SimMocapSource | None = None
        self.clock: Any = None
        self._sessions: list[Any] = []

    def park_q(self, robot: str) -> np.ndarray:
        """Parking pose [rad] of ``robot`` (6,)."""
        return park_q(robot)

    def open(self) -> SimCell:
        """Build and connect everything; on failure whatever was opened is closed again."""

        c = self.config
        try:
            self.clock = clock = SimClock(c.time_scale, stepped=c.deterministic)
            for name, truth in cell_truths(self.cell, c.seed, c.errors, self.robots).items():
                r = self.cell.robot(name)
                driver = SimRobotDriver(name, r.robot, truth, q0=self.park_q(name), clock=clock,
                                        config=SimRobotConfig(settle_time_s=c.settle_time_s))
                driver.connect()
                self.drivers[name], self.truths[name] = driver, truth
            world = None
            if c.mocap_world:
                hidden = hidden_frames(self.cell, c.seed)
                world = {self.body_ids[n]: hidden[n].T_world_base for n in self.robots}
            self._sim_mocap = SimMocapSource(
                {self.body_ids[n]: self.drivers[n] for n in self.robots},
                SimMocapConfig(rate_hz=c.mocap_rate_hz, noise_pos_mm=c.noise_pos_mm, noise_rot_deg=c.noise_rot_deg,
                               buffer_frames=int(30 * c.mocap_rate_hz), seed=c.seed),  # 30 s: a slow bridge catches up
                T_ref_base=world)
            self._sim_mocap.connect()
            bridge_cfg, collector_cfg = loopback_pair(self.cell.zenoh)
            bridge_session = open_session(bridge_cfg)
            self._sessions.append(bridge_session)
            collector_session = open_session(collector_cfg)
            self._sessions.append(collector_session)
            names = {self.body_ids[n]: self.cell.robot(n).tool.rigid_body for n in self.robots}
            self.subscriber = ZenohMocapSource(self.cell.name, session=collector_session,
                                               rigid_bodies=list(names.values()), max_buffered_frames=100_000)
            self.subscriber.connect()
            self.mocap = SettledFrames(self.subscriber, clock, self._sim_mocap.config.latency_s,
                                       FRAMES_PER_STEP / c.mocap_rate_hz, self._frames_in_sync)
            for body in names.values():
                if not wait_for_subscriber(bridge_session, mocap_key(self.cell.name, body), 10.0):
                    raise DriverError("zenoh", f"the collector session never matched the bridge on "
                                               f"{mocap_key(self.cell.name, body)} within 10 s "
                                               f"(bridge {bridge_cfg.listen}, collector {collector_cfg.connect})")
            self.bridge = MocapBridge(self._sim_mocap, bridge_session, self.cell.name, names,
                                      poll_s=0.02 * c.time_scale)
            self.bridge.start()
            log.info("simulated cell up: %s, mocap %g Hz over zenoh %s, time x%g", ", ".join(self.robots),
                     c.mocap_rate_hz, ", ".join(bridge_cfg.listen), c.time_scale)
        except BaseException:
            self.close()
            raise
        return self

    def _frames_in_sync(self) -> bool:
        """Whether every frame the simulated mocap had due by now went through the bridge and reached the collector."""
        sim, bridge, sub = self._sim_mocap, self.bridge, self.subscriber
        if sim is None or bridge is None or sub is None:
            return False
        published = bridge.published
        return sim.delivered_all_due() and published == sim.delivered and sub.stats.received >= published

    @property
    def frames_received(self) -> int:
        """Mocap frames the collector received over Zenoh so far.

        On a stepped clock (``deterministic``) once every frame due by the present simulated instant has arrived,
        so the count is a function of simulated time, like everything measured: without that wait it depended on
        whether the bridge thread had published the frames of the last simulated moments yet, which at a fast
        time scale it often had not (``cellcal demo``'s count differed between runs of one seed).
        """
        if self.subscriber is None:
            return 0
        if self.clock is not None and self.clock.stepped and isinstance(self.mocap, SettledFrames):
            self.mocap.wait_in_sync()
        return int(self.subscriber.stats.received)

    def others(self, robot: str) -> dict[str, RobotDriver]:
        """Drivers of every arm but ``robot`` (their live poses feed the safety checks)."""
        return {n: d for n, d in self.drivers.items() if n != robot}

    def mocap_for(self, robot: str) -> MocapSource:
        """The collector's mocap source for ``robot`` (one source carries every body; frames carry body ids)."""
        if self.mocap is None:
            raise ConfigError("SimCell", "mocap", "the simulated cell is not open")
        return self.mocap

    def stop_all(self) -> None:
        """Stop every simulated arm now."""
        for d in self.drivers.values():
            d.stop()

    def close(self) -> None:
        """Stop the bridge, close the sessions and the devices; safe to call twice."""
        if self.bridge is not None:
            self.bridge.close()
            self.bridge = None
        if self.subscriber is not None:
            self.subscriber.close()
            self.subscriber = None
        self.mocap = None
        for s in reversed(self._sessions):
            try:
                s.close()
            except Exception as e:  # noqa: BLE001 - closing must not mask the error that brought us here
                log.warning("closing a zenoh session failed: %s", e)
        self._sessions.clear()
        if self._sim_mocap is not None:
            self._sim_mocap.close()
            self._sim_mocap = None
        for d in self.drivers.values():
            d.close()

    def __enter__(self) -> SimCell:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()
