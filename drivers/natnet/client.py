"""NatNet client: a MocapSource fed by Motive's UDP stream.

Motive answers commands on its command port (1510) and streams frames of data either to a multicast
group on the data port (1511, group 239.255.42.99 by default) or, in unicast mode, to the socket the
client sent ``NAT_CONNECT`` from. The client therefore listens on both its command socket and its data
socket. ``NAT_CONNECT`` (laid out as the SDK's ``NatNetClient.py`` sends it) is answered with
``NAT_SERVERINFO``, which gives the stream version; a configured version skips the wait (for servers that
do not answer, or recorded streams). ``NAT_REQUEST_MODELDEF`` is answered with ``NAT_MODELDEF``, which maps
rigid-body names to the ids frames carry (:meth:`NatNetSource.rigid_body_ids`).

One receive thread parses every datagram; a malformed one is counted in :attr:`NatNetSource.stats`
and dropped, never raised into the thread. :meth:`NatNetSource.read` hands out the buffered rigid-body
frames.

Motive restarting: a restarted Motive does not know its unicast clients, and may stream another version.
When nothing arrives for ``reconnect_s`` the receive thread re-sends ``NAT_CONNECT`` (every ``reconnect_s``
until the server answers); the new ``NAT_SERVERINFO`` re-learns the version and the stream resumes with no
call from the caller (counted in :attr:`NatNetStats.handshakes`). ``close()`` then ``connect()`` also works
any number of times on the same object.
"""

from __future__ import annotations

import collections
import dataclasses
import logging
import threading
import time
from collections.abc import Iterable
from dataclasses import dataclass

from drivers.base import MocapSource, RigidBodyFrame
from drivers.errors import DriverDisconnected, DriverError, DriverTimeout, ProtocolError
from drivers.natnet.link import NatNetLink
from drivers.natnet.messages import (
    MessageId,
    ServerInfo,
    build_connect,
    build_request,
    check_version,
    parse_server_info,
    split_packet,
)
from drivers.natnet.modeldef import ModelDefinitions, parse_model_definitions
from drivers.natnet.packets import parse_frame

log = logging.getLogger("cellcal.drivers")
_MODELDEF_RETRY_S = 0.5


