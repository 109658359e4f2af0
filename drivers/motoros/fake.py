"""A fake MotoROS controller on loopback: the real wire protocol, simulated arms, injectable faults.

It binds a motion port and a state port (0 = ephemeral; read ``motion_port`` / ``state_port`` after
``start``), simulates several motion groups that follow queued trajectory points at a finite joint speed,
publishes JointFeedback (15) per group, JointFeedbackEx (2017) and RobotStatus (13) at ``publish_hz``, and
answers motion requests the way MotoROS does: one motion connection at a time, trajectory mode needed
before points, point 0 must match the current position, BUSY when the queue is full, NOT_READY with a
subcode on alarm / e-stop / servo off. Faults for tests: ``set_alarm``, ``set_estop``, ``set_servo``,
``drop_connections``, ``stall_replies``, ``split_messages`` and ``inject_state_bytes``.
"""

from __future__ import annotations

import logging
import socket
import threading
import time

import numpy as np

from drivers.errors import DriverError, ProtocolError
from drivers.motoros.codec import (Command, JointFeedback, JointFeedbackEx, JointTrajPtFull, JointTrajPtFullEx,
                                   Message, MotionCtrl, MotionReply, Result, RobotStatusMsg, ValidFields,
                                   decode)
from drivers.motoros.fake_arm import SimulatedGroup
from drivers.motoros.framing import Framer, recv_into_framer

log = logging.getLogger("cellcal.drivers")

_POLL_S = 0.05


def _hang_up(sock: socket.socket) -> None:
    """Close ``sock`` now: shutdown sends the FIN even while another thread is blocked on the socket."""
    try:
        sock.shutdown(socket.SHUT_RDWR)
    except OSError:
        pass  # already disconnected
    sock.close()


