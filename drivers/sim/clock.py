"""A simulated clock shared by the simulated devices of one cell, optionally faster than real time."""

from __future__ import annotations

import time

from drivers.errors import InvalidArgument


class SimClock:
    """Simulated time [s] = real monotonic time elapsed since creation x ``time_scale``.

    Every duration the simulated devices accept (timeouts, settling, dwell) is on this clock, so a demo at
    ``time_scale=50`` behaves like the real cell, 50 times faster.

    Args:
        time_scale: simulated seconds per real second (> 0).

    Raises:
        InvalidArgument: ``time_scale`` is not positive.
    """

    def __init__(self, time_scale: float = 1.0) -> None:
        if not time_scale > 0:
            raise InvalidArgument("sim:clock", "time_scale", time_scale, "a positive number of simulated s per real s")
        self.time_scale = float(time_scale)
        self._t0 = time.monotonic()

    def now(self) -> float:
        """Simulated time [s]."""
        return (time.monotonic() - self._t0) * self.time_scale

    def sleep(self, seconds: float) -> None:
        """Sleep ``seconds`` of simulated time."""
        if seconds > 0:
            time.sleep(seconds / self.time_scale)
