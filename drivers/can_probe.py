"""Contact probe on a CAN bus: touch / release events and a heartbeat, read with python-can.

Frame layout (classic CAN, 11-bit ids; ``base_id`` defaults to 0x5A0; multi-byte fields little-endian):

===========  ====  ===  ===================================================================================
frame        id    DLC  bytes
===========  ====  ===  ===================================================================================
heartbeat    base    2  [0] counter, uint8, +1 per heartbeat, wraps 255 -> 0
                        [1] status bits: bit 0 armed, bit 1 fault, bit 2 in contact; others 0
contact      base+1  6  [0] state: 1 touched, 0 released
                        [1] sequence, uint8, +1 per event, wraps; a gap means events were lost
                        [2:6] probe timestamp [ms], uint32, the probe's own clock (wraps after 49.7 days)
===========  ====  ===  ===================================================================================

The probe sends a heartbeat every 50 ms or so. Frames with other ids are someone else's and are skipped.
A frame with one of our ids but a wrong DLC, an unknown state or status bit, or that is a remote or error
frame, is malformed: it is counted in ``stats`` and ignored, never raised.
"""

from __future__ import annotations

import abc
import logging
import struct
import threading
import time
from dataclasses import dataclass
from typing import Any

from drivers.errors import DriverError, DriverTimeout

log = logging.getLogger("cellcal.drivers")

DEFAULT_BASE_ID = 0x5A0
STATUS_ARMED, STATUS_FAULT, STATUS_CONTACT = 0x01, 0x02, 0x04
_EVENT = struct.Struct("<BBI")


@dataclass(frozen=True)
class ContactEvent:
    """One touch or release.

    Attributes:
        touched: True for a touch, False for a release.
        sequence: the probe's event counter (0..255).
        probe_time_ms: the probe's time stamp [ms].
        stamp: local ``time.monotonic()`` at reception [s].
    """

    touched: bool
    sequence: int
    probe_time_ms: int
    stamp: float


@dataclass(frozen=True)
class ProbeStats:
    """Frame counters since ``connect``: heartbeats, events, malformed frames and events lost to gaps."""

    heartbeats: int = 0
    events: int = 0
    malformed: int = 0
    lost_events: int = 0


def encode_heartbeat(counter: int, status: int, base_id: int = DEFAULT_BASE_ID) -> tuple[int, bytes]:
    """Arbitration id and payload of a heartbeat frame."""
    return base_id, bytes([counter & 0xFF, status & 0xFF])


def encode_event(touched: bool, sequence: int, probe_time_ms: int,
                 base_id: int = DEFAULT_BASE_ID) -> tuple[int, bytes]:
    """Arbitration id and payload of a contact frame."""
    return base_id + 1, _EVENT.pack(int(touched), sequence & 0xFF, probe_time_ms & 0xFFFFFFFF)


def import_can() -> Any:
    try:
        import can
    except ImportError as e:
        raise DriverError("can", "python-can is not installed; install it with `pip install python-can`") from e
    return can


