"""A simulated CAN contact probe: the frames a real probe sends, on python-can's virtual bus (or any bus)."""

from __future__ import annotations

import threading
import time
from typing import Any

from drivers.can_probe import DEFAULT_BASE_ID, STATUS_ARMED, STATUS_CONTACT, encode_event, encode_heartbeat, import_can


class SimulatedProbe:
    """A probe that speaks the frame layout of :mod:`drivers.can_probe` on a bus: heartbeats from a thread,
    events on demand.

    Ships in the package so the app and the tests run with no hardware (``interface="virtual"``).

    Args:
        channel: bus channel; a ``CanContactProbe`` on the same virtual channel receives the frames.
        interface: python-can interface.
        heartbeat_period_s: time between heartbeats [s].
        base_id: arbitration id of the heartbeat.
        bus_kwargs: passed to ``can.Bus``.
    """

    def __init__(self, channel: str, interface: str = "virtual", heartbeat_period_s: float = 0.05,
                 base_id: int = DEFAULT_BASE_ID, **bus_kwargs: Any) -> None:
        self.channel = channel
        self.interface = interface
        self.heartbeat_period_s = heartbeat_period_s
        self.base_id = base_id
        self.status = STATUS_ARMED
        self.heartbeat_paused = False  # set True to simulate a dead probe (heartbeat loss)
        self._bus_kwargs = bus_kwargs
        self._bus: Any = None
        self._lock = threading.Lock()
        self._counter = 0
        self._sequence = 0
        self._t0 = time.monotonic()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> SimulatedProbe:
        """Open the bus and start heartbeating; returns self."""
        can = import_can()
        self._bus = can.Bus(channel=self.channel, interface=self.interface, **self._bus_kwargs)
        self._stop.clear()
        self._thread = threading.Thread(target=self._beat, name="sim-can-probe", daemon=True)
        self._thread.start()
        return self

    def close(self) -> None:
        """Stop heartbeating and close the bus; safe to call twice."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        if self._bus is not None:
            self._bus.shutdown()
            self._bus = None

    def __enter__(self) -> SimulatedProbe:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _beat(self) -> None:
        while not self._stop.wait(self.heartbeat_period_s):
            if not self.heartbeat_paused:
                with self._lock:
                    self._counter = (self._counter + 1) & 0xFF
                    counter = self._counter
                self.send_raw(*encode_heartbeat(counter, self.status, self.base_id))

    def _event(self, touched: bool) -> int:
        with self._lock:
            self._sequence = (self._sequence + 1) & 0xFF
            sequence = self._sequence
        self.status = (self.status | STATUS_CONTACT) if touched else (self.status & ~STATUS_CONTACT)
        probe_ms = int((time.monotonic() - self._t0) * 1000)
        self.send_raw(*encode_event(touched, sequence, probe_ms, self.base_id))
        return sequence

    def touch(self) -> int:
        """Send a touch event; returns its sequence number."""
        return self._event(True)

    def release(self) -> int:
        """Send a release event; returns its sequence number."""
        return self._event(False)

    def skip_events(self, n: int) -> None:
        """Advance the sequence counter by ``n`` without sending, as if ``n`` events were lost on the bus."""
        with self._lock:
            self._sequence = (self._sequence + n) & 0xFF

    def send_raw(self, arbitration_id: int, data: bytes, **frame_kwargs: Any) -> None:
        """Send any frame (``is_remote_frame=True``, a wrong DLC, ...) to exercise the receiver."""
        can = import_can()
        self._bus.send(can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=False,
                                   **frame_kwargs))
