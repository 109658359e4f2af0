"""The state connection (port 50241) to a MotoROS controller: a reader thread and the latest samples.

MotoROS publishes, per state connection, JointFeedback (15) for every group, JointFeedbackEx (2017) when
the controller has two groups or more, then RobotStatus (13) (StateServer.c, Ros_StateServer_SendState).
The reader keeps the latest sample of each and its local arrival time. When the connection drops it
reconnects with a doubling, capped back-off for as long as the stream runs (a restarted controller on the
same port is found again); readers get DriverDisconnected meanwhile.
"""

from __future__ import annotations

import logging
import socket
import threading
import time
from typing import TypeVar

from drivers.errors import DriverDisconnected, DriverError, DriverTimeout, ProtocolError
from drivers.motoros.codec import JointFeedback, JointFeedbackEx, Packet, RobotStatusMsg, decode
from drivers.motoros.framing import Framer, recv_into_framer

log = logging.getLogger("cellcal.drivers")

_M = TypeVar("_M", JointFeedback, RobotStatusMsg)


class StateStream:
    """Background reader of one controller's state port.

    Args:
        host: controller address.
        port: MotoROS state server port.
        device: name used in errors (``motoros@10.0.0.2:50241``).
        stop: set to end the reader (shared with the link).
        connect_timeout_s: longest wait for a TCP connect and for the first status [s].
        backoff_s: first delay between connection tries [s]; doubles up to ``max_backoff_s``.
        max_backoff_s: cap of the delay between tries [s].
        stale_after_s: a sample older than this [s] raises DriverTimeout.
    """

    def __init__(self, host: str, port: int, device: str, stop: threading.Event, *, connect_timeout_s: float,
                 backoff_s: float, max_backoff_s: float, stale_after_s: float) -> None:
        self.host = host
        self.port = port
        self.device = device
        self.connect_timeout_s = connect_timeout_s
        self.backoff_s = backoff_s
        self.max_backoff_s = max_backoff_s
        self.stale_after_s = stale_after_s
        self._stop = stop
        self._cond = threading.Condition()
        # latest sample and the local time.monotonic() [s] at which it arrived
        self._feedback: dict[int, tuple[JointFeedback, float]] = {}
        self._status: tuple[RobotStatusMsg, float] | None = None
        self._up = False
        self._error = "not connected yet"
        self.connections = 0  # state connections opened so far (reconnects included)
        self._reader: threading.Thread | None = None

    def start(self) -> None:
        """Start the reader thread (the caller has cleared ``stop``)."""
        self._reader = threading.Thread(target=self._read, name="motoros-state", daemon=True)
        self._reader.start()

    def join(self) -> None:
        """Wait for the reader to end after ``stop`` was set."""
        if self._reader is not None:
            self._reader.join(timeout=2.0)
            self._reader = None

    def wait_first_status(self) -> None:
        """Block until a RobotStatus has arrived; DriverTimeout after ``connect_timeout_s``."""
        deadline = time.monotonic() + self.connect_timeout_s
        with self._cond:
            while self._status is None:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise DriverTimeout(self.device, "the first robot status", self.connect_timeout_s)
                self._cond.wait(remaining)

    def _read(self) -> None:
        delay = self.backoff_s
        while not self._stop.is_set():
            try:
                sock = socket.create_connection((self.host, self.port), timeout=self.connect_timeout_s)
            except OSError as e:
                self._error = f"connect failed: {e}"
            else:
                if self._pump(sock):  # only a connection that delivered state resets the back-off: a peer that
                    delay = self.backoff_s  # accepts and sends garbage is retried ever more slowly, up to the cap
            if self._stop.wait(delay):
                break
            delay = min(2 * delay, self.max_backoff_s)

    def _pump(self, sock: socket.socket) -> bool:
        """Read state packets until the connection fails; True when at least one message decoded."""
        healthy = False
        framer = Framer(self.device)
        sock.settimeout(0.1)
        with self._cond:
            self._up = True
            self.connections += 1
        try:
            while not self._stop.is_set():
                try:
                    packets = recv_into_framer(sock, framer)
                except TimeoutError:
                    continue
                for packet in packets:
                    healthy = self._store(packet) or healthy
        except DriverError as e:
            log.warning("%s; reconnecting", e)
            self._error = e.reason
        finally:
            sock.close()
            with self._cond:
                self._up = False
                self._cond.notify_all()
        return healthy

    def _store(self, packet: Packet) -> bool:
        try:
            msg = decode(packet)
        except ProtocolError as e:
            log.debug("skipping state packet: %s", e)
            return False
        now = time.monotonic()
        with self._cond:
            if isinstance(msg, RobotStatusMsg):
                self._status = (msg, now)
            elif isinstance(msg, JointFeedback):
                self._feedback[msg.group] = (msg, now)
            elif isinstance(msg, JointFeedbackEx):
                for fb in msg.groups:
                    self._feedback[fb.group] = (fb, now)
            self._cond.notify_all()
        return True

    def _fresh(self, sample: tuple[_M, float] | None, what: str) -> tuple[_M, float]:
        if not self._up:
            raise DriverDisconnected(self.device, f"state connection down ({self._error})")
        if sample is None or time.monotonic() - sample[1] > self.stale_after_s:
            raise DriverTimeout(self.device, f"fresh {what}", self.stale_after_s)
        return sample

    def feedback(self, group: int) -> tuple[JointFeedback, float]:
        """Latest joint feedback of ``group`` and its arrival time [s, monotonic]; raises DriverDisconnected
        (connection down) or DriverTimeout (no sample newer than ``stale_after_s``)."""
        with self._cond:
            return self._fresh(self._feedback.get(group), f"joint feedback of group {group}")

    def status(self) -> tuple[RobotStatusMsg, float]:
        """Latest RobotStatus and its arrival time [s, monotonic]; raises like ``feedback``."""
        with self._cond:
            return self._fresh(self._status, "robot status")

    def wait(self, timeout_s: float) -> None:
        """Sleep until the next state packet arrives or ``timeout_s`` [s] passes."""
        with self._cond:
            self._cond.wait(timeout_s)
