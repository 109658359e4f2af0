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


def test_advance_moves_a_stepped_clock_at_once_and_only_from_its_thread():
    import pytest

    from drivers.errors import InvalidArgument

    clock = SimClock(1.0, stepped=True)  # real time: an advance that slept would take 100 s
    clock.advance(100.0)
    assert clock.now() == 100.0
    errors = []

    def other() -> None:
        try:
            clock.advance(1.0)
        except InvalidArgument as e:
            errors.append(e)

    worker = threading.Thread(target=other)
    worker.start()
    worker.join()
    assert len(errors) == 1 and clock.now() == 100.0
    with pytest.raises(InvalidArgument):
        SimClock(1.0).advance(1.0)
