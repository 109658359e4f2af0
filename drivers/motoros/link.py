"""The two TCP connections to one MotoROS controller, shared by every motion group on it.

MotoROS accepts a single motion connection (port 50240) and a few state connections (port 50241) per
controller, so R1 and R2 on one controller cannot each open their own: they share one ``MotorosLink``.

* State (50241): a background thread reads JointFeedback (15), JointFeedbackEx (2017) and RobotStatus (13)
  and keeps the latest sample per group. When the connection drops it reconnects with a doubling,
  capped back-off for as long as the link is open; readers get DriverDisconnected meanwhile.
* Motion (50240): one request at a time (a lock), answered by a MotoMotionReply matched on
  (group, sequence, command). No reply in time raises DriverTimeout and drops the connection, so a late
  reply can never be taken for the answer to a later request; the next request reconnects (bounded tries).
  START_TRAJ_MODE gets its own, longer timeout: MotoROS answers it only after resetting alarms, turning the
  servos on and starting its INIT_ROS job, each waited for up to 5 s (MotionServer.c,
  Ros_MotionServer_StartTrajMode, MOTION_START_TIMEOUT), so ~10 s is normal on a real controller.
* Trajectory mode is a controller-wide state: the link remembers that a START_TRAJ_MODE succeeded and sends
  STOP_TRAJ_MODE when its last user closes it (as motoman_driver does on shutdown), so the controller's
  INIT_ROS job ends and INFORM jobs can run again.
"""

from __future__ import annotations

import logging
import select
import socket
import threading
import time
from typing import TypeVar

from drivers.errors import DriverDisconnected, DriverError, DriverTimeout, ProtocolError
from drivers.motoros.codec import (Command, JointFeedback, JointFeedbackEx, MotionCtrl, MotionReply, Packet,
                                   Result, RobotStatusMsg, decode)
from drivers.motoros.errors import InvalidArgument
from drivers.motoros.framing import Framer, recv_into_framer

log = logging.getLogger("cellcal.drivers")

MOTION_PORT = 50240
STATE_PORT = 50241


_M = TypeVar("_M", JointFeedback, RobotStatusMsg)


def _peer_closed(sock: socket.socket) -> bool:
    """True when the peer has closed ``sock`` (readable with nothing to read, or an error pending)."""
    try:
        readable, _, _ = select.select([sock], [], [], 0.0)
        return bool(readable) and sock.recv(1, socket.MSG_PEEK | socket.MSG_DONTWAIT) == b""
    except BlockingIOError:
        return False
    except OSError:
        return True


