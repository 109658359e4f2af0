"""Why pi misses 0.30 / 0.75 mm on some days: candidate causes measured on the training recordings only.

For every R1 training recording of ``../shared/data/welding_motoman/PH_grad_data`` (no test recording is read),
with the ``pi`` fit as ``compare`` makes it:

- **held-out clusters**: position error of every training pose predicted by pi refitted without that pose's
  cluster (5 folds of whole clusters, :meth:`Fitter.held_out_errors`): mean, p95, max [mm];
- **drift over the recording order** (the recordings have no time column; row order is the only clock, and it is
  confounded with q2, which the anchors sweep slowly): the end-to-end change of the residual along a straight
  line in the row index [mm], and the RMS of the residual's 70-row moving mean [mm];
- **approach direction (backlash)**: the approach direction of each joint from the row order, one lost motion per
  joint fitted to the residual along ``J_q``: the fitted widths [deg] and the training RMS before/after [mm];
- **one-sided shifts**: the principal direction ``v`` of the largest 5 % of residuals. Noise and smooth model
  error give large residuals of both signs along any direction; a measurement that jumps by a fixed vector on
  some poses gives them of one sign. Printed: the share of the largest 5 % on the ``+v`` side, how many poses
  sit beyond the median + 3.5 MAD of the projection on ``v`` (``shifted``), the mean shift of those [mm], and
  whether the worst held-out pose is one of them;
- **time or configuration**: the anchors are recorded column by column (one q2, q3 swept), so two clusters 5 deg
  apart in q3 within a column were recorded minutes apart, two clusters 5 deg apart in q2 (next column, nearest
  q3) about ten clusters apart. The RMS difference of the clusters' median residuals [mm] for both kinds of
  neighbours, and their ratio: an error that is a function of the configuration gives a ratio near 1, one that
  changes with recording time (a drifting or switching measurement) a ratio above 1.

    python scripts/studies/sameday_causes.py [--json FILE] [--days test0801_R1,...]
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from calibration.data.recording import read_recording  # noqa: E402
from calibration.diagnosis.shifts import OneSidedShift, one_sided_shift  # noqa: E402
from calibration.methods.cdc import cluster_anchors  # noqa: E402
from calibration.methods.fitter import Fitter  # noqa: E402
from scripts.benchmarks.bench_days import DATA  # noqa: E402
from scripts.studies.heldout_folds import run_days

WINDOW = 70  # rows of the moving mean: 10 clusters


def approach_directions(q: np.ndarray, eps_rad: float = np.radians(0.05)) -> np.ndarray:
    """Sign of the last move of each joint larger than ``eps_rad`` before each row (0 before the first), (N, 6)."""
    d = np.zeros_like(q)
    last = np.zeros(q.shape[1])
    for i in range(1, len(q)):
        step = q[i] - q[i - 1]
        last = np.where(np.abs(step) > eps_rad, np.sign(step), last)
        d[i] = last
    return d


def backlash_fit(J_q: np.ndarray, d: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, float]:
    """Lost motion per joint [rad] (full width) fitted to residual r (N, 3) = J_q (N, 3, 6) d b / 2; the RMS after."""
    A = (J_q * d[:, None, :] * 0.5).reshape(-1, d.shape[1])
    seen = np.abs(A).sum(axis=0) > 0
    b = np.zeros(d.shape[1])
    b[seen] = np.linalg.lstsq(A[:, seen], r.reshape(-1), rcond=None)[0]
    after = (r.reshape(-1) - A @ b).reshape(-1, 3)
    return b, float(np.sqrt(np.mean(np.sum(after**2, axis=1))))


def drift(r: np.ndarray) -> tuple[float, float]:
    """End-to-end change of a straight line through the residual (N, 3) over the row index [mm], and the RMS
    norm of its moving mean over WINDOW rows [mm]."""
    n = len(r)
    idx = np.arange(n)
    slope = np.array([np.polyfit(idx, r[:, k], 1)[0] for k in range(3)]) * n
    kernel = np.ones(WINDOW) / WINDOW
    moving = np.stack([np.convolve(r[:, k], kernel, mode="valid") for k in range(3)], axis=1)
    return float(np.linalg.norm(slope)), float(np.sqrt(np.mean(np.sum(moving**2, axis=1))))


def neighbour_differences(r: np.ndarray, groups: np.ndarray, anchors_deg: np.ndarray) -> tuple[float, float]:
    """RMS difference [mm] of cluster-median residuals between clusters 5 deg apart in q3 in the same column
    (consecutive in the recording), and between clusters 5 deg apart in q2 (next column, nearest q3 within 5.5 deg).

    Args:
        r: position residual (N, 3) [mm]; groups: cluster index per pose (N,); anchors_deg: (q2, q3) per cluster.
    """
    K = len(anchors_deg)
    med = np.stack([np.median(r[groups == k], axis=0) for k in range(K)])
    q2, q3 = anchors_deg[:, 0], anchors_deg[:, 1]
    same = [np.linalg.norm(med[k + 1] - med[k]) for k in range(K - 1)
            if abs(q2[k + 1] - q2[k]) < 1.0 and abs(abs(q3[k + 1] - q3[k]) - 5.0) < 1.5]
    nxt = []
    for k in range(K):
        c = np.flatnonzero(np.abs(q2 - (q2[k] + 5.0)) < 1.0)
        if c.size:
            j = c[np.argmin(np.abs(q3[c] - q3[k]))]
            if abs(q3[j] - q3[k]) <= 5.5:
                nxt.append(np.linalg.norm(med[j] - med[k]))
    return float(np.sqrt(np.mean(np.square(same)))), float(np.sqrt(np.mean(np.square(nxt))))


def day_row(robot, day: str) -> dict:
    train = read_recording(DATA / "PH_grad_data" / day, robot.robot.lower_rad, robot.robot.upper_rad)
    fitter = Fitter.for_arm(robot.arm(), train)
    pi = fitter.physics_informed()
    _, p = pi.fk(train.q)
    r = train.p - p
    e = np.linalg.norm(r, axis=1)
    held = fitter.held_out_errors("pi")
    b, rms_after = backlash_fit(pi.kinematics.jacobian_q(train.q, pi.theta)[:, :3], approach_directions(train.q), r)
    line_mm, moving_mm = drift(r)
    s: OneSidedShift = one_sided_shift(r)
    worst = int(np.argmax(held))
    span = np.degrees(np.ptp(train.q, axis=0))
    groups, anchors = cluster_anchors(train, fitter.options.cluster_size)
    same_mm, next_mm = neighbour_differences(r, groups, np.degrees(anchors[:, 1:3]))
    return {"day": day, "rows": len(train), "train_rms_mm": float(np.sqrt(np.mean(e**2))),
            "heldout_mean_mm": float(held.mean()), "heldout_p95_mm": float(np.percentile(held, 95)),
            "heldout_max_mm": float(held.max()), "joint_span_deg": np.round(span, 1).tolist(),
            "drift_line_mm": line_mm, "drift_moving_rms_mm": moving_mm,
            "backlash_deg": np.round(np.degrees(b), 4).tolist(), "backlash_rms_after_mm": rms_after,
            "shift_direction": np.round(s.direction, 3).tolist(), "shift_one_sided_share": s.one_sided_share,
            "shifted_poses": int(s.shifted.sum()), "shift_mean_mm": s.mean_shift_mm,
            "worst_heldout_is_shifted": bool(s.shifted[worst]),
            "heldout_max_unshifted_mm": float(held[~s.shifted].max()),
            "neighbour_same_column_mm": same_mm, "neighbour_next_column_mm": next_mm}


def show(day: str, row: dict) -> None:
    print(f"{day:21s} {row['train_rms_mm']:6.3f} {row['heldout_mean_mm']:7.3f} {row['heldout_p95_mm']:6.3f} "
          f"{row['heldout_max_mm']:6.3f} | {row['drift_line_mm']:6.3f} {row['drift_moving_rms_mm']:6.3f} | "
          f"{row['backlash_rms_after_mm']:6.3f} | {row['shift_one_sided_share']:7.2f} {row['shifted_poses']:7d} "
          f"{row['shift_mean_mm']:6.3f} {'yes' if row['worst_heldout_is_shifted'] else 'no ':3s}  "
          f"{row['heldout_max_unshifted_mm']:.3f}        | {row['neighbour_same_column_mm']:8.3f} "
          f"{row['neighbour_next_column_mm']:8.3f} "
          f"{row['neighbour_next_column_mm'] / row['neighbour_same_column_mm']:5.2f}   span deg {row['joint_span_deg']} backlash deg "
          f"{row['backlash_deg']}", flush=True)


def main(argv: list[str] | None = None) -> int:
    print(f"{'day':21s} {'train':>6s} {'ho mean':>7s} {'p95':>6s} {'max':>6s} | {'drift':>6s} {'mov':>6s} | "
          f"{'bl rms':>6s} | {'1-sided':>7s} {'shifted':>7s} {'shift':>6s} worst? max(unshifted) | "
          f"{'same col':>8s} {'next col':>8s} ratio")
    return run_days(argv, __doc__, day_row, show)


if __name__ == "__main__":
    sys.exit(main())
