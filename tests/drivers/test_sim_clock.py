"""The stepped simulated clock: only the thread that made it moves it, by exactly what it sleeps."""

import threading

from drivers.sim import SimClock


def test_a_stepped_clock_advances_by_the_owner_sleeps_only():
    clock = SimClock(1000.0, stepped=True)
    assert clock.now() == 0.0
    clock.sleep(0.25)
    clock.sleep(0.5)
    assert clock.now() == 0.75  # exact: no wall-clock time leaks in
    seen = []
    worker = threading.Thread(target=lambda: (clock.sleep(2.0), seen.append(clock.now())))
    worker.start()
    worker.join()
    assert seen == [0.75] and clock.now() == 0.75  # another thread's sleep waits in real time, never moves it


def test_a_free_running_clock_follows_real_time():
    clock = SimClock(1000.0)
    clock.sleep(0.5)
    assert clock.now() >= 0.5 and clock.stepped is False
