"""One static pose from a mocap stream: the frames of one dwell window, checked and averaged.

After the arm has settled, the frames captured during a dwell window (after a short discard for latency and
residual vibration) are collected; frames that are not tracking-valid, carry a large marker error or bad values
are rejected, and the rest are averaged: mean position, eigenvector quaternion average. Too few usable frames,
or none for a while, is a failure worth retrying (:class:`WindowFailed`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

import numpy as np

from drivers.base import MocapSource, RigidBodyFrame


class WindowOptions(Protocol):
    """What a window needs (:class:`app.cell.collect.CollectConfig` has it). Times are on the mocap clock [s]."""

    dwell_s: float
    discard_s: float
    frame_timeout_s: float
    min_frames: int
    min_valid_fraction: float
    max_marker_error_mm: float


class WindowFailed(Exception):
    """No frames for a while, or too few usable frames in the window: worth measuring again."""


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
    return (f.tracking_valid and f.marker_error_mm <= max_marker_error_mm and p.shape == (3,) and q.shape == (4,)
            and bool(np.all(np.isfinite(p)) and np.all(np.isfinite(q))) and abs(np.linalg.norm(q) - 1.0) < 1e-3)


def collect_window(mocap: MocapSource, body_id: int, config: WindowOptions) -> list[RigidBodyFrame]:
    """Frames of ``body_id`` captured during one dwell window after now, usable ones only.

    Raises:
        WindowFailed: no frames for ``frame_timeout_s``, or too few usable frames.
    """
    mocap.read(0.0)  # drop frames captured before the arm settled
    frames: list[RigidBodyFrame] = []
    numbers: list[int] = []
    t0: float | None = None
    while True:
        got = mocap.read(config.frame_timeout_s)
        if not got:
            raise WindowFailed(f"mocap: no frames for {config.frame_timeout_s:g} s")
        if t0 is None:
            t0 = got[0].capture_time + config.discard_s
        window = [f for f in got if t0 <= f.capture_time <= t0 + config.dwell_s]
        numbers += [f.frame_number for f in window]
        frames += [f for f in window if f.body_id == body_id]
        if got[-1].capture_time >= t0 + config.dwell_s:
            break
    expected = max(numbers) - min(numbers) + 1 if numbers else 0
    good = [f for f in frames if usable(f, config.max_marker_error_mm)]
    lost = sum(not f.tracking_valid for f in frames)
    if len(good) < config.min_frames or len(good) < config.min_valid_fraction * expected:
        raise WindowFailed(f"mocap: {len(good)} usable of ~{expected} frames of body {body_id} "
                             f"({lost} not tracking, {len(frames) - len(good) - lost} with marker error above "
                             f"{config.max_marker_error_mm:g} mm or bad values, {max(0, expected - len(frames))} "
                             "missing)")
    return good
