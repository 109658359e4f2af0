"""A fake MotoROS controller on loopback: the real wire protocol, simulated arms, injectable faults.

It binds a motion port and a state port (0 = ephemeral; read ``motion_port`` / ``state_port`` after
``start``; SO_REUSEADDR, so a restarted fake can take the ports of one that was killed), simulates several
motion groups (fake_arm), answers motion requests as MotoROS does (fake_logic) and publishes, per state
connection, JointFeedback (15) per group, JointFeedbackEx (2017) when there are two groups or more, then
RobotStatus (13) at ``publish_hz`` (StateServer.c, Ros_StateServer_SendState). Feedback carries position and
velocity, no time, as MotoROS's does.

Motion connections follow MotionServer.c (Ros_MotionServer_StartNewConnection, MAX_MOTION_CONNECTIONS = 1): a
new connection replaces an idle one, and is closed at once while a queue still holds motion. What the motion
server does with each message follows Ros_MotionServer_WaitForSimpleMsg and Ros_MotionServer_SimpleMsgProcess: a
type it has no size for (Ros_MotionServer_GetExpectedByteSizeForMessageType) is answered INVALID 3003 and the
connection stays; a type it knows but does not serve on the motion port (RobotStatus, JointFeedback(Ex), a
MotoMotionReply) drops the connection without a reply; a successful DISCONNECT closes it without a reply too.

Faults for tests: ``set_alarm``, ``set_estop``, ``set_servo``, ``set_mode``, ``set_remote``, ``set_hold``,
``set_nonfinite_feedback``, ``drop_connections``, ``stall_replies``, ``split_messages``, ``inject_state_bytes``.
"""

from __future__ import annotations

import collections
import logging
import socket
import threading
import time
from collections.abc import Callable

import numpy as np

from drivers.errors import DriverError, InvalidArgument, ProtocolError
from drivers.motoros.codec import (
    JointFeedback,
    JointFeedbackEx,
    JointTrajPtFull,
    JointTrajPtFullEx,
    Message,
    MotionReply,
    Packet,
    ValidFields,
    decode,
)
from drivers.motoros.codes import CommType, InvalidSubcode, MsgType, Result
from drivers.motoros.fake_arm import INTERPOLATION_PERIOD_S, SimulatedGroup
from drivers.motoros.fake_logic import SimulatedController
from drivers.motoros.framing import Framer, recv_into_framer

log = logging.getLogger("cellcal.drivers")

_POLL_S = 0.05
#: Decoded requests kept in order (``FakeMotorosController.received``).
MAX_KEPT_REQUESTS = 10_000
#: Types MotoROS's motion server has a size for but does not serve (SimpleMsgProcess's default: the connection
#: closes, no reply is sent).
_NOT_SERVED = {int(MsgType.ROBOT_STATUS), int(MsgType.JOINT_FEEDBACK), int(MsgType.MOTO_MOTION_REPLY),
               int(MsgType.JOINT_FEEDBACK_EX)}
#: Every type GetExpectedByteSizeForMessageType has a size for (SimpleMessage.h numbers): ping 1, the two point
#: types, MotoMotionCtrl, the I/O requests 2003/2005/2007/2009, SELECT_TOOL 2018, GET_DH_PARAMETERS 2020, and the
#: four not served. Those this fake does not implement (ping, I/O, tool, DH) it cannot decode and answers INVALID
#: 3001 (a liberty: MotoROS serves them).
_SIZED = {1, 14, 2001, 2016, 2003, 2005, 2007, 2009, 2018, 2020} | _NOT_SERVED
DEFAULT_PULSES_PER_RAD = 1.0e5  # a generic encoder (30 pulses = 0.3 mrad); fake_cell uses the robot YAML's
_DEVICE = "fake-motoros"


