"""NatNet client: a MocapSource fed by Motive's UDP stream.

Motive answers commands on its command port (1510) and streams frames of data either to a multicast
group on the data port (1511, group 239.255.42.99 by default) or, in unicast mode, to the socket the
client sent ``NAT_CONNECT`` from. The client therefore listens on both its command socket and its data
socket. ``NAT_CONNECT`` is answered with ``NAT_SERVERINFO``, which gives the stream version; a configured
version skips the wait (for servers that do not answer, or recorded streams).

One receive thread parses every datagram; a malformed one is counted in :attr:`NatNetSource.stats`
and dropped, never raised into the thread. :meth:`NatNetSource.read` hands out the buffered rigid-body
frames.
"""

from __future__ import annotations

import collections
import logging
import selectors
import socket
import threading
import time
from dataclasses import dataclass

from drivers.base import MocapSource, RigidBodyFrame
from drivers.errors import DriverDisconnected, DriverError, DriverTimeout, ProtocolError
from drivers.natnet.packets import (MessageId, ServerInfo, build_connect, build_request, check_version,
                                    parse_frame, parse_server_info, split_packet)

log = logging.getLogger("cellcal.drivers")
_RECV_SIZE = 65536
_POLL_S = 0.05


@dataclass(frozen=True)
class NatNetStats:
    """Counters of the receive thread.

    Attributes:
        packets_received: datagrams received on either socket.
        frames_parsed: ``NAT_FRAMEOFDATA`` packets parsed successfully.
        packets_rejected: malformed datagrams dropped (truncated, inconsistent counts).
        frames_dropped: rigid-body frames discarded because the buffer was full (read() too slow).
        last_error: message of the last rejected datagram, ``""`` if none.
    """

    packets_received: int = 0
    frames_parsed: int = 0
    packets_rejected: int = 0
    frames_dropped: int = 0
    last_error: str = ""


