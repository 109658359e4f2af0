"""The simulated contact sensor: the physics behind the simulated CAN probe.

:class:`SimContactSensor` polls, in its own thread, how far the true gun tip is from the contact point (a
callable the caller builds from the simulated arms' true poses) and sends touch / release frames through a
:class:`~drivers.sim.can_probe.SimulatedProbe` on its bus, as a real probe would when the tip touches.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any


class SimContactSensor:
    """Touches while ``distance_mm()`` is within ``tolerance_mm``. A context manager (starts/stops its thread).

    Args:
        distance_mm: the true distance of the gun tip from the contact point now [mm].
        probe: the :class:`~drivers.sim.can_probe.SimulatedProbe` whose ``touch``/``release`` to send.
        tolerance_mm: the probe touches within this distance [mm].
        period_s: polling period [s] (real time).
    """

    def __init__(self, distance_mm: Callable[[], float], probe: Any, tolerance_mm: float = 0.1,
                 period_s: float = 0.002) -> None:
        self.distance_mm = distance_mm
        self.probe = probe
        self.tol, self.period = tolerance_mm, period_s
        self.touching = False
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="sim-contact", daemon=True)

    def _run(self) -> None:
        while not self._stop.wait(self.period):
            inside = self.distance_mm() <= self.tol
            if inside != self.touching:
                self.touching = inside
                self.probe.touch() if inside else self.probe.release()

    def __enter__(self) -> SimContactSensor:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
