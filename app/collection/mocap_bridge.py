"""The mocap PC's process: NatNet in, Zenoh out, until stopped (``cellcal mocap-bridge``).

:class:`BridgeService` connects to Motive (``mocap`` block of ``cell.yaml``), resolves each arm's rigid-body
**name** to Motive's id from the server's model definitions, and publishes every frame of those bodies on
``cellcal/<cell>/mocap/<name>`` through a :class:`~drivers.bus.MocapBridge` on the bridge's Zenoh session
(``zenoh.roles.bridge``). When Motive goes away (no frame for ``frame_timeout_s``, or the connection fails) it
closes the NatNet client and connects again with a capped back-off, for as long as it runs; the Zenoh session
stays up, so collectors keep their subscriptions. Its health is published once a second on
``cellcal/<cell>/health/mocap-bridge`` as JSON (:meth:`BridgeService.health`).
"""

from __future__ import annotations

import json
import logging
import os
import threading
import time
from dataclasses import asdict, dataclass
from typing import Any

from calibration.errors import ConfigError
from drivers.bus import MocapBridge, open_session
from drivers.errors import DriverError
from drivers.natnet import NatNetSource

log = logging.getLogger("cellcal.app")


def health_key(cell: str, process: str) -> str:
    """Key expression of a process's health messages."""
    return f"cellcal/{cell}/health/{process}"


@dataclass(frozen=True)
class BridgeHealth:
    """What the bridge says about itself.

    Attributes:
        state: ``connecting`` (no Motive yet), ``streaming`` or ``stopped``.
        natnet_version: the stream's NatNet version, ``""`` before the first connection.
        bodies: Motive id -> published rigid-body name.
        frames_published: frames published since the process started.
        last_frame_age_s: seconds since the last published frame (-1 before the first).
        connections: times the bridge (re)connected its NatNet client to Motive.
        handshakes: NAT_SERVERINFO answers received over all connections; the client handshakes again by itself
            when Motive restarts, so more handshakes than connections means Motive came back on its own.
        last_error: the last connection error, ``""`` if none.
        pid: process id. time: wall-clock time of the message [s].
    """

    state: str
    natnet_version: str
    bodies: dict[str, str]
    frames_published: int
    last_frame_age_s: float
    connections: int
    handshakes: int
    last_error: str
    pid: int
    time: float