class NatNetSource(MocapSource):
    """Rigid-body frames from a NatNet server (Motive).

    Args:
        server_address: IP of the NatNet server.
        local_address: IP of the local interface to bind and to join the multicast group on.
        command_port: server command port (1510 in Motive).
        data_port: local data port to bind (1511 in Motive; 0 picks a free port, useful in tests).
        multicast_group: group to join, or None for unicast streaming.
        version: NatNet stream (major, minor); None learns it from the server's ``NAT_SERVERINFO``.
        connect_timeout_s: how long connect() waits for ``NAT_SERVERINFO`` [s].
        max_buffered_frames: rigid-body frames kept between read() calls; older ones are dropped.
        keepalive_s: period of ``NAT_KEEPALIVE`` in unicast mode [s].
    """

    def __init__(self, server_address: str = "127.0.0.1", *, local_address: str = "0.0.0.0",
                 command_port: int = 1510, data_port: int = 1511, multicast_group: str | None = "239.255.42.99",
                 version: tuple[int, int] | None = None, connect_timeout_s: float = 2.0,
                 max_buffered_frames: int = 10_000, keepalive_s: float = 1.0) -> None:
        self.device = f"natnet@{server_address}:{command_port}"
        if max_buffered_frames < 1:
            raise DriverError(self.device, f"max_buffered_frames must be >= 1, got {max_buffered_frames}")
        self.server_address = server_address
        self.local_address = local_address
        self.command_port = command_port
        self.multicast_group = multicast_group
        self.connect_timeout_s = connect_timeout_s
        self.keepalive_s = keepalive_s
        self._requested_data_port = data_port
        self._version = None if version is None else check_version(version)
        self._server_info: ServerInfo | None = None
        self._buffer: collections.deque[RigidBodyFrame] = collections.deque(maxlen=max_buffered_frames)
        self._cond = threading.Condition()
        self._stats = NatNetStats()
        self._failure: DriverError | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._cmd: socket.socket | None = None
        self._data: socket.socket | None = None

    @property
    def version(self) -> tuple[int, int] | None:
        """NatNet stream (major, minor) in use; None before connect() when not configured."""
        return self._version

    @property
    def server_info(self) -> ServerInfo | None:
        """The server's ``NAT_SERVERINFO``, None if it never answered."""
        return self._server_info

    @property
    def data_port(self) -> int:
        """The local data port actually bound (differs from the argument when that was 0)."""
        if self._data is None:
            raise DriverError(self.device, "not connected")
        return self._data.getsockname()[1]

    @property
    def stats(self) -> NatNetStats:
        """A snapshot of the receive counters."""
        with self._cond:
            return self._stats

    def connect(self) -> None:
        """Open both sockets, handshake with the server and start the receive thread.

        Raises:
            DriverTimeout: no ``NAT_SERVERINFO`` within connect_timeout_s and no version configured.
            DriverError: a socket could not be opened, bound or joined to the group.
        """
        if self._thread is not None:
            return
        try:
            self._open_sockets()
            self._cmd.sendto(build_connect(self._version or (4, 1)), (self.server_address, self.command_port))
            if self._version is None:
                self._await_server_info()
        except DriverError:  # before OSError: DriverTimeout is a TimeoutError, hence an OSError
            self._close_sockets()
            raise
        except OSError as e:
            self._close_sockets()
            raise DriverError(self.device, f"cannot open the NatNet sockets ({e})") from e
        self._stop.clear()
        self._thread = threading.Thread(target=self._receive_loop, name="natnet-receive", daemon=True)
        self._thread.start()
        log.info("%s: connected, NatNet %d.%d, data port %d", self.device, *self._version, self.data_port)

    def _open_sockets(self) -> None:
        self._cmd = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._cmd.bind((self.local_address, 0))
        self._data = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._data.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        if self.multicast_group is None:
            self._data.bind((self.local_address, self._requested_data_port))
            return
        self._data.bind(("", self._requested_data_port))
        membership = socket.inet_aton(self.multicast_group) + socket.inet_aton(self.local_address)
        self._data.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, membership)

    def _await_server_info(self) -> None:
        deadline = time.monotonic() + self.connect_timeout_s
        while (remaining := deadline - time.monotonic()) > 0:
            self._cmd.settimeout(remaining)
            try:
                packet = self._cmd.recv(_RECV_SIZE)
            except socket.timeout:
                break
            try:
                message_id, payload = split_packet(packet)
                if message_id == MessageId.SERVER_INFO:
                    self._server_info = parse_server_info(payload)
                    self._version = check_version(self._server_info.natnet_version[:2])
                    return
            except ProtocolError as e:
                self._count_rejected(e)
        raise DriverTimeout(self.device, "NAT_SERVERINFO (is Motive streaming? or configure version=)",
                            self.connect_timeout_s)

    def _receive_loop(self) -> None:
        sel = selectors.DefaultSelector()
        for sock in (self._cmd, self._data):
            sock.setblocking(False)
            sel.register(sock, selectors.EVENT_READ)
        next_keepalive = time.monotonic() + self.keepalive_s
        try:
            while not self._stop.is_set():
                for key, _ in sel.select(_POLL_S):
                    self._handle(key.fileobj.recv(_RECV_SIZE))
                if self.multicast_group is None and time.monotonic() >= next_keepalive:
                    self._cmd.sendto(build_request(MessageId.KEEP_ALIVE), (self.server_address, self.command_port))
                    next_keepalive += self.keepalive_s
        except (OSError, ValueError) as e:
            if not self._stop.is_set():
                log.error("%s: receive thread stopped: %s", self.device, e)
                with self._cond:
                    self._failure = DriverDisconnected(self.device, f"socket error ({e})")
                    self._cond.notify_all()
        finally:
            sel.close()

    def _handle(self, packet: bytes) -> None:
        try:
            message_id, payload = split_packet(packet)
            frame = parse_frame(payload, self._version) if message_id == MessageId.FRAME_OF_DATA else None
        except ProtocolError as e:
            self._count_rejected(e, received=True)
            return
        with self._cond:
            s = self._stats
            if frame is None:
                self._stats = NatNetStats(s.packets_received + 1, s.frames_parsed, s.packets_rejected,
                                          s.frames_dropped, s.last_error)
                return
            overflow = max(0, len(self._buffer) + len(frame.rigid_bodies) - self._buffer.maxlen)
            self._buffer.extend(frame.rigid_bodies)
            self._stats = NatNetStats(s.packets_received + 1, s.frames_parsed + 1, s.packets_rejected,
                                      s.frames_dropped + overflow, s.last_error)
            self._cond.notify_all()

    def _count_rejected(self, error: ProtocolError, received: bool = False) -> None:
        with self._cond:
            s = self._stats
            if s.packets_rejected == 0:
                log.warning("%s: dropping malformed packet: %s", self.device, error.reason)
            self._stats = NatNetStats(s.packets_received + int(received), s.frames_parsed, s.packets_rejected + 1,
                                      s.frames_dropped, error.reason)

    def read(self, timeout_s: float) -> list[RigidBodyFrame]:
        """Rigid-body frames received since the last call, oldest first.

        Waits up to ``timeout_s`` [s] for at least one; returns an empty list when none came.

        Raises:
            DriverError: not connected.
            DriverDisconnected: the receive thread lost its socket.
        """
        if self._thread is None:
            raise DriverError(self.device, "not connected; call connect() first")
        with self._cond:
            self._cond.wait_for(lambda: self._buffer or self._failure is not None, timeout=timeout_s)
            if not self._buffer and self._failure is not None:
                raise self._failure
            frames = list(self._buffer)
            self._buffer.clear()
        return frames

    def close(self) -> None:
        """Stop the receive thread and release both sockets; safe to call twice."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=1.0)
            self._thread = None
        self._close_sockets()

    def _close_sockets(self) -> None:
        for sock in (self._cmd, self._data):
            if sock is not None:
                sock.close()
        self._cmd = self._data = None