class MotorosLink:
    """Shared state and motion connections to one controller; connect/close are reference counted.

    Args:
        host: controller address.
        motion_port: MotoROS motion server port.
        state_port: MotoROS state server port.
        reply_timeout_s: longest wait for a motion reply [s].
        start_traj_timeout_s: longest wait for the reply to START_TRAJ_MODE [s] (alarm reset + servo on).
        connect_timeout_s: longest wait for a TCP connect and for the first state packet [s].
        reconnect_attempts: motion connection tries before DriverDisconnected.
        backoff_s: first delay between connection tries [s]; doubles up to ``max_backoff_s``.
        max_backoff_s: cap of the delay between tries [s].
        stale_after_s: feedback older than this [s] raises DriverTimeout.
    """

    def __init__(self, host: str, motion_port: int = MOTION_PORT, state_port: int = STATE_PORT, *,
                 reply_timeout_s: float = 1.0, connect_timeout_s: float = 2.0, start_traj_timeout_s: float = 15.0,
                 reconnect_attempts: int = 3, backoff_s: float = 0.05, max_backoff_s: float = 1.0,
                 stale_after_s: float = 0.5) -> None:
        self.motion_device = f"motoros@{host}:{motion_port}"
        self.state_device = f"motoros@{host}:{state_port}"
        if reconnect_attempts < 1:
            raise InvalidArgument(self.motion_device, "reconnect_attempts", reconnect_attempts, ">= 1")
        for name, value in (("reply_timeout_s", reply_timeout_s), ("connect_timeout_s", connect_timeout_s),
                            ("start_traj_timeout_s", start_traj_timeout_s), ("stale_after_s", stale_after_s)):
            if not value > 0:
                raise InvalidArgument(self.motion_device, name, value, "a positive number of seconds")
        self.host = host
        self.motion_port = motion_port
        self.state_port = state_port
        self.reply_timeout_s = reply_timeout_s
        self.start_traj_timeout_s = start_traj_timeout_s
        self.connect_timeout_s = connect_timeout_s
        self.reconnect_attempts = reconnect_attempts
        self.backoff_s = backoff_s
        self.max_backoff_s = max_backoff_s
        self.stale_after_s = stale_after_s
        self._traj_mode_group: int | None = None  # group whose START_TRAJ_MODE succeeded, until STOP_TRAJ_MODE
        self._users = 0
        self._users_lock = threading.Lock()
        self._motion_lock = threading.Lock()
        self._motion: tuple[socket.socket, Framer] | None = None
        self._state_cond = threading.Condition()
        # latest sample and the local time.monotonic() [s] at which it arrived
        self._feedback: dict[int, tuple[JointFeedback, float]] = {}
        self._status: tuple[RobotStatusMsg, float] | None = None
        self._state_up = False
        self.state_connections = 0  # state connections opened so far (reconnects included)
        self._state_error = "not connected yet"
        self._stop = threading.Event()
        self._reader: threading.Thread | None = None

    # -- lifecycle -------------------------------------------------------------------------------
    def connect(self) -> None:
        """Open both connections (first user only) and wait for the first state packet."""
        with self._users_lock:
            self._users += 1
            if self._users > 1:
                return
            self._stop.clear()
            self._reader = threading.Thread(target=self._read_state, name="motoros-state", daemon=True)
            self._reader.start()
            try:
                with self._motion_lock:
                    self._motion_socket()
                self._wait_first_status()
            except DriverError:
                self._users = 0
                self._shutdown()
                raise

    def close(self) -> None:
        """Release one user; the last one ends trajectory mode (if started), closes the sockets, joins the reader."""
        with self._users_lock:
            if self._users == 0:
                return
            if self._users == 1:
                self._stop_trajectory_mode()
            self._users -= 1
            if self._users == 0:
                self._shutdown()

    @property
    def trajectory_mode(self) -> bool:
        """True after a successful START_TRAJ_MODE through this link and until STOP_TRAJ_MODE."""
        return self._traj_mode_group is not None

    def _stop_trajectory_mode(self) -> None:
        """Send STOP_TRAJ_MODE if this link started trajectory mode; failures are logged, not raised."""
        group = self._traj_mode_group
        if group is None:
            return
        try:
            reply = self.request(MotionCtrl(group, 0, Command.STOP_TRAJ_MODE).encode(), group, 0,
                                 Command.STOP_TRAJ_MODE)
        except DriverError as e:
            log.warning("%s: STOP_TRAJ_MODE on close failed: %s", self.motion_device, e)
            return
        if reply.result != Result.SUCCESS:  # MotoROS refuses while a queue still holds motion
            log.warning("%s: STOP_TRAJ_MODE on close refused: %s (trajectory mode left on)", self.motion_device,
                        reply.describe())

    def _shutdown(self) -> None:
        self._stop.set()
        with self._motion_lock:
            self._drop_motion()
        if self._reader is not None:
            self._reader.join(timeout=2.0)
            self._reader = None

    def _wait_first_status(self) -> None:
        deadline = time.monotonic() + self.connect_timeout_s
        with self._state_cond:
            while self._status is None:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise DriverTimeout(self.state_device, "the first robot status", self.connect_timeout_s)
                self._state_cond.wait(remaining)

    # -- state -----------------------------------------------------------------------------------
    def _read_state(self) -> None:
        delay = self.backoff_s
        while not self._stop.is_set():
            try:
                sock = socket.create_connection((self.host, self.state_port), timeout=self.connect_timeout_s)
            except OSError as e:
                self._state_error = f"connect failed: {e}"
            else:
                delay = self.backoff_s
                self._pump_state(sock)
            if self._stop.wait(delay):
                break
            delay = min(2 * delay, self.max_backoff_s)

    def _pump_state(self, sock: socket.socket) -> None:
        framer = Framer(self.state_device)
        sock.settimeout(0.1)
        with self._state_cond:
            self._state_up = True
            self.state_connections += 1
        try:
            while not self._stop.is_set():
                try:
                    packets = recv_into_framer(sock, framer)
                except TimeoutError:
                    continue
                for packet in packets:
                    self._store(packet)
        except DriverError as e:
            log.warning("%s; reconnecting", e)
            self._state_error = e.reason
        finally:
            sock.close()
            with self._state_cond:
                self._state_up = False
                self._state_cond.notify_all()

    def _store(self, packet: Packet) -> None:
        try:
            msg = decode(packet)
        except ProtocolError as e:
            log.debug("skipping state packet: %s", e)
            return
        now = time.monotonic()
        with self._state_cond:
            if isinstance(msg, RobotStatusMsg):
                self._status = (msg, now)
            elif isinstance(msg, JointFeedback):
                self._feedback[msg.group] = (msg, now)
            elif isinstance(msg, JointFeedbackEx):
                for fb in msg.groups:
                    self._feedback[fb.group] = (fb, now)
            self._state_cond.notify_all()

    def _fresh(self, sample: tuple[_M, float] | None, what: str) -> tuple[_M, float]:
        if not self._state_up:
            raise DriverDisconnected(self.state_device, f"state connection down ({self._state_error})")
        if sample is None or time.monotonic() - sample[1] > self.stale_after_s:
            raise DriverTimeout(self.state_device, f"fresh {what}", self.stale_after_s)
        return sample

    def feedback(self, group: int) -> tuple[JointFeedback, float]:
        """Latest joint feedback of ``group`` and its arrival time [s, monotonic].

        Raises DriverDisconnected (state connection down) or DriverTimeout (no sample newer than
        ``stale_after_s``).
        """
        with self._state_cond:
            return self._fresh(self._feedback.get(group), f"joint feedback of group {group}")

    def status(self) -> tuple[RobotStatusMsg, float]:
        """Latest controller status and its arrival time [s]; raises like ``feedback``."""
        with self._state_cond:
            return self._fresh(self._status, "robot status")

    def wait_state(self, timeout_s: float) -> None:
        """Sleep until the next state packet arrives or ``timeout_s`` [s] passes."""
        with self._state_cond:
            self._state_cond.wait(timeout_s)

    # -- motion ----------------------------------------------------------------------------------
    def _motion_socket(self) -> tuple[socket.socket, Framer]:
        """The motion connection, opened with bounded back-off if needed; caller holds the motion lock.

        An idle connection the controller has closed is noticed here, before a request is written to it,
        and replaced, so a request is never lost on a connection that was already dead.
        """
        if self._motion is not None and _peer_closed(self._motion[0]):
            log.info("%s: controller closed the idle connection; reconnecting", self.motion_device)
            self._drop_motion()
        if self._motion is not None:
            return self._motion
        delay = self.backoff_s
        for attempt in range(1, self.reconnect_attempts + 1):
            try:
                sock = socket.create_connection((self.host, self.motion_port), timeout=self.connect_timeout_s)
            except OSError as e:
                log.info("%s: connect attempt %d/%d failed: %s", self.motion_device, attempt,
                         self.reconnect_attempts, e)
                if attempt == self.reconnect_attempts:
                    raise DriverDisconnected(self.motion_device,
                                             f"no connection after {attempt} attempts: {e}") from e
                if self._stop.wait(delay):
                    break
                delay = min(2 * delay, self.max_backoff_s)
            else:
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                self._motion = (sock, Framer(self.motion_device))
                return self._motion
        raise DriverDisconnected(self.motion_device, "link closed while connecting")

    def _drop_motion(self) -> None:
        if self._motion is not None:
            self._motion[0].close()
            self._motion = None

    def request(self, payload: bytes, group: int, sequence: int, command: int, *,
                timeout_s: float | None = None) -> MotionReply:
        """Send one encoded request and return the reply matching (group, sequence, command).

        ``timeout_s`` [s] overrides the reply timeout; by default START_TRAJ_MODE waits
        ``start_traj_timeout_s`` and everything else ``reply_timeout_s``.

        A connection opened for this request and closed by the controller before any reply means the
        controller refused it (its single motion slot is still held, e.g. by a connection it has not yet
        noticed is gone); that is retried with back-off up to ``reconnect_attempts`` times. Retrying is safe:
        the control commands are idempotent and a repeated trajectory point is rejected for its sequence.

        Raises:
            DriverDisconnected: no connection, or it broke (the request may or may not have arrived).
            DriverTimeout: no matching reply within the timeout.
            ProtocolError: the controller sent bytes that do not decode.
        """
        if self._users == 0:
            raise DriverDisconnected(self.motion_device, "link is not connected; call connect() first")
        if timeout_s is None:
            timeout_s = self.start_traj_timeout_s if command == Command.START_TRAJ_MODE else self.reply_timeout_s
        reply = self._request(payload, (group, sequence, command), timeout_s)
        if reply.result == Result.SUCCESS and command == Command.START_TRAJ_MODE:
            self._traj_mode_group = group
        elif reply.result == Result.SUCCESS and command in (Command.STOP_TRAJ_MODE, Command.DISCONNECT):
            self._traj_mode_group = None
        return reply

    def _request(self, payload: bytes, match: tuple[int, int, int], timeout_s: float) -> MotionReply:
        with self._motion_lock:
            delay = self.backoff_s
            for attempt in range(1, self.reconnect_attempts + 1):
                fresh = self._motion is None
                sock, framer = self._motion_socket()
                try:
                    return self._exchange(sock, framer, payload, match, timeout_s)
                except DriverDisconnected as e:
                    self._drop_motion()
                    if not fresh or attempt == self.reconnect_attempts:
                        raise
                    log.info("%s: connection refused by the controller (%s); retrying", self.motion_device,
                             e.reason)
                except DriverError:
                    self._drop_motion()
                    raise
                if self._stop.wait(delay):
                    break
                delay = min(2 * delay, self.max_backoff_s)
            raise DriverDisconnected(self.motion_device, "link closed while retrying")

    def _exchange(self, sock: socket.socket, framer: Framer, payload: bytes, match: tuple[int, int, int],
                  timeout_s: float) -> MotionReply:
        try:
            sock.sendall(payload)
        except OSError as e:
            raise DriverDisconnected(self.motion_device, f"send failed: {e}") from e
        deadline = time.monotonic() + timeout_s
        while (remaining := deadline - time.monotonic()) > 0:
            sock.settimeout(remaining)
            try:
                packets = recv_into_framer(sock, framer)
            except TimeoutError:
                continue
            for packet in packets:
                msg = decode(packet)
                if isinstance(msg, MotionReply) and (msg.group, msg.sequence, msg.command) == match:
                    return msg
                log.warning("%s: discarding unexpected %s", self.motion_device, type(msg).__name__)
        self._drop_motion()  # a late reply must never be read as the answer to a later request
        raise DriverTimeout(self.motion_device, f"reply to command {match[2]} (sequence {match[1]})", timeout_s)