class FakeMotorosController:
    """Simulated MotoROS controller. Use as a context manager, or call ``start`` and ``close``.

    Args:
        n_groups: number of motion groups (0 = R1, 1 = R2, ...).
        n_joints: joints per group.
        max_speed_rad_s: joint speed limit of the simulation [rad/s], scalar or shape (n_joints,).
        publish_hz: state publication and simulation rate [Hz].
        host: address to bind.
        motion_port: motion port to bind; 0 picks a free one.
        state_port: state port to bind; 0 picks a free one.
        initial_q: starting joint angles [rad], shape (n_groups, n_joints); zeros by default.
    """

    def __init__(self, n_groups: int = 2, n_joints: int = 6, max_speed_rad_s: float | np.ndarray = 2.0,
                 publish_hz: float = 100.0, host: str = "127.0.0.1", motion_port: int = 0,
                 state_port: int = 0, initial_q: np.ndarray | None = None) -> None:
        if not 1 <= n_groups <= 4:
            raise ValueError(f"n_groups must be 1..4, got {n_groups}")
        self.host = host
        self.motion_port = motion_port
        self.state_port = state_port
        self.period_s = 1.0 / publish_hz
        self.groups = [SimulatedGroup(n_joints, max_speed_rad_s) for _ in range(n_groups)]
        if initial_q is not None:
            q0 = np.asarray(initial_q, dtype=float)
            if q0.shape != (n_groups, n_joints):
                raise ValueError(f"initial_q must have shape ({n_groups}, {n_joints}), got {q0.shape}")
            for group, q in zip(self.groups, q0):
                group.q = q.copy()
        self.received: list[Message] = []  # every decoded request, for tests to inspect
        self._lock = threading.Lock()
        self._servo_on = True
        self._e_stopped = False
        self._alarm_code = 0
        self._traj_mode = False
        self._stall = False
        self._chunk: tuple[int, float] | None = None
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._listeners: list[socket.socket] = []
        self._motion_client: socket.socket | None = None
        self._state_clients: list[socket.socket] = []

    # -- lifecycle -------------------------------------------------------------------------------
    def start(self) -> "FakeMotorosController":
        """Bind both ports and start the threads; returns self."""
        motion = socket.create_server((self.host, self.motion_port))
        state = socket.create_server((self.host, self.state_port))
        self._listeners = [motion, state]
        self.motion_port = motion.getsockname()[1]
        self.state_port = state.getsockname()[1]
        for target, args in ((self._accept, (motion, self._on_motion_client)),
                             (self._accept, (state, self._on_state_client)), (self._simulate, ())):
            self._spawn(target, args)
        return self

    def close(self) -> None:
        """Stop every thread and close every socket; safe to call twice."""
        self._stop.set()
        self.drop_connections()
        for sock in self._listeners:
            sock.close()
        while self._threads:  # an acceptor may still spawn a handler until it sees the stop flag
            self._threads.pop().join(timeout=2.0)

    def __enter__(self) -> "FakeMotorosController":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _spawn(self, target, args: tuple) -> None:  # noqa: ANN001 (any callable)
        thread = threading.Thread(target=target, args=args, name="fake-motoros", daemon=True)
        self._threads.append(thread)
        thread.start()

    # -- faults and inspection -------------------------------------------------------------------
    def set_alarm(self, code: int = 4107) -> None:
        """Raise an alarm (``code`` > 0) or clear it (0); an alarm stops all motion."""
        with self._lock:
            self._alarm_code = code
            self._halt_if_faulted()

    def set_estop(self, pressed: bool) -> None:
        """Press or release the e-stop; pressing it stops all motion and turns the servos off."""
        with self._lock:
            self._e_stopped = pressed
            self._servo_on = self._servo_on and not pressed
            self._halt_if_faulted()

    def set_servo(self, on: bool) -> None:
        """Switch the servo power."""
        with self._lock:
            self._servo_on = on
            self._halt_if_faulted()

    def stall_replies(self, stalled: bool) -> None:
        """While stalled, motion requests are read and never answered."""
        self._stall = stalled

    def split_messages(self, chunk_bytes: int | None, delay_s: float = 0.0002) -> None:
        """Send every message in ``chunk_bytes`` pieces ``delay_s`` [s] apart (None: whole messages)."""
        self._chunk = None if chunk_bytes is None else (chunk_bytes, delay_s)

    def drop_connections(self) -> None:
        """Close every client connection (the ports stay open, so clients can reconnect)."""
        with self._lock:
            clients = self._state_clients + ([self._motion_client] if self._motion_client else [])
            self._state_clients = []
            self._motion_client = None
        for sock in clients:
            _hang_up(sock)

    def inject_state_bytes(self, data: bytes) -> None:
        """Write raw bytes to every state connection (garbage, a forged length, ...)."""
        with self._lock:
            for sock in self._state_clients:
                self._send(sock, data)

    def q(self, group: int) -> np.ndarray:
        """Current simulated joint angles of ``group`` [rad]."""
        with self._lock:
            return self.groups[group].q.copy()

    # -- connections -----------------------------------------------------------------------------
    def _accept(self, listener: socket.socket, on_client) -> None:  # noqa: ANN001
        listener.settimeout(_POLL_S)
        while not self._stop.is_set():
            try:
                sock, _ = listener.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            on_client(sock)

    def _on_state_client(self, sock: socket.socket) -> None:
        sock.settimeout(1.0)
        with self._lock:
            self._state_clients.append(sock)

    def _on_motion_client(self, sock: socket.socket) -> None:
        with self._lock:
            busy = self._motion_client is not None
            if not busy:
                self._motion_client = sock
        if busy:  # MotoROS serves a single motion connection
            log.info("fake motoros: refusing a second motion connection")
            sock.close()
            return
        self._spawn(self._serve_motion, (sock,))

    def _send(self, sock: socket.socket, data: bytes) -> bool:
        try:
            if self._chunk is None:
                sock.sendall(data)
            else:
                size, delay = self._chunk
                for i in range(0, len(data), size):
                    sock.sendall(data[i:i + size])
                    time.sleep(delay)
        except OSError:
            return False
        return True

    def _serve_motion(self, sock: socket.socket) -> None:
        framer = Framer("fake-motoros-motion")
        sock.settimeout(_POLL_S)
        try:
            while not self._stop.is_set():
                try:
                    packets = recv_into_framer(sock, framer)
                except TimeoutError:
                    continue
                for packet in packets:
                    try:
                        reply = self._answer(decode(packet))
                    except ProtocolError:  # MotoROS answers an unknown or mis-sized message, it does not hang up
                        reply = MotionReply(-1, -1, packet.msg_type, Result.INVALID, 3001)
                    if not self._stall and not self._send(sock, reply.encode()):
                        return
        except DriverError as e:
            log.info("fake motoros: motion client gone: %s", e)
        finally:
            with self._lock:
                if self._motion_client is sock:
                    self._motion_client = None
                    self._traj_mode = False
            sock.close()

    # -- protocol --------------------------------------------------------------------------------
    def _not_ready_subcode(self) -> int:
        """MotoROS NOT_READY subcode for the present faults, 0 when ready (caller holds the lock)."""
        if self._e_stopped:
            return 5003
        if self._alarm_code:
            return 5001
        if not self._servo_on:
            return 5006
        return 0

    def _answer(self, msg: Message) -> MotionReply:
        with self._lock:
            self.received.append(msg)
            if isinstance(msg, MotionCtrl):
                return self._answer_ctrl(msg)
            if isinstance(msg, JointTrajPtFull):
                result, sub = self._accept_point(msg.group, msg.sequence, msg.time, msg.pos)
                return MotionReply(msg.group, msg.sequence, msg.TYPE, result, sub)
            if isinstance(msg, JointTrajPtFullEx):
                for point in msg.groups:
                    result, sub = self._accept_point(point.group, msg.sequence, point.time, point.pos)
                    if result != Result.SUCCESS:
                        break
                return MotionReply(msg.groups[0].group, msg.sequence, msg.TYPE, result, sub)
            return MotionReply(-1, -1, msg.TYPE, Result.INVALID, 3003)

    def _answer_ctrl(self, msg: MotionCtrl) -> MotionReply:
        sub = self._not_ready_subcode()
        result, data = Result.SUCCESS, ()
        if msg.command == Command.CHECK_MOTION_READY:
            sub = sub or (0 if self._traj_mode else 5008)
            result = Result.NOT_READY if sub else Result.SUCCESS
        elif msg.command == Command.CHECK_QUEUE_CNT:
            sub, data = 0, (float(len(self.groups[msg.group].queue)) if msg.group < len(self.groups) else -1.0,)
        elif msg.command == Command.START_TRAJ_MODE:
            result = Result.NOT_READY if sub else Result.SUCCESS
            self._traj_mode = not sub
        elif msg.command in (Command.STOP_MOTION, Command.STOP_TRAJ_MODE):
            sub = 0
            for group in self.groups:
                group.halt()
            self._traj_mode = self._traj_mode and msg.command == Command.STOP_MOTION
        else:
            result, sub = Result.INVALID, 3006
        return MotionReply(msg.group, msg.sequence, msg.command, result, sub, data)

    def _accept_point(self, group: int, sequence: int, time_s: float, pos: np.ndarray) -> tuple[Result, int]:
        if not 0 <= group < len(self.groups):
            return Result.INVALID, 3004
        sub = self._not_ready_subcode() or (0 if self._traj_mode else 5008)
        if sub:
            return Result.NOT_READY, sub
        return self.groups[group].accept_point(sequence, time_s, pos)

    def _halt_if_faulted(self) -> None:
        if self._not_ready_subcode():
            self._traj_mode = False
            for group in self.groups:
                group.halt()

    # -- simulation and publication --------------------------------------------------------------
    def _simulate(self) -> None:
        start = time.monotonic()
        while not self._stop.wait(self.period_s):
            now = time.monotonic()
            with self._lock:
                feedback = []
                for i, group in enumerate(self.groups):
                    group.step(now)
                    feedback.append(JointFeedback(i, group.q, group.qd, time=now - start,
                                                  valid_fields=ValidFields.TIME | ValidFields.POSITION
                                                  | ValidFields.VELOCITY))
                status = RobotStatusMsg(
                    drives_powered=int(self._servo_on), e_stopped=int(self._e_stopped),
                    error_code=self._alarm_code, in_error=int(self._alarm_code != 0),
                    in_motion=int(any(g.moving for g in self.groups)), mode=2,
                    motion_possible=int(self._traj_mode and not self._not_ready_subcode()))
                clients = list(self._state_clients)
            data = b"".join(fb.encode() for fb in feedback) + JointFeedbackEx(tuple(feedback)).encode()
            data += status.encode()
            for sock in clients:
                if not self._send(sock, data):
                    with self._lock:
                        if sock in self._state_clients:
                            self._state_clients.remove(sock)
                    sock.close()