class BridgeService:
    """NatNet -> Zenoh with reconnection and health. Call :meth:`run` until ``stop`` is set.

    Args:
        cell: the cell description (``name``, ``mocap``, ``zenoh_for("bridge")``).
        stop: set it to end :meth:`run` (the CLI sets it on SIGINT / SIGTERM).
        frame_timeout_s: no frame for this long means Motive is gone: reconnect.
        connect_timeout_s: how long one connection attempt waits for Motive's answer.
        max_backoff_s: cap of the delay between connection attempts.
    """

    def __init__(self, cell: Any, stop: threading.Event, *, frame_timeout_s: float = 2.0,
                 connect_timeout_s: float = 2.0, max_backoff_s: float = 2.0) -> None:

        if cell.mocap is None:
            raise ConfigError(cell.path, "mocap", "no mocap block: the bridge needs Motive's address and the "
                                                  "rigid-body names")
        self.cell, self.stop = cell, stop
        self.frame_timeout_s, self.connect_timeout_s = frame_timeout_s, connect_timeout_s
        self.max_backoff_s = max_backoff_s
        self.state = "connecting"
        self.version = ""
        self.names: dict[int, str] = {}
        self.published = 0
        self.connections = 0
        self.last_error = ""
        self._last_frame = -1.0
        self._source: Any = None
        self._past_handshakes = 0
        self._session: Any = None
        self._health_pub: Any = None
        self._last_health = 0.0

    def health(self) -> BridgeHealth:
        """The bridge's state now."""
        age = -1.0 if self._last_frame < 0 else time.monotonic() - self._last_frame
        handshakes = self._past_handshakes + (self._source.stats.handshakes if self._source is not None else 0)
        return BridgeHealth(self.state, self.version, {str(k): v for k, v in self.names.items()}, self.published,
                            round(age, 3), self.connections, handshakes, self.last_error, os.getpid(), time.time())

    def run(self) -> None:
        """Serve until ``stop`` is set; the Zenoh session is opened first and closed last.

        Raises:
            DriverError: the Zenoh session cannot be opened (bad endpoints, port in use).
        """

        self._session = open_session(self.cell.zenoh_for("bridge"))
        try:
            self._health_pub = self._session.declare_publisher(health_key(self.cell.name, "mocap-bridge"))
            backoff = 0.1
            while not self.stop.is_set():
                source = self._connect()
                if source is None:
                    self._publish_health(force=True)
                    self.stop.wait(backoff)
                    backoff = min(2 * backoff, self.max_backoff_s)
                    continue
                backoff = 0.1
                self._source = source
                try:
                    self._stream(source)
                finally:
                    self._past_handshakes += source.stats.handshakes
                    self._source = None
                    source.close()
            self.state = "stopped"
            self._publish_health(force=True)
        finally:
            if self._health_pub is not None:
                self._health_pub.undeclare()
            self._session.close()

    def _connect(self) -> Any:
        """A connected NatNet client with the bodies resolved, or None (the error is kept for the health)."""

        m = self.cell.mocap
        source = NatNetSource(m.server_address, local_address=m.local_address, command_port=m.command_port,
                              data_port=m.data_port, multicast_group=m.multicast_group if m.multicast else None,
                              connect_timeout_s=self.connect_timeout_s, max_buffered_frames=100_000)
        self.state = "connecting"
        try:
            source.connect()
            ids = source.rigid_body_ids(self.connect_timeout_s)
            wanted = dict(m.rigid_bodies)
            missing = [name for name in wanted.values() if name not in ids]
            if missing:
                raise DriverError(source.device, f"Motive defines no rigid body named {', '.join(missing)}; it "
                                                 f"defines {', '.join(sorted(ids)) or 'none'}")
        except DriverError as e:
            source.close()
            if str(e) != self.last_error:
                log.warning("mocap bridge: %s", e)
            self.last_error = str(e)
            return None
        self.names = {ids[name]: name for name in wanted.values()}
        self.version = ".".join(str(v) for v in (source.version or ()))
        self.connections += 1
        self.state = "streaming"
        self._last_frame = time.monotonic()
        log.warning("mocap bridge: streaming %s from Motive %s (NatNet %s)",
                    ", ".join(f"{n} (id {i})" for i, n in self.names.items()), m.server_address, self.version)
        return source

    def _stream(self, source: Any) -> None:
        """Publish the wanted bodies' frames until Motive goes silent or ``stop`` is set."""

        bridge = MocapBridge(source, self._session, self.cell.name, self.names)
        try:
            while not self.stop.is_set():
                frames = [f for f in source.read(0.05) if f.body_id in self.names]
                for f in frames:
                    bridge.publish(f)
                if frames:
                    self.published += len(frames)
                    self._last_frame = time.monotonic()
                elif time.monotonic() - self._last_frame > self.frame_timeout_s:
                    self.last_error = f"no frames from Motive for {self.frame_timeout_s:g} s"
                    log.warning("mocap bridge: %s; reconnecting", self.last_error)
                    return
                self._publish_health()
        finally:
            bridge.close()

    def _publish_health(self, force: bool = False) -> None:
        now = time.monotonic()
        if not force and now - self._last_health < 1.0:
            return
        self._last_health = now
        try:
            self._health_pub.put(json.dumps(asdict(self.health())))
        except Exception as e:  # noqa: BLE001 - health is best effort; the stream matters more
            log.debug("health not published: %s", e)
