"""The two UDP sockets of a NatNet client and the loop that reads them.

Like the SDK's ``NatNetClient.py``, the client has a command socket (bound to an ephemeral port of the
local interface; requests go from it to the server's command port and replies, and unicast frames, come
back to it) and a data socket (the data port, joined to the multicast group in multicast mode). The loop
also sends ``NAT_KEEPALIVE`` in unicast mode and re-sends ``NAT_CONNECT`` when nothing has arrived for
``reconnect_s`` (Motive restarted, or the network dropped): the restarted server answers with
``NAT_SERVERINFO`` and, in unicast mode, streams to the client again.

Only the configured server is heard: a datagram from any other address (a forged frame from another host of the
network, which made a collection skip targets with injected NaN frames) is dropped and counted
(:attr:`NatNetLink.foreign_dropped`), never parsed. NatNet has no authentication: the mocap network must still be
trusted (a host that can forge the server's address can inject frames).
"""

from __future__ import annotations

import logging
import selectors
import socket
import threading
import time
from collections.abc import Callable
from typing import cast

from drivers.natnet.messages import MessageId, build_request

log = logging.getLogger("cellcal.drivers")
RECV_SIZE = 65536
POLL_S = 0.05


class NatNetLink:
    """Command and data sockets of one connection; open() binds them, close() releases them.

    Args:
        device: name used in log messages.
        server: (address, command port) of the server.
        local_address: local interface to bind and to join the multicast group on.
        data_port: local data port (0 picks a free one).
        multicast_group: group to join, None for unicast.
        connect_packet: the ``NAT_CONNECT`` datagram re-sent after silence.
        keepalive_s: ``NAT_KEEPALIVE`` period in unicast mode [s].
        reconnect_s: silence before ``NAT_CONNECT`` is re-sent, and its retry period [s].
    """

    def __init__(self, device: str, server: tuple[str, int], *, local_address: str, data_port: int,
                 multicast_group: str | None, connect_packet: bytes, keepalive_s: float, reconnect_s: float) -> None:
        self.device, self.server = device, server
        self.local_address, self.requested_data_port = local_address, data_port
        self.multicast_group = multicast_group
        self.connect_packet = connect_packet
        self.keepalive_s, self.reconnect_s = keepalive_s, reconnect_s
        self.cmd: socket.socket | None = None
        self.data: socket.socket | None = None
        self.foreign_dropped = 0  # datagrams from another address than the server's, dropped
        self._server_ip: str | None = None

    def open(self) -> None:
        """Resolve the server's address, bind both sockets (and join the group); raises OSError."""
        self._server_ip = socket.gethostbyname(self.server[0])
        self.cmd = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.cmd.bind((self.local_address, 0))
        self.data = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.data.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        if self.multicast_group is None:
            self.data.bind((self.local_address, self.requested_data_port))
            return
        self.data.bind(("", self.requested_data_port))
        membership = socket.inet_aton(self.multicast_group) + socket.inet_aton(self.local_address)
        self.data.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, membership)

    @property
    def data_port(self) -> int | None:
        """The local data port bound, None when closed."""
        return None if self.data is None else self.data.getsockname()[1]

    def _sockets(self) -> tuple[socket.socket, socket.socket]:
        """The (command, data) sockets; raises OSError when the link is not open."""
        if self.cmd is None or self.data is None:
            raise OSError(f"{self.device}: NatNet link is not open")
        return self.cmd, self.data

    def send(self, packet: bytes) -> None:
        """Send to the server's command port; raises OSError."""
        self._sockets()[0].sendto(packet, self.server)

    def recv_command(self, timeout_s: float) -> bytes | None:
        """One datagram of the server from the command socket, None after ``timeout_s`` [s] (blocking mode only)."""
        cmd = self._sockets()[0]
        cmd.settimeout(max(timeout_s, 1e-3))
        try:
            packet, source = cmd.recvfrom(RECV_SIZE)
        except (TimeoutError, ConnectionRefusedError):
            return None
        return packet if self._from_server(source) else None

    def _from_server(self, source: tuple[str, int]) -> bool:
        """True for a datagram from the server's address; another sender's is counted and dropped."""
        if source[0] == self._server_ip:
            return True
        if self.foreign_dropped == 0:
            log.warning("%s: dropping datagrams from %s:%d, not the NatNet server %s", self.device, source[0],
                        source[1], self._server_ip)
        self.foreign_dropped += 1
        return False

    def _send_quietly(self, packet: bytes) -> None:
        try:
            self.send(packet)
        except OSError as e:  # unreachable or refused: the server is down, the loop keeps trying
            log.debug("%s: send failed: %s", self.device, e)

    def run(self, handle: Callable[[bytes], None], stop: threading.Event) -> None:
        """Read both sockets until ``stop`` is set, passing each datagram to ``handle``.

        Raises:
            OSError, ValueError: a socket failed (or was closed under the loop).
        """
        sel = selectors.DefaultSelector()
        for sock in self._sockets():
            sock.setblocking(False)
            sel.register(sock, selectors.EVENT_READ)
        now = time.monotonic()
        next_keepalive, last_packet, next_connect = now + self.keepalive_s, now, now + self.reconnect_s
        try:
            while not stop.is_set():
                for key, _ in sel.select(POLL_S):
                    try:
                        packet, source = cast(socket.socket, key.fileobj).recvfrom(RECV_SIZE)
                    except ConnectionRefusedError:  # ICMP port unreachable: the server is down
                        continue
                    if not self._from_server(source):
                        continue
                    last_packet = time.monotonic()
                    handle(packet)
                now = time.monotonic()
                if now - last_packet >= self.reconnect_s and now >= next_connect:
                    log.info("%s: nothing received for %.1f s; re-sending NAT_CONNECT", self.device,
                             now - last_packet)
                    self._send_quietly(self.connect_packet)
                    next_connect = now + self.reconnect_s
                if self.multicast_group is None and now >= next_keepalive:
                    self._send_quietly(build_request(MessageId.KEEP_ALIVE))
                    next_keepalive = now + self.keepalive_s
        finally:
            sel.close()

    def close(self) -> None:
        """Close both sockets; safe to call twice."""
        for sock in (self.cmd, self.data):
            if sock is not None:
                sock.close()
        self.cmd = self.data = None
