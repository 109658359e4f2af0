"""A bounded, thread-safe inbox filled by zenoh callbacks and drained by ``read``."""

from __future__ import annotations

import collections
import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Generic, TypeVar

from drivers.errors import DriverError, ProtocolError

log = logging.getLogger("cellcal.drivers")
T = TypeVar("T")


@dataclass(frozen=True)
class InboxStats:
    """Counters of one subscriber.

    Attributes:
        received: samples decoded and buffered.
        rejected: payloads that failed to decode (wrong size, magic or version).
        dropped: buffered samples discarded because ``read`` was not called often enough.
        last_error: message of the last rejected payload, ``""`` if none.
    """

    received: int = 0
    rejected: int = 0
    dropped: int = 0
    last_error: str = ""


class Inbox(Generic[T]):
    """Decodes payloads with ``decode`` and buffers up to ``capacity`` items, oldest dropped first.

    Args:
        name: used in log messages (the key expression).
        decode: payload bytes -> item; raises ProtocolError on a bad payload.
        capacity: maximum buffered items.
    """

    def __init__(self, name: str, decode: Callable[[bytes], T], capacity: int) -> None:
        if capacity < 1:
            raise DriverError("zenoh", f"{name}: buffer capacity must be >= 1, got {capacity}")
        self.name = name
        self._decode = decode
        self._items: collections.deque[T] = collections.deque(maxlen=capacity)
        self._cond = threading.Condition()
        self._stats = InboxStats()
        self._latest: T | None = None

    @property
    def stats(self) -> InboxStats:
        """A snapshot of the counters."""
        with self._cond:
            return self._stats

    @property
    def latest(self) -> T | None:
        """The most recent item, kept even after ``drain``; None before the first one."""
        with self._cond:
            return self._latest

    def push(self, payload: bytes) -> None:
        """Decode and buffer one payload; a bad one is counted, never raised (runs in zenoh's thread)."""
        try:
            item = self._decode(payload)
        except ProtocolError as e:
            with self._cond:
                s = self._stats
                if s.rejected == 0:
                    log.warning("%s: dropping bad payload: %s", self.name, e.reason)
                self._stats = InboxStats(s.received, s.rejected + 1, s.dropped, e.reason)
            return
        with self._cond:
            s = self._stats
            full = len(self._items) == self._items.maxlen
            self._items.append(item)
            self._latest = item
            self._stats = InboxStats(s.received + 1, s.rejected, s.dropped + int(full), s.last_error)
            self._cond.notify_all()

    def drain(self, timeout_s: float) -> list[T]:
        """Items buffered since the last call, oldest first, waiting up to ``timeout_s`` [s] for one."""
        with self._cond:
            self._cond.wait_for(lambda: len(self._items) > 0, timeout=timeout_s)
            items = list(self._items)
            self._items.clear()
        return items
