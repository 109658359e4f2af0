"""The dwell window opens at the settle instant mapped onto the mocap's clock, not at the first frame read.

A scripted mocap source on a manual host clock: each frame has a capture instant (host time) and a delivery
instant; its stamp is on the source's own clock (an offset from the host's). Frames captured while the arm still
moved carry a marker 1 mm off, so any of them in the average shows in the mean.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from app.collection.collect import CollectConfig as Options
from app.collection.mocap_window import ClockLink, WindowFailed, average_frames, collect_window
from drivers.base import MocapSource, RigidBodyFrame

OFFSET = -500.0  # source clock = host clock + OFFSET
PERIOD = 0.01  # 100 Hz


class HostClock:
    def __init__(self, t: float = 0.0) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


class ScriptedMocap(MocapSource):
    """Frames captured every PERIOD from ``t_from``; ``latency(t)`` [s] gives each one's delivery delay."""

    def __init__(self, clock: HostClock, t_from: float, settle: float, latency, stamp=lambda t: t + OFFSET) -> None:
        self.clock, self.settle, self.latency, self.stamp = clock, settle, latency, stamp
        self.next_capture = t_from
        self.pending: list[tuple[float, RigidBodyFrame]] = []
        self.number = 0

    def connect(self) -> None: ...

    def close(self) -> None: ...

    def _capture_until(self, t: float) -> None:
        while self.next_capture <= t:
            c = self.next_capture
            moving = c < self.settle
            p = np.array([1.0 if moving else 0.0, 0.0, 0.0])
            self.number += 1
            f = RigidBodyFrame(1, p, np.array([1.0, 0.0, 0.0, 0.0]), 0.1, True, self.stamp(c), self.number)
            self.pending.append((c + self.latency(c), f))
            self.next_capture = round(c + PERIOD, 9)

    def _due(self) -> list[RigidBodyFrame]:
        out = [f for d, f in self.pending if d <= self.clock.t + 1e-12]
        self.pending = [(d, f) for d, f in self.pending if d > self.clock.t + 1e-12]
        return out

    def read(self, timeout_s: float) -> list[RigidBodyFrame]:
        deadline = self.clock.t + timeout_s
        while True:
            self._capture_until(self.clock.t)
            got = self._due()
            if got or self.clock.t >= deadline:
                return got
            self.clock.t = min(deadline, round(self.clock.t + 0.001, 9))


def _stall(settle: float, start: float = 0.1, end: float = 0.05):
    """Latency 2 ms, except that delivery stalls (a loaded host) from ``start`` before ``settle`` until ``end``
    after it, then everything held back arrives at once, in order."""
    def latency(c: float) -> float:
        return settle + end - c if settle - start <= c < settle + end else 0.002
    return latency


def test_frames_in_transit_when_the_arm_settled_stay_out_of_the_window() -> None:
    clock = HostClock(0.0)
    settle = 10.0
    src = ScriptedMocap(clock, 0.0, settle, _stall(settle))
    link = ClockLink(clock)
    clock.t = 9.0  # earlier reads taught the link the offset (the session's previous pose)
    src.read(0.0)
    link.observe(src.read(0.1))
    clock.t = settle  # the arm moved until now; the frames of its last 0.1 s are held up on the way
    frames = collect_window(src, 1, Options(), link, settle)
    p, *_ = average_frames(frames)
    assert np.linalg.norm(p) < 1e-12, f"a frame captured in motion was averaged (mean {p})"
    assert min(f.capture_time for f in frames) >= settle + OFFSET + Options.discard_s - 0.003
    assert len(frames) >= 45  # the whole half-second window, not a shortened one


def test_a_fresh_link_learns_the_offset_while_the_window_fills() -> None:
    clock = HostClock(0.0)
    settle = 10.0
    src = ScriptedMocap(clock, 9.0, settle, _stall(settle))
    link = ClockLink(clock)
    clock.t = settle
    frames = collect_window(src, 1, Options(), link, settle)  # the link has seen no frame before this window
    p, *_ = average_frames(frames)
    assert np.linalg.norm(p) < 1e-12, f"a frame captured in motion was averaged (mean {p})"


def test_a_stamp_that_stops_advancing_fails_the_window_instead_of_waiting_for_ever() -> None:
    clock = HostClock(0.0)
    src = ScriptedMocap(clock, 0.0, 0.0, lambda c: 0.002, stamp=lambda t: min(t, 5.0) + OFFSET)
    link = ClockLink(clock)
    clock.t = 5.2
    with pytest.raises(WindowFailed, match="none closed"):
        collect_window(src, 1, Options(), link, 5.2)


