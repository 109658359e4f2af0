"""One static pose from a mocap stream: the frames of one dwell window, checked and averaged.

After the arm has settled, the frames captured during a dwell window (after a short discard for latency and
residual vibration) are collected; frames that are not tracking-valid, carry a large marker error or bad values
are rejected, and the rest are averaged: mean position, eigenvector quaternion average. Too few usable frames,
or none for a while, is a failure worth retrying (:class:`WindowFailed`).

The window starts on the mocap's clock, at the moment the arm was seen settled (host clock) mapped through a
:class:`ClockLink`: frames that were captured while the arm still moved but were in transit when the queue was
flushed (network delay, a loaded host) are then left out, instead of opening the window.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable, Sequence
from typing import Protocol

import numpy as np

from drivers.base import MocapSource, RigidBodyFrame


class WindowOptions(Protocol):
    """What a window needs (:class:`app.collection.collect.CollectConfig` has it). Times are on the mocap clock [s]."""

    @property
    def dwell_s(self) -> float: ...
    @property
    def discard_s(self) -> float: ...
    @property
    def frame_timeout_s(self) -> float: ...
    @property
    def min_frames(self) -> int: ...
    @property
    def min_valid_fraction(self) -> float: ...
    @property
    def max_marker_error_mm(self) -> float: ...


class WindowFailed(Exception):
    """No frames for a while, or too few usable frames in the window: worth measuring again."""


class ClockLink:
    """Maps a host-clock instant onto a mocap source's capture clock, from the frames as they are received.

    A frame captured at mocap time ``c`` and read at host time ``r`` bounds the offset host - mocap from above:
    ``offset <= r - c`` (its latency is not negative). The smallest bound over the frames of the last
    ``horizon_s`` is the estimate; it exceeds the true offset by the smallest latency seen (a few ms when some read
    returned as soon as a frame arrived), so a window started at ``settled - estimate`` may begin that much before
    the settle instant, which the window's discard covers. The horizon keeps a drift between the two clocks
    (crystal rates differ by ppm) out of the estimate.

    Args:
        clock: the host clock [s] the settle instants are read on (the collector's clock).
        horizon_s: how long a bound is kept [s] (host clock).
    """

    def __init__(self, clock: Callable[[], float] = time.monotonic, horizon_s: float = 30.0) -> None:
        self.clock = clock
        self.horizon_s = float(horizon_s)
        self._bounds: deque[tuple[float, float]] = deque()  # (host read time, bound), bounds increasing
        self._latest = -math.inf  # newest capture time seen

    def observe(self, frames: Sequence[RigidBodyFrame]) -> float:
        """Take the bounds of ``frames`` read just now; returns the host read time.

        A capture clock that went back by over a second (the mocap software restarted) starts the link afresh.
        """
        r = self.clock()
        if frames:
            newest = max(f.capture_time for f in frames)
            if newest < self._latest - 1.0:
                self._bounds.clear()
            self._latest = newest
            bound = r - newest
            while self._bounds and self._bounds[-1][1] >= bound:
                self._bounds.pop()  # a later, smaller bound makes it useless
            self._bounds.append((r, bound))
        while self._bounds and self._bounds[0][0] < r - self.horizon_s and len(self._bounds) > 1:
            self._bounds.popleft()
        return r

    def to_capture(self, host_time: float) -> float:
        """``host_time`` on the mocap clock (−inf before any frame was observed)."""
        return host_time - self._bounds[0][1] if self._bounds else -math.inf


def quat_average(quat: np.ndarray) -> np.ndarray:
    """Average of unit quaternions (w, x, y, z), shape (N, 4) -> (4,): the principal eigenvector of sum q q^T."""
    quat = np.asarray(quat, dtype=float)
    _, vecs = np.linalg.eigh(quat.T @ quat)
    q = vecs[:, -1]
    return q if q[0] >= 0 else -q


def average_frames(frames: Sequence[RigidBodyFrame]) -> tuple[np.ndarray, np.ndarray, float, float, float]:
    """Mean pose of static frames.

    Returns:
        ``(p (3,) mm, quat (4,), position RMS spread [mm], orientation RMS spread [deg], mean marker error [mm])``.
    """
    p = np.array([f.position_mm for f in frames], dtype=float)
    qs = np.array([f.quat_wxyz for f in frames], dtype=float)
    qs /= np.linalg.norm(qs, axis=1, keepdims=True)
    p_mean = p.mean(axis=0)
    q_mean = quat_average(qs)
    std_pos = float(np.sqrt(np.mean(np.sum((p - p_mean) ** 2, axis=1))))
    angles = 2.0 * np.arccos(np.clip(np.abs(qs @ q_mean), 0.0, 1.0))
    std_rot = float(np.degrees(np.sqrt(np.mean(angles**2))))
    return p_mean, q_mean, std_pos, std_rot, float(np.mean([f.marker_error_mm for f in frames]))


def usable(f: RigidBodyFrame, max_marker_error_mm: float) -> bool:
    p = np.asarray(f.position_mm, dtype=float)
    q = np.asarray(f.quat_wxyz, dtype=float)
    return bool(f.tracking_valid and f.marker_error_mm <= max_marker_error_mm and p.shape == (3,) and q.shape == (4,)
                and bool(np.all(np.isfinite(p)) and np.all(np.isfinite(q))) and abs(np.linalg.norm(q) - 1.0) < 1e-3)


def collect_window(mocap: MocapSource, body_id: int, config: WindowOptions, link: ClockLink,
                   settled_at: float | None = None) -> list[RigidBodyFrame]:
    """Frames of ``body_id`` captured during one dwell window after the arm settled, usable ones only.

    The window opens ``discard_s`` after the later of: the first frame read after the flush, and ``settled_at``
    (host clock, default: now) mapped onto the capture clock by ``link``. The mapping sharpens as frames come in,
    so the start can only move later while the window fills; the frames are kept and sorted out at the end. A
    frame read more than ``frame_timeout_s`` after the link says it was captured is held up, not in transit (a
    bridge or a network that stalled delivers its backlog): it is left out. A stalled bridge's backlog, captured
    while the arm moved to the target, had opened the window and made a sample 22.7 mm off (issue 30's rehearsal).
    A link off its source's clock (see :meth:`drivers.base.MocapSource.stamp_clock`) sees every frame held up and
    fails the window, naming it.

    Args:
        link: the source's clock link, kept across windows (it learns the offset from every read).
        settled_at: host-clock instant the arm was seen settled (``link.clock``); now when not given.

    Raises:
        WindowFailed: no frames for ``frame_timeout_s``, or too few usable frames.
    """
    if settled_at is None:
        settled_at = link.clock()
    link.observe(mocap.read(0.0))  # drop what was queued: captured before the arm settled (most of it)
    got_all: list[RigidBodyFrame] = []
    t0 = first = -math.inf
    # a last guard: frames keep coming but none closes the window, the clocks disagree beyond what observe mends
    give_up = link.clock() + 5.0 * (config.discard_s + config.dwell_s + config.frame_timeout_s)
    while True:
        got = mocap.read(config.frame_timeout_s)
        if not got:
            raise WindowFailed(f"mocap: no frames for {config.frame_timeout_s:g} s")
        read_at = link.observe(got)
        if read_at > give_up:
            raise WindowFailed(f"mocap: frames came but none closed the {config.dwell_s:g} s window by "
                               f"{give_up - settled_at:.3g} s after the arm settled (frames held up, or a capture "
                               "clock off the host's)")
        # frames held up longer than a dropout (a backlog: the bridge or the network stalled) were captured before
        # now by more than the link allows; they say nothing of the pose the arm holds now
        now = link.to_capture(read_at)
        got = [f for f in got if now - f.capture_time <= config.frame_timeout_s]
        if not got:
            continue
        if not got_all:
            first = got[0].capture_time + config.discard_s
            t0 = first
        got_all += got
        t0 = max(t0, link.to_capture(settled_at) + config.discard_s)
        if got[-1].capture_time >= t0 + config.dwell_s:
            break
    window = [f for f in got_all if t0 <= f.capture_time <= t0 + config.dwell_s]
    numbers = [f.frame_number for f in window]
    frames = [f for f in window if f.body_id == body_id]
    expected = max(numbers) - min(numbers) + 1 if numbers else 0
    good = [f for f in frames if usable(f, config.max_marker_error_mm)]
    lost = sum(not f.tracking_valid for f in frames)
    if 0 < expected < config.min_frames and len(good) == expected:
        raise WindowFailed(f"mocap: a {config.dwell_s:g} s window holds {expected} frames at this stream's rate, "
                           f"fewer than the {config.min_frames} a sample needs: lengthen the window (the cell "
                           "file's mocap.dwell_s)")
    if len(good) < config.min_frames or len(good) < config.min_valid_fraction * expected:
        raise WindowFailed(f"mocap: {len(good)} usable of ~{expected} frames of body {body_id} "
                             f"({lost} not tracking, {len(frames) - len(good) - lost} with marker error above "
                             f"{config.max_marker_error_mm:g} mm or bad values, {max(0, expected - len(frames))} "
                             "missing)")
    return good
