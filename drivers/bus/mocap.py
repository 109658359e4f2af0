"""Mocap frames over Zenoh: a bridge that publishes a MocapSource, and a MocapSource that subscribes.

The bridge runs next to the motion-capture PC (NatNet in, Zenoh out); collectors anywhere on the
network read the same frames through :class:`ZenohMocapSource` without knowing about NatNet.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

from cell_config.devices import ZenohConfig
from drivers.base import MocapSource, RigidBodyFrame
from drivers.bus.inbox import Inbox, InboxStats
from drivers.bus.payloads import decode_mocap, encode_mocap
from drivers.bus.session import mocap_key, open_session
from drivers.errors import DriverError

if TYPE_CHECKING:
    import zenoh

log = logging.getLogger("cellcal.drivers")


@dataclass(frozen=True)
class MocapSample:
    """A received frame with its transport times.

    Attributes:
        frame: the rigid-body frame as the source produced it.
        publish_time: publisher's ``time.time()`` when it sent the frame [s].
        receive_time: subscriber's ``time.time()`` when the frame was decoded [s].
    """

    frame: RigidBodyFrame
    publish_time: float
    receive_time: float

    @property
    def latency_s(self) -> float:
        """Publish-to-receive delay [s]; meaningful across machines only with synchronised clocks."""
        return self.receive_time - self.publish_time


class MocapBridge:
    """Publishes every frame of a MocapSource on ``cellcal/<cell>/mocap/<name>``.

    The bridge does not own the source or the session: connect and close them yourself. Use
    :meth:`start` (or the context manager) for a background thread, or call :meth:`publish` directly.

    Args:
        source: a connected MocapSource.
        session: an open zenoh session (see :func:`~drivers.bus.session.open_session`).
        cell: cell name, first key chunk.
        names: rigid-body id -> key name (``weldgun``); ids not listed publish as their number.
        poll_s: how long each source.read call waits [s].
        express: send each sample at once instead of batching (lower latency, more packets).

    Publications use blocking congestion control: under a burst (NatNet can deliver several frames at
    once) zenoh's default policy drops samples once its transmit queue is full, which loses frames of a
    recording; blocking instead lets the source's own buffer absorb the burst, where drops are counted.
    """

    def __init__(self, source: MocapSource, session: zenoh.Session, cell: str,
                 names: Mapping[int, str] | None = None, poll_s: float = 0.05, express: bool = True) -> None:
        mocap_key(cell, "*")  # validates the cell name now rather than at the first frame
        self.source = source
        self.cell = cell
        self.poll_s = poll_s
        self._session = session
        self._names = dict(names or {})
        self._express = express
        self._publishers: dict[int, zenoh.Publisher] = {}
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.published = 0
        self.error: DriverError | None = None

    def key(self, body_id: int) -> str:
        """Key expression of a rigid body's frames."""
        return mocap_key(self.cell, self._names.get(body_id, str(body_id)))

    def publish(self, frame: RigidBodyFrame) -> None:
        """Publish one frame now, stamped with the current ``time.time()``.

        Raises:
            DriverError: zenoh refused the publication (session closed).
        """
        import zenoh

        with self._lock:
            try:
                pub = self._publishers.get(frame.body_id)
                if pub is None:
                    pub = self._session.declare_publisher(self.key(frame.body_id), express=self._express,
                                                         congestion_control=zenoh.CongestionControl.BLOCK)
                    self._publishers[frame.body_id] = pub
                pub.put(encode_mocap(frame, time.time()))
            except zenoh.ZError as e:
                raise DriverError("zenoh", f"cannot publish on {self.key(frame.body_id)} ({e})") from e
            self.published += 1

    def start(self) -> None:
        """Start the background thread that reads the source and publishes; no-op if running."""
        if self._thread is not None:
            return
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="mocap-bridge", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                for frame in self.source.read(self.poll_s):
                    self.publish(frame)
            except DriverError as e:
                log.error("mocap bridge stopped: %s", e)
                self.error = e
                return

    def close(self) -> None:
        """Stop the thread and undeclare the publishers; safe to call twice."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=max(1.0, 4 * self.poll_s))
            self._thread = None
        with self._lock:
            for pub in self._publishers.values():
                pub.undeclare()  # type: ignore[no-untyped-call]  # zenoh's stub leaves undeclare() unannotated
            self._publishers.clear()

    def __enter__(self) -> MocapBridge:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class ZenohMocapSource(MocapSource):
    """A MocapSource fed by the frames a MocapBridge publishes.

    Args:
        cell: cell name, first key chunk.
        config: session settings when this source opens (and later closes) its own session.
        session: an open session to share instead; it is left open by close().
        rigid_bodies: key names to subscribe to; None subscribes to every rigid body of the cell.
        max_buffered_frames: frames kept between read() calls; older ones are dropped and counted.
    """

    def __init__(self, cell: str, *, config: ZenohConfig | None = None, session: zenoh.Session | None = None,
                 rigid_bodies: Sequence[str] | None = None, max_buffered_frames: int = 10_000) -> None:
        if config is not None and session is not None:
            raise DriverError("zenoh", "give either config or session, not both")
        self.keys = [mocap_key(cell, name) for name in (rigid_bodies or ["*"])]
        self._config = config
        self._session = session
        self._owns_session = session is None
        self._inbox: Inbox[MocapSample] = Inbox(
            ",".join(self.keys), lambda b: MocapSample(*decode_mocap(b), time.time()), max_buffered_frames)
        self._subscribers: list[zenoh.Subscriber[None]] = []

    @property
    def stats(self) -> InboxStats:
        """Counters: frames received, bad payloads rejected, frames dropped from a full buffer."""
        return self._inbox.stats

    def connect(self) -> None:
        """Open the session (unless shared) and subscribe; no-op if already connected."""
        import zenoh

        if self._subscribers:
            return
        if self._session is None:
            self._session = open_session(self._config)
        try:
            for key in self.keys:
                self._subscribers.append(
                    self._session.declare_subscriber(key, lambda s: self._inbox.push(s.payload.to_bytes())))
        except zenoh.ZError as e:
            self.close()
            raise DriverError("zenoh", f"cannot subscribe to {self.keys} ({e})") from e

    def read(self, timeout_s: float) -> list[RigidBodyFrame]:
        """Frames received since the last call, oldest first; empty after ``timeout_s`` [s] without any."""
        return [s.frame for s in self.read_samples(timeout_s)]

    def read_samples(self, timeout_s: float) -> list[MocapSample]:
        """Like :meth:`read` with publish and receive times (latency monitoring)."""
        if not self._subscribers:
            raise DriverError("zenoh", "not connected; call connect() first")
        return self._inbox.drain(timeout_s)

    def close(self) -> None:
        """Undeclare the subscribers and close an owned session; safe to call twice."""
        for sub in self._subscribers:
            sub.undeclare()  # type: ignore[no-untyped-call]  # zenoh's stub leaves undeclare() unannotated
        self._subscribers.clear()
        if self._owns_session and self._session is not None:
            self._session.close()  # type: ignore[no-untyped-call]  # zenoh's stub leaves close() unannotated
            self._session = None