def _hang_up(sock: socket.socket) -> None:
    """Close ``sock`` now: shutdown sends the FIN even while another thread is blocked on the socket."""
    try:
        sock.shutdown(socket.SHUT_RDWR)
    except OSError:
        pass  # already disconnected
    sock.close()


def _per_group(value: float | np.ndarray, n_groups: int, n_joints: int, name: str) -> np.ndarray:
    """Broadcast a scalar, a (n_joints,) or a (n_groups, n_joints) array to (n_groups, n_joints)."""
    arr = np.asarray(value, dtype=float)
    try:
        return np.broadcast_to(arr, (n_groups, n_joints)).copy()
    except ValueError:
        expected = f"a scalar, ({n_joints},) or ({n_groups}, {n_joints})"
        raise InvalidArgument(_DEVICE, name, arr.shape, expected) from None


class FakeMotorosController:
    """Simulated MotoROS controller. Use as a context manager, or call ``start`` and ``close``.

    Args:
        n_groups: number of motion groups (0 = R1, 1 = R2, ...).
        n_joints: joints per group.
        max_speed_rad_s: joint speed limits [rad/s]: scalar, (n_joints,) or (n_groups, n_joints).
        publish_hz: state publication and simulation rate [Hz].
        host: address to bind.
        motion_port: motion port to bind; 0 picks a free one.
        state_port: state port to bind; 0 picks a free one.
        initial_q: starting joint angles [rad], shape (n_groups, n_joints); zeros by default.
        pulses_per_rad: encoder pulses per radian [1/rad]: scalar, (n_joints,) or (n_groups, n_joints); sets
            the 30-pulse tolerance of point 0.
        servo_on_delay_s: time START_TRAJ_MODE takes to turn the servos on [s] (seconds on a real one).
        interpolation_period_s: the controller's interpolation clock [s] (CHECK_QUEUE_CNT counts in it).
    """

    def __init__(self, n_groups: int = 2, n_joints: int = 6, max_speed_rad_s: float | np.ndarray = 2.0,
                 publish_hz: float = 100.0, host: str = "127.0.0.1", motion_port: int = 0,
                 state_port: int = 0, initial_q: np.ndarray | None = None, *,
                 pulses_per_rad: float | np.ndarray = DEFAULT_PULSES_PER_RAD, servo_on_delay_s: float = 0.1,
                 interpolation_period_s: float = INTERPOLATION_PERIOD_S) -> None:
        if not 1 <= n_groups <= 4:
            raise InvalidArgument(_DEVICE, "n_groups", n_groups, "1..4")
        speeds = _per_group(max_speed_rad_s, n_groups, n_joints, "max_speed_rad_s")
        pulses = _per_group(pulses_per_rad, n_groups, n_joints, "pulses_per_rad")
        q0 = np.zeros((n_groups, n_joints)) if initial_q is None else np.asarray(initial_q, dtype=float)
        if q0.shape != (n_groups, n_joints) or not np.all(np.isfinite(q0)):
            raise InvalidArgument(_DEVICE, "initial_q", q0, f"finite angles [rad] of shape ({n_groups}, {n_joints})")
        self.host = host
        self.motion_port = motion_port
        self.state_port = state_port
        self.period_s = 1.0 / publish_hz
        self._stop = threading.Event()
        self.groups = [SimulatedGroup(n_joints, s, p, q, interpolation_period_s) for s, p, q in zip(speeds, pulses, q0)]
        self.controller = SimulatedController(self.groups, servo_on_delay_s, self._stop.wait)
        self._lock = self.controller.lock
        # the latest decoded requests, for tests to inspect (a rehearsal sends ~100 points a second for hours: the
        # history is bounded); points_received counts every trajectory point
        self.received: collections.deque[Message] = collections.deque(maxlen=MAX_KEPT_REQUESTS)
        self.points_received = 0
        self._stall = False
        self.nonfinite_feedback = False  # publishing NaN / inf joint positions (set_nonfinite_feedback)
        self._nonfinite_value = float("nan")
        self._chunk: tuple[int, float] | None = None
        self._threads: list[threading.Thread] = []  # started threads only (_spawn holds _spawn_lock across both)
        self._spawn_lock = threading.Lock()
        self._listeners: list[socket.socket] = []
        self._motion_client: socket.socket | None = None
        self._state_clients: list[socket.socket] = []

    # -- lifecycle -------------------------------------------------------------------------------
    def start(self) -> FakeMotorosController:
        """Bind both ports (SO_REUSEADDR) and start the threads; returns self."""
        self._listeners = []
        self._listeners.append(self._listen(self.motion_port, "motion"))
        self._listeners.append(self._listen(self.state_port, "state"))
        motion, state = self._listeners
        self.motion_port = motion.getsockname()[1]
        self.state_port = state.getsockname()[1]
        for target, args in ((self._accept, (motion, self._on_motion_client)),
                             (self._accept, (state, self._on_state_client)), (self._simulate, ())):
            self._spawn(target, args)
        return self

    def _listen(self, port: int, role: str) -> socket.socket:
        """A listening socket on ``port``; a port already taken (another fake controller) is a DriverError naming
        it, with the sockets bound so far closed (the CLI's one line, exit 2, instead of an OSError traceback)."""
        try:
            return socket.create_server((self.host, port), reuse_port=False)
        except OSError as e:
            for sock in self._listeners:
                sock.close()
            self._listeners = []
            raise DriverError(f"fake-motoros@{self.host}:{port}", f"cannot listen on the {role} port {port} "
                                                                 f"({e.strerror or e}); is another fake controller "
                                                                 "or a MotoROS client already using it?") from e

    def close(self) -> None:
        """Stop every thread and close every socket; safe to call twice."""
        self._stop.set()
        self.drop_connections()
        for sock in self._listeners:
            sock.close()
        while True:  # an acceptor may still spawn a handler until it sees the stop flag
            with self._spawn_lock:  # a thread is listed only once started: never joined before its start
                if not self._threads:
                    break
                thread = self._threads.pop()
            thread.join(timeout=2.0)

    def __enter__(self) -> FakeMotorosController:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _spawn(self, target: Callable[..., None], args: tuple[object, ...]) -> None:
        thread = threading.Thread(target=target, args=args, name="fake-motoros", daemon=True)
        with self._spawn_lock:  # close() joins what it finds listed: list a thread only together with its start
            thread.start()
            self._threads.append(thread)

    # -- faults and inspection -------------------------------------------------------------------
    def _set(self, **flags: object) -> None:
        with self._lock:
            for name, value in flags.items():
                setattr(self.controller, name, value)
            self.controller.halt_if_faulted()

    def set_alarm(self, code: int = 4107, resettable: bool = True) -> None:
        """Raise an alarm (``code`` > 0, stops motion; START_TRAJ_MODE resets it if ``resettable``) or clear it (0)."""
        self._set(alarm_code=code, alarm_resettable=resettable)

    def set_estop(self, pressed: bool) -> None:
        """Press or release the e-stop; pressing it stops all motion and turns the servos off."""
        with self._lock:
            self._set(e_stopped=pressed, servo_on=self.controller.servo_on and not pressed)

    def set_servo(self, on: bool) -> None:
        """Switch the servo power (off stops motion)."""
        self._set(servo_on=on)

    def set_mode(self, play: bool) -> None:
        """Pendant mode PLAY (True) or TEACH (False, stops motion)."""
        self._set(play=play)

    def set_remote(self, remote: bool) -> None:
        """The pendant's REMOTE key (off stops motion)."""
        self._set(remote=remote)

    def set_hold(self, hold: bool) -> None:
        """The HOLD button (on stops motion)."""
        self._set(hold=hold)

    def set_nonfinite_feedback(self, on: bool, value: float = float("nan")) -> None:
        """Publish ``value`` (NaN or inf) as every joint position (True) or the simulated ones (False)."""
        self.nonfinite_feedback = on
        self._nonfinite_value = value

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
    def _accept(self, listener: socket.socket, on_client: Callable[[socket.socket], None]) -> None:
        try:
            listener.settimeout(_POLL_S)
        except OSError:  # closed before this thread ran
            return
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
            old = self._motion_client
            busy = old is not None and any(g.moving for g in self.groups)
            if not busy:
                self._motion_client = sock
        if busy:  # "Motion server already connected... not accepting last attempt."
            log.info("fake motoros: refusing a second motion connection while moving")
            sock.close()
            return
        if old is not None:  # "Motion server already connected... closing old connection."
            log.info("fake motoros: a new motion connection replaces the idle one")
            _hang_up(old)
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
        try:
            sock.settimeout(_POLL_S)  # EBADF when a newer connection replaced this one before its thread ran
            while not self._stop.is_set():
                try:
                    packets = recv_into_framer(sock, framer)
                except TimeoutError:
                    continue
                for packet in packets:
                    reply, hang_up = self._answer(packet)
                    if reply is not None and not self._stall and not self._send(sock, reply.encode()):
                        return
                    if hang_up:
                        return
        except OSError as e:  # the socket closed under this thread (replaced, dropped): the client is gone
            log.info("fake motoros: motion connection closed: %s", e)
        except DriverError as e:
            log.info("fake motoros: motion client gone: %s", e)
        finally:
            with self._lock:
                if self._motion_client is sock:
                    self._motion_client = None
            sock.close()

    def _answer(self, packet: Packet) -> tuple[MotionReply | None, bool]:
        """The reply to one packet (None: none is sent) and whether the connection closes after it."""
        if packet.msg_type not in _SIZED:  # "Unknown Message Received": INVALID_MSGTYPE, the connection stays
            if packet.comm_type == CommType.SERVICE_REPLY:  # "don't send a reply to a reply from the pc"
                return None, False
            return MotionReply(0, -1, packet.msg_type, Result.INVALID, InvalidSubcode.MSGTYPE), False
        if packet.msg_type in _NOT_SERVED:  # SimpleMsgProcess's default returns ERROR: disconnect, no reply
            log.info("fake motoros: message type %d is not served on the motion port; closing", packet.msg_type)
            return None, True
        try:
            msg = decode(packet)
        except ProtocolError:  # a served type of the wrong size: INVALID_MSGSIZE, the connection stays
            return MotionReply(-1, -1, packet.msg_type, Result.INVALID, InvalidSubcode.MSGSIZE), False
        with self._lock:
            self.received.append(msg)
            self.points_received += isinstance(msg, (JointTrajPtFull, JointTrajPtFullEx))
        reply, hang_up = self.controller.answer(msg)
        return (None if hang_up else reply), hang_up  # a successful DISCONNECT: closed without a reply

    # -- simulation and publication --------------------------------------------------------------
    def _feedback(self) -> list[JointFeedback]:
        fields = ValidFields.POSITION | ValidFields.VELOCITY
        nan = np.full(self.groups[0].n_joints, self._nonfinite_value) if self.nonfinite_feedback else None
        return [JointFeedback(i, g.q if nan is None else nan, g.qd, valid_fields=fields)
                for i, g in enumerate(self.groups)]

    def _simulate(self) -> None:
        while not self._stop.wait(self.period_s):
            now = time.monotonic()
            with self._lock:
                for group in self.groups:
                    group.step(now)
                feedback = self._feedback()
                status = self.controller.status()
                clients = list(self._state_clients)
            data = b"".join(fb.encode() for fb in feedback)
            if len(feedback) >= 2:
                data += JointFeedbackEx(tuple(feedback)).encode()
            data += status.encode()
            for sock in clients:
                if not self._send(sock, data):
                    with self._lock:
                        if sock in self._state_clients:
                            self._state_clients.remove(sock)
                    sock.close()