class ContactProbe(abc.ABC):
    """A touch probe. Use as a context manager."""

    @abc.abstractmethod
    def connect(self) -> None:
        """Open the device; raises DriverError on failure."""

    @abc.abstractmethod
    def wait_for_contact(self, timeout_s: float) -> ContactEvent:
        """Block until the next touch after this call; raises DriverTimeout (no touch, or probe silent)."""

    @abc.abstractmethod
    def heartbeat_age_s(self) -> float:
        """Seconds since the last heartbeat, or since ``connect`` while none has arrived."""

    @abc.abstractmethod
    def close(self) -> None:
        """Release the device; safe to call twice."""

    def __enter__(self) -> ContactProbe:
        self.connect()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class CanContactProbe(ContactProbe):
    """Contact probe read from a CAN bus with ``can.Bus`` in a background thread.

    Args:
        channel: bus channel (``can0``, or any name for ``interface="virtual"``).
        interface: python-can interface (``socketcan``, ``pcan``, ``virtual``, ...).
        heartbeat_timeout_s: a heartbeat older than this [s] means the probe is lost.
        base_id: arbitration id of the heartbeat; contact events use ``base_id + 1``.
        bus_kwargs: passed to ``can.Bus`` (``bitrate=500000``, ...).
    """

    def __init__(self, channel: str, interface: str = "socketcan", heartbeat_timeout_s: float = 0.5,
                 base_id: int = DEFAULT_BASE_ID, **bus_kwargs: Any) -> None:
        if heartbeat_timeout_s <= 0:
            raise ValueError(f"heartbeat_timeout_s must be > 0, got {heartbeat_timeout_s}")
        self.channel = channel
        self.interface = interface
        self.heartbeat_timeout_s = heartbeat_timeout_s
        self.base_id = base_id
        self.device = f"can-probe@{interface}:{channel}"
        self._bus_kwargs = bus_kwargs
        self._bus: Any = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._cond = threading.Condition()
        self._latest: ContactEvent | None = None
        self._last_touch: ContactEvent | None = None
        self._touches = 0
        self._connected_at = 0.0
        self._last_heartbeat: float | None = None
        self._status = 0
        self._stats = ProbeStats()
        self._bus_error: str | None = None

    def connect(self) -> None:
        if self._bus is not None:
            return
        can = import_can()
        try:
            self._bus = can.Bus(channel=self.channel, interface=self.interface, **self._bus_kwargs)
        except (can.CanError, OSError, ValueError) as e:
            raise DriverError(self.device, f"cannot open the bus: {e}") from e
        self._stop.clear()
        self._stats = ProbeStats()
        self._bus_error = None
        self._last_heartbeat = None
        self._connected_at = time.monotonic()
        self._thread = threading.Thread(target=self._read, name="can-probe", daemon=True)
        self._thread.start()

    def close(self) -> None:
        if self._bus is None:
            return
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        self._bus.shutdown()
        self._bus = None

    # -- reading ---------------------------------------------------------------------------------
    def _read(self) -> None:
        can = import_can()
        while not self._stop.is_set():
            try:
                frame = self._bus.recv(timeout=0.05)
            except can.CanError as e:
                log.warning("%s: receive failed: %s", self.device, e)
                with self._cond:
                    self._bus_error = str(e)
                    self._cond.notify_all()
                return
            if frame is not None and not frame.is_extended_id and frame.arbitration_id in (self.base_id,
                                                                                            self.base_id + 1):
                self._handle(frame.arbitration_id, bytes(frame.data), frame.is_remote_frame or frame.is_error_frame)

    def _handle(self, arbitration_id: int, data: bytes, bad_kind: bool) -> None:
        now = time.monotonic()
        s = self._stats
        with self._cond:
            if arbitration_id == self.base_id and not bad_kind and len(data) == 2 and data[1] & ~0x07 == 0:
                self._last_heartbeat, self._status = now, data[1]
                self._stats = ProbeStats(s.heartbeats + 1, s.events, s.malformed, s.lost_events)
            elif arbitration_id == self.base_id + 1 and not bad_kind and len(data) == 6 and data[0] in (0, 1):
                state, seq, probe_ms = _EVENT.unpack(data)
                lost = 0 if self._latest is None else (seq - self._latest.sequence - 1) % 256
                self._latest = ContactEvent(bool(state), seq, probe_ms, now)
                if state:
                    self._last_touch = self._latest
                    self._touches += 1
                self._stats = ProbeStats(s.heartbeats, s.events + 1, s.malformed, s.lost_events + lost)
            else:
                log.debug("%s: malformed frame id 0x%X data %s", self.device, arbitration_id, data.hex())
                self._stats = ProbeStats(s.heartbeats, s.events, s.malformed + 1, s.lost_events)
            self._cond.notify_all()

    # -- queries ---------------------------------------------------------------------------------
    @property
    def latest(self) -> ContactEvent | None:
        """The last touch or release received, or None."""
        with self._cond:
            return self._latest

    @property
    def stats(self) -> ProbeStats:
        """Frame counters since ``connect``."""
        with self._cond:
            return self._stats

    @property
    def status_bits(self) -> int:
        """Status byte of the last heartbeat (``STATUS_ARMED | STATUS_FAULT | STATUS_CONTACT``)."""
        with self._cond:
            return self._status

    def heartbeat_age_s(self) -> float:
        with self._cond:
            last = self._connected_at if self._last_heartbeat is None else self._last_heartbeat
            return time.monotonic() - last

    def is_alive(self) -> bool:
        """True when a heartbeat arrived within ``heartbeat_timeout_s``."""
        return self.heartbeat_age_s() <= self.heartbeat_timeout_s

    def check_alive(self) -> None:
        """Raise DriverTimeout when the heartbeat is older than ``heartbeat_timeout_s``, DriverError on a bus fault."""
        if self._bus is None:
            raise DriverError(self.device, "not connected; call connect() first")
        if self._bus_error is not None:
            raise DriverError(self.device, f"bus failed: {self._bus_error}")
        if not self.is_alive():
            raise DriverTimeout(self.device, "the probe heartbeat", self.heartbeat_timeout_s)

    def wait_for_contact(self, timeout_s: float) -> ContactEvent:
        """Block until a touch arrives after this call.

        Raises:
            DriverTimeout: no touch within ``timeout_s`` [s], or the heartbeat was lost while waiting.
            DriverError: not connected, or the bus failed.
        """
        deadline = time.monotonic() + timeout_s
        with self._cond:
            touches = self._touches
            while True:
                if self._touches > touches and self._last_touch is not None:
                    return self._last_touch
                self.check_alive()
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise DriverTimeout(self.device, "a contact", timeout_s)
                self._cond.wait(min(remaining, self.heartbeat_timeout_s / 4))
