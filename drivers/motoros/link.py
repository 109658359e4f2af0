"""The two TCP connections to one MotoROS controller, shared by every motion group on it.

MotoROS accepts a single motion connection (port 50240) and a few state connections (port 50241) per
controller, so R1 and R2 on one controller cannot each open their own: they share one ``MotorosLink``.

* State (50241): a background reader (``state.StateStream``) keeps the latest JointFeedback per group and
  RobotStatus, and reconnects with a capped back-off for as long as the link is open.
* Motion connections are replaced before a request when the controller has closed them (MotoROS closes an
  idle motion connection when another client connects, and a restarted controller starts with none).
* Motion (50240): one request at a time (a lock), answered by a MotoMotionReply matched on
  (group, sequence, command). No reply in time raises DriverTimeout and drops the connection, so a late
  reply can never be taken for the answer to a later request; the next request reconnects (bounded tries).
  START_TRAJ_MODE gets its own, longer timeout: MotoROS answers it only after resetting alarms, turning the
  servos on and starting its INIT_ROS job, each waited for up to 5 s (MotionServer.c,
  Ros_MotionServer_StartTrajMode, MOTION_START_TIMEOUT), so up to ~15 s on a real controller; the default
  25 s leaves it margin (15 s had none), and ``start_traj_timeout_s`` (the cell file's) sets it.
* Trajectory mode is a controller-wide state: the link remembers that a START_TRAJ_MODE succeeded and sends
  STOP_TRAJ_MODE when its last user closes it (as motoman_driver does on shutdown), so the controller's
  INIT_ROS job ends and INFORM jobs can run again.
* One process per controller: MotoROS hands its single motion slot to whichever client connected last (an idle
  connection is closed for the newcomer), so two processes on one controller move its arms in turn, each
  reconnecting over the other. The first user of a link claims the controller on this machine (an exclusive
  ``flock`` on a file per controller address in :func:`lock_dir`, freed by the kernel when the process ends, even
  by a crash), and a second process's link of the same user is refused before it opens a connection, naming the
  holder. The claims live in a folder of this user only (``$XDG_RUNTIME_DIR``, else a 0700 folder under the system
  temporary folder; ``$CELLCAL_LOCK_DIR`` overrides), checked to be owned by the user and writable by no one else:
  a shared claim folder let another user plant a symlink there that a root collector truncated and made
  world-writable, and published every collector's command line.
"""

from __future__ import annotations

import logging
import os
import re
import select
import socket
import sys
import tempfile
import threading
import time
from pathlib import Path

from calibration.data.files import ExclusiveLock, LockHeld, private_folder
from drivers.errors import DriverDisconnected, DriverError, DriverTimeout, InvalidArgument
from drivers.motoros.codec import JointFeedback, MotionCtrl, MotionReply, RobotStatusMsg, decode
from drivers.motoros.codes import Command, Result
from drivers.motoros.framing import Framer, recv_into_framer
from drivers.motoros.state import StateStream

log = logging.getLogger("cellcal.drivers")

MOTION_PORT = 50240
STATE_PORT = 50241


def lock_dir() -> Path:
    """Folder of the controller claims: ``$CELLCAL_LOCK_DIR``, else ``cellcal-locks`` in ``$XDG_RUNTIME_DIR``, else
    ``cellcal-locks-<uid>`` in the temporary folder (not yet created or checked: :func:`claim_controller` does)."""
    if os.environ.get("CELLCAL_LOCK_DIR"):
        return Path(os.environ["CELLCAL_LOCK_DIR"])
    if os.environ.get("XDG_RUNTIME_DIR"):
        return Path(os.environ["XDG_RUNTIME_DIR"]) / "cellcal-locks"
    return Path(tempfile.gettempdir()) / f"cellcal-locks-{os.geteuid()}"


def claim_controller(host: str, port: int, device: str) -> ExclusiveLock:
    """An exclusive claim on the controller at ``host:port`` for this process (release it to let another process
    claim it; the kernel releases it when the process ends).

    Raises:
        DriverError: another process holds the claim (naming its pid and command line), or the claim file cannot
            be opened.
    """
    folder = lock_dir()
    path = folder / f"motoros-{re.sub(r'[^A-Za-z0-9.-]', '_', host)}-{port}.lock"
    try:
        private_folder(folder)  # this user's only: nobody else can plant a link or read the command line
        return ExclusiveLock(path, f"pid {os.getpid()}: {' '.join(sys.argv)}", mode=0o600)
    except LockHeld as e:
        raise DriverError(device, f"another process holds this controller ({e.holder or 'unknown'}); MotoROS serves "
                                  "one motion client and hands the arms to whichever connected last, so stop that "
                                  f"process first (claim file {path})") from None
    except OSError as e:
        where = e.filename or path
        raise DriverError(device, f"cannot open the controller claim {where}: {e.strerror or e}") from e


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
                 reply_timeout_s: float = 1.0, connect_timeout_s: float = 2.0, start_traj_timeout_s: float = 25.0,
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
        self._claim: ExclusiveLock | None = None  # this process's claim on the controller
        self._users = 0
        self._users_lock = threading.Lock()
        self._motion_lock = threading.Lock()
        self._motion: tuple[socket.socket, Framer] | None = None
        self._stop = threading.Event()
        self._state = StateStream(host, state_port, self.state_device, self._stop, connect_timeout_s=connect_timeout_s,
                                  backoff_s=backoff_s, max_backoff_s=max_backoff_s, stale_after_s=stale_after_s)

    # -- lifecycle -------------------------------------------------------------------------------
    def connect(self) -> None:
        """Open both connections (first user only) and wait for the first state packet."""
        with self._users_lock:
            self._users += 1
            if self._users > 1:
                return
            try:
                self._claim = claim_controller(self.host, self.motion_port, self.motion_device)
            except DriverError:
                self._users = 0
                raise
            self._stop.clear()
            self._state.start()
            try:
                with self._motion_lock:
                    self._motion_socket()
                self._state.wait_first_status()
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
        self._state.join()
        if self._claim is not None:
            self._claim.release()
            self._claim = None

    # -- state -----------------------------------------------------------------------------------
    @property
    def state_connections(self) -> int:
        """State connections opened so far (reconnects included)."""
        return self._state.connections

    def feedback(self, group: int) -> tuple[JointFeedback, float]:
        """Latest joint feedback of ``group`` and its arrival time [s, monotonic].

        Raises DriverDisconnected (state connection down) or DriverTimeout (no sample newer than
        ``stale_after_s``).
        """
        return self._state.feedback(group)

    def status(self) -> tuple[RobotStatusMsg, float]:
        """Latest controller status and its arrival time [s]; raises like ``feedback``."""
        return self._state.status()

    def wait_state(self, timeout_s: float) -> None:
        """Sleep until the next state packet arrives or ``timeout_s`` [s] passes."""
        self._state.wait(timeout_s)

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