@dataclass(frozen=True)
class NatNetStats:
    """Counters of the receive thread.

    Attributes:
        packets_received: datagrams received on either socket.
        frames_parsed: ``NAT_FRAMEOFDATA`` packets parsed successfully.
        packets_rejected: malformed datagrams dropped (truncated, inconsistent counts).
        frames_dropped: rigid-body frames discarded because the buffer was full (read() too slow).
        last_error: message of the last rejected datagram, ``""`` if none.
        handshakes: ``NAT_SERVERINFO`` replies received (1 after connect, +1 per server restart seen).
        packets_foreign: datagrams from another address than the server's, dropped unread.
        bodies_dropped: rigid bodies dropped from parsed frames for a non-finite pose or a non-unit quaternion.
    """

    packets_received: int = 0
    frames_parsed: int = 0
    packets_rejected: int = 0
    frames_dropped: int = 0
    last_error: str = ""
    handshakes: int = 0
    packets_foreign: int = 0
    bodies_dropped: int = 0


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
        reconnect_s: silence after which ``NAT_CONNECT`` is re-sent, and its retry period [s].
    """

    def __init__(self, server_address: str = "127.0.0.1", *, local_address: str = "0.0.0.0",
                 command_port: int = 1510, data_port: int = 1511, multicast_group: str | None = "239.255.42.99",
                 version: tuple[int, int] | None = None, connect_timeout_s: float = 2.0,
                 max_buffered_frames: int = 10_000, keepalive_s: float = 1.0, reconnect_s: float = 1.0) -> None:
        self.device = f"natnet@{server_address}:{command_port}"
        if max_buffered_frames < 1:
            raise DriverError(self.device, f"max_buffered_frames must be >= 1, got {max_buffered_frames}")
        self.server_address = server_address
        self.local_address = local_address
        self.command_port = command_port
        self.multicast_group = multicast_group
        self.connect_timeout_s = connect_timeout_s
        self._configured_version = None if version is None else check_version(version)
        self._link = NatNetLink(self.device, (server_address, command_port), local_address=local_address,
                                data_port=data_port, multicast_group=multicast_group,
                                connect_packet=build_connect(self._configured_version or (4, 1)),
                                keepalive_s=keepalive_s, reconnect_s=reconnect_s)
        self._version = self._configured_version
        self._model_definitions: ModelDefinitions | None = None
        self._model_definitions_seq = 0
        self._server_info: ServerInfo | None = None
        self._buffer_size = max_buffered_frames
        self._buffer: collections.deque[RigidBodyFrame] = collections.deque(maxlen=max_buffered_frames)
        self._cond = threading.Condition()
        self._stats = NatNetStats()
        self._failure: DriverError | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

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
        port = self._link.data_port
        if port is None:
            raise DriverError(self.device, "not connected")
        return port

    @property
    def stats(self) -> NatNetStats:
        """A snapshot of the receive counters."""
        with self._cond:
            return dataclasses.replace(self._stats, packets_foreign=self._link.foreign_dropped)

    def connect(self) -> None:
        """Open both sockets, handshake with the server and start the receive thread.

        Raises:
            DriverTimeout: no ``NAT_SERVERINFO`` within connect_timeout_s and no version configured.
            DriverError: a socket could not be opened, bound or joined to the group.
        """
        if self._thread is not None:
            return
        self._version, self._server_info, self._failure = self._configured_version, None, None
        self._buffer.clear()
        try:
            self._link.open()
            self._link.send(self._link.connect_packet)
            if self._version is None:
                self._await_server_info()
        except DriverError:  # before OSError: DriverTimeout is a TimeoutError, hence an OSError
            self._link.close()
            raise
        except OSError as e:
            self._link.close()
            raise DriverError(self.device, f"cannot open the NatNet sockets ({e})") from e
        self._stop.clear()
        self._thread = threading.Thread(target=self._receive_loop, name="natnet-receive", daemon=True)
        self._thread.start()
        log.info("%s: connected, NatNet %d.%d, data port %d", self.device, *self._stream_version(), self.data_port)

    def _await_server_info(self) -> None:
        deadline = time.monotonic() + self.connect_timeout_s
        while (remaining := deadline - time.monotonic()) > 0:
            packet = self._link.recv_command(remaining)
            if packet is None:
                continue
            try:
                message_id, payload = split_packet(packet)
                if message_id == MessageId.SERVER_INFO:
                    self._accept_server_info(parse_server_info(payload))
                    return
            except ProtocolError as e:
                self._count_rejected(e)
        raise DriverTimeout(self.device, "NAT_SERVERINFO (is Motive streaming? or configure version=)",
                            self.connect_timeout_s)

    def _stream_version(self) -> tuple[int, int]:
        """The version in use once connect() has it (configured, or from ``NAT_SERVERINFO``)."""
        if self._version is None:
            raise DriverError(self.device, "NatNet version unknown: connect() first")
        return self._version

    def _accept_server_info(self, info: ServerInfo) -> None:
        version = check_version(info.natnet_version[:2])
        with self._cond:
            self._server_info = info
            if self._configured_version is None:
                self._version = version
            self._stats = dataclasses.replace(self._stats, handshakes=self._stats.handshakes + 1)

    def _receive_loop(self) -> None:
        try:
            self._link.run(self._handle, self._stop)
        except (OSError, ValueError) as e:
            if not self._stop.is_set():
                log.error("%s: receive thread stopped: %s", self.device, e)
                with self._cond:
                    self._failure = DriverDisconnected(self.device, f"socket error ({e})")
                    self._cond.notify_all()

    def _handle(self, packet: bytes) -> None:
        try:
            message_id, payload = split_packet(packet)
            if message_id == MessageId.SERVER_INFO:
                self._accept_server_info(parse_server_info(payload))
            elif message_id == MessageId.MODEL_DEF:
                definitions = parse_model_definitions(payload, self._stream_version())
                with self._cond:
                    self._model_definitions = definitions
                    self._model_definitions_seq += 1
                    self._cond.notify_all()
            frame = parse_frame(payload, self._stream_version()) if message_id == MessageId.FRAME_OF_DATA else None
        except ProtocolError as e:
            self._count_rejected(e, received=True)
            return
        with self._cond:
            s = self._stats
            if frame is None:
                self._stats = dataclasses.replace(s, packets_received=s.packets_received + 1)
                return
            overflow = max(0, len(self._buffer) + len(frame.rigid_bodies) - self._buffer_size)
            self._buffer.extend(frame.rigid_bodies)
            self._stats = dataclasses.replace(s, packets_received=s.packets_received + 1,
                                              frames_parsed=s.frames_parsed + 1,
                                              frames_dropped=s.frames_dropped + overflow,
                                              bodies_dropped=s.bodies_dropped + frame.bodies_dropped)
            if frame.bodies_dropped and not s.bodies_dropped:
                log.warning("%s: dropping rigid bodies with a non-finite pose or a non-unit quaternion",
                            self.device)
            self._cond.notify_all()

    def _count_rejected(self, error: ProtocolError, received: bool = False) -> None:
        with self._cond:
            s = self._stats
            if s.packets_rejected == 0:
                log.warning("%s: dropping malformed packet: %s", self.device, error.reason)
            self._stats = dataclasses.replace(s, packets_received=s.packets_received + int(received),
                                              packets_rejected=s.packets_rejected + 1, last_error=error.reason)

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

    def request_model_definitions(self, timeout_s: float = 2.0) -> ModelDefinitions:
        """Ask the server for its model definitions (``NAT_REQUEST_MODELDEF``) and wait for ``NAT_MODELDEF``.

        The request is re-sent every 0.5 s (UDP may lose either datagram) until the reply or ``timeout_s`` [s].

        Raises:
            DriverError: not connected, or the stream version is still unknown.
            DriverTimeout: no ``NAT_MODELDEF`` within ``timeout_s``.
            DriverDisconnected: the receive thread lost its socket.
        """
        if self._thread is None or self._version is None:
            raise DriverError(self.device, "not connected; call connect() first")
        deadline = time.monotonic() + timeout_s
        with self._cond:
            seq = self._model_definitions_seq
        while (remaining := deadline - time.monotonic()) > 0:
            try:
                self._link.send(build_request(MessageId.REQUEST_MODEL_DEF))
            except OSError as e:
                raise DriverError(self.device, f"cannot send NAT_REQUEST_MODELDEF ({e})") from e
            with self._cond:
                self._cond.wait_for(lambda: self._model_definitions_seq != seq or self._failure is not None,
                                    timeout=min(_MODELDEF_RETRY_S, remaining))
                if self._failure is not None:
                    raise self._failure
                if self._model_definitions_seq != seq and self._model_definitions is not None:
                    return self._model_definitions
        raise DriverTimeout(self.device, "NAT_MODELDEF (reply to NAT_REQUEST_MODELDEF)", timeout_s)

    def rigid_body_ids(self, timeout_s: float = 2.0, names: Iterable[str] | None = None) -> dict[str, int]:
        """Rigid-body name -> id from the server's model definitions.

        Args:
            timeout_s: how long to wait for ``NAT_MODELDEF`` [s].
            names: the names needed; None returns every rigid body the server defines.

        Raises:
            DriverError: a name in ``names`` is not defined by the server (the message lists the defined ones).
            DriverTimeout: no ``NAT_MODELDEF`` within ``timeout_s``.
        """
        definitions = self.request_model_definitions(timeout_s)
        ids = definitions.rigid_body_ids()
        if names is None:
            return ids
        names = list(names)
        missing = definitions.missing_rigid_bodies(names)
        if missing:
            defined = ", ".join(sorted(ids)) or "none"
            raise DriverError(self.device, f"rigid bod{'y' if len(missing) == 1 else 'ies'} "
                                           f"{', '.join(map(repr, missing))} not defined in the server's model "
                                           f"definitions; defined: {defined}")
        return {name: ids[name] for name in names}

    def close(self) -> None:
        """Stop the receive thread and release both sockets; safe to call twice."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=1.0)
            self._thread = None
        self._link.close()
