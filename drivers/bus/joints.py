"""Robot joint states over Zenoh on ``cellcal/<cell>/robot/<name>/joints``.

The robot driver's process publishes each reading; collectors subscribe and either take the
latest state or drain every state received since their last call.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

from drivers.base import JointState
from drivers.bus.inbox import Inbox, InboxStats
from drivers.bus.payloads import decode_joints, encode_joints
from drivers.bus.session import joints_key
from drivers.errors import DriverError

if TYPE_CHECKING:
    import zenoh


class JointStatePublisher:
    """Publishes one robot's joint states (blocking congestion control, like MocapBridge). Does not own the session.

    Args:
        session: an open zenoh session.
        cell: cell name.
        robot: robot name in the cell (``R1``).
    """

    def __init__(self, session: zenoh.Session, cell: str, robot: str) -> None:
        import zenoh

        self.key = joints_key(cell, robot)
        try:
            self._publisher = session.declare_publisher(self.key, express=True,
                                                       congestion_control=zenoh.CongestionControl.BLOCK)
        except zenoh.ZError as e:
            raise DriverError("zenoh", f"cannot declare a publisher on {self.key} ({e})") from e
        self._closed = False

    def publish(self, state: JointState) -> None:
        """Publish one state (6 angles [rad] and its stamp [s]).

        Raises:
            ProtocolError: the state does not have 6 angles.
            DriverError: the publisher is closed or zenoh refused the publication.
        """
        import zenoh

        if self._closed:
            raise DriverError("zenoh", f"publisher on {self.key} is closed")
        try:
            self._publisher.put(encode_joints(state, time.time()))
        except zenoh.ZError as e:
            raise DriverError("zenoh", f"cannot publish on {self.key} ({e})") from e

    def close(self) -> None:
        """Undeclare the publisher; safe to call twice."""
        if not self._closed:
            self._publisher.undeclare()  # type: ignore[no-untyped-call]  # zenoh's stub leaves undeclare() unannotated
            self._closed = True

    def __enter__(self) -> JointStatePublisher:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class JointStateSubscriber:
    """Receives one robot's joint states. Does not own the session.

    Args:
        session: an open zenoh session.
        cell: cell name.
        robot: robot name in the cell (``R1``).
        max_buffered: states kept between read() calls; older ones are dropped and counted.
    """

    def __init__(self, session: zenoh.Session, cell: str, robot: str, max_buffered: int = 10_000) -> None:
        import zenoh

        self.key = joints_key(cell, robot)
        self._inbox: Inbox[JointState] = Inbox(self.key, lambda b: decode_joints(b)[0], max_buffered)
        try:
            self._subscriber = session.declare_subscriber(self.key, lambda s: self._inbox.push(s.payload.to_bytes()))
        except zenoh.ZError as e:
            raise DriverError("zenoh", f"cannot subscribe to {self.key} ({e})") from e
        self._closed = False

    @property
    def stats(self) -> InboxStats:
        """Counters: states received, bad payloads rejected, states dropped from a full buffer."""
        return self._inbox.stats

    def latest(self) -> JointState | None:
        """The most recent state, None before the first one."""
        return self._inbox.latest

    def read(self, timeout_s: float) -> list[JointState]:
        """States received since the last call, oldest first; empty after ``timeout_s`` [s] without any."""
        return self._inbox.drain(timeout_s)

    def close(self) -> None:
        """Undeclare the subscriber; safe to call twice."""
        if not self._closed:
            self._subscriber.undeclare()  # type: ignore[no-untyped-call]  # zenoh's stub leaves undeclare() unannotated
            self._closed = True

    def __enter__(self) -> JointStateSubscriber:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
