"""A simulated clock shared by the simulated devices of one cell, optionally faster than real time."""

from __future__ import annotations

import threading
import time

from drivers.errors import InvalidArgument


class SimClock:
    """Simulated time [s], ``time_scale`` simulated seconds per real second.

    Every duration the simulated devices accept (timeouts, settling, dwell) is on this clock, so a demo at
    ``time_scale=50`` behaves like the real cell, 50 times faster.

    Two ways to run:

    * free-running (default): simulated time = real monotonic time since creation x ``time_scale``. When things
      happen in simulated time then depends on the interpreter's thread timing, so two runs differ slightly.
    * ``stepped``: simulated time advances only when the thread that created the clock (the one running the
      workflow) sleeps on it, by exactly the time it sleeps; the sleep is still paced at ``time_scale`` in real
      time. Other threads (a mocap bridge) sleep in real time and never move the clock. Every move, settle and
      dwell of the workflow thread then starts at the same simulated instant on every run, so a seeded
      simulation measures the same values (``cellcal demo --seed``).

    Args:
        time_scale: simulated seconds per real second (> 0).
        stepped: advance time only by the creating thread's sleeps (see above).

    Raises:
        InvalidArgument: ``time_scale`` is not positive.
    """

    def __init__(self, time_scale: float = 1.0, stepped: bool = False) -> None:
        if not time_scale > 0:
            raise InvalidArgument("sim:clock", "time_scale", time_scale, "a positive number of simulated s per real s")
        self.time_scale = float(time_scale)
        self.stepped = bool(stepped)
        self._t0 = time.monotonic()
        self._t = 0.0
        self._owner = threading.get_ident()

    def now(self) -> float:
        """Simulated time [s]."""
        if self.stepped:
            return self._t
        return (time.monotonic() - self._t0) * self.time_scale

    def sleep(self, seconds: float) -> None:
        """Sleep ``seconds`` of simulated time (stepped: the creating thread advances the clock by them)."""
        if seconds > 0:
            if self.stepped and threading.get_ident() == self._owner:
                self._t += seconds
            time.sleep(seconds / self.time_scale)

    def advance(self, seconds: float) -> None:
        """Stepped clock, creating thread: move simulated time on by ``seconds`` at once, without the paced real
        sleep (for a caller that waits in real time for something else, e.g. frames to come through Zenoh).

        Raises:
            InvalidArgument: a free-running clock, or another thread than the one that made the clock.
        """
        if not self.stepped or threading.get_ident() != self._owner:
            raise InvalidArgument("sim:clock", "advance", seconds, "a stepped clock, from the thread that made it")
        if seconds > 0:
            self._t += seconds