def test_a_source_clock_restarted_behind_resets_the_link() -> None:
    clock = HostClock(0.0)
    link = ClockLink(clock)
    f = lambda c: RigidBodyFrame(1, np.zeros(3), np.array([1.0, 0, 0, 0]), 0.1, True, c, 0)  # noqa: E731
    clock.t = 100.0
    link.observe([f(50.0)])
    assert link.to_capture(100.0) == pytest.approx(50.0)
    clock.t = 101.0
    link.observe([f(0.5)])  # restarted: its clock reads 0.5 s
    assert link.to_capture(101.0) == pytest.approx(0.5)


def test_the_link_keeps_the_tightest_recent_bound_and_forgets_old_ones() -> None:
    clock = HostClock(0.0)
    link = ClockLink(clock, horizon_s=30.0)
    assert link.to_capture(1.0) == -math.inf
    f = lambda c: RigidBodyFrame(1, np.zeros(3), np.array([1.0, 0, 0, 0]), 0.1, True, c, 0)  # noqa: E731
    for t, latency in [(1.0, 0.001), (2.0, 0.1), (3.0, 0.05)]:
        clock.t = t
        link.observe([f(t - latency + OFFSET)])
    assert link.to_capture(3.0) == pytest.approx(3.0 + OFFSET - 0.001)
    clock.t = 40.0  # the 1 ms bound is older than the horizon
    link.observe([f(40.0 - 0.02 + OFFSET)])
    assert link.to_capture(40.0) == pytest.approx(40.0 + OFFSET - 0.02)


def test_a_link_off_its_sources_clock_fails_the_window_naming_it() -> None:
    """Every frame of a source read against another clock looks held up: the window fails, naming the clock (it
    used to open at the first frame, a dropout after it at most, which a stalled bridge's backlog also did)."""
    clock = HostClock(0.0)
    # stamps at half the host's rate (a simulated source read against the host clock by mistake)
    src = ScriptedMocap(clock, 0.0, 0.0, lambda c: 0.002, stamp=lambda t: 0.5 * t + OFFSET)
    link = ClockLink(clock)
    clock.t = 1.0
    src.read(0.0)
    link.observe(src.read(0.1))  # its smallest bound; the later ones grow at half a second per second
    clock.t = 20.0  # mapped through that bound, now lies 9.5 stamp-seconds ahead of the stamps
    with pytest.raises(WindowFailed, match="frames held up, or a capture clock off the host's"):
        collect_window(src, 1, Options(), link, 20.0)


def test_a_backlog_held_up_by_a_stalled_bridge_stays_out_of_the_window() -> None:
    """The bridge stalled 6 s while the arm moved to its next target; when it came back it delivered its backlog
    at once, and the window opened at the backlog's first frame, a dropout after it at most: the sample averaged
    frames captured in motion (22.7 mm off in issue 30's rehearsal). Held-up frames are left out."""
    clock = HostClock(0.0)
    settle = 10.0
    src = ScriptedMocap(clock, 0.0, settle, lambda c: settle + 0.05 - c if 4.0 <= c < settle + 0.05 else 0.002)
    link = ClockLink(clock)
    clock.t = 3.9  # the previous window taught the link the offset
    src.read(0.0)
    link.observe(src.read(0.1))
    clock.t = settle
    frames = collect_window(src, 1, Options(), link, settle)
    p, *_ = average_frames(frames)
    assert np.linalg.norm(p) < 1e-12, f"a frame captured in motion was averaged (mean {p})"
    assert min(f.capture_time for f in frames) >= settle + OFFSET + Options.discard_s - 0.003
    assert len(frames) >= 45


def test_simulated_sources_and_wrappers_name_the_clock_their_stamps_keep() -> None:
    from app.collection.runtime.real import BaseFrameMocap
    from drivers.natnet.client import NatNetSource
    from tests.app.collection.sim_cell import make_cell

    _, driver, source, _, _ = make_cell()
    assert source.stamp_clock() == driver.clock.now
    assert BaseFrameMocap(source, None, 1).stamp_clock() == driver.clock.now
    assert ScriptedMocap(HostClock(), 0.0, 0.0, lambda c: 0.0).stamp_clock() is None
    assert NatNetSource.stamp_clock is MocapSource.stamp_clock  # a real system: the host's clock


def test_a_window_too_short_for_the_stream_rate_names_the_cell_file_key() -> None:
    from dataclasses import replace

    clock = HostClock(0.0)
    src = ScriptedMocap(clock, 0.0, 0.0, lambda c: 0.002)
    clock.t = 1.0
    with pytest.raises(WindowFailed, match=r"0.05 s window holds [0-9] frames .* mocap.dwell_s"):
        collect_window(src, 1, replace(Options(), dwell_s=0.05), ClockLink(clock), 1.0)
