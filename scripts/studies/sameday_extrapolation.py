"""Where pi's same-day test error comes from: extrapolation in q1/q4-q6, or the measurement. Reads TEST recordings.

This is a diagnosis of the final figures, not a tuning tool: nothing here feeds back into a default. For every
shared day with a test recording (the pairs of ``scripts/benchmarks/bench_days.py``), pi fitted on the day's training
recording as ``compare`` fits it, and on its test recording:

- **by distance from training**: the test poses binned by how far joints 1, 4, 5, 6 (the ones the training
  recordings keep within 2 deg, or 6 deg on 0524/0613/0620) leave the training range (largest excess over the
  four joints, deg); mean / max position error per bin [mm];
- **seen**: pi refitted on the test recording itself, five folds, each fold predicted by the fit on the other
  four: with interleaved folds (row i in fold i mod 5; its neighbours along the same line are seen) what the same
  model form reaches once it has seen these configurations, and with blocks of 300 consecutive rows (a region of
  the test poses left out) what it reaches when it must extrapolate within the test's own range (mean / max);
- **one-sided shift** (:mod:`calibration.diagnosis.shifts`) of the test residual of the training fit, and of the
  seen fit's residual: the share of the largest residuals on one side, how many poses are shifted, the cosine
  between the test shift's direction and the training recording's, and the seen fit's max without them.

    python scripts/studies/sameday_extrapolation.py [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from calibration.data.recording import read_recording  # noqa: E402
from calibration.diagnosis.shifts import one_sided_shift  # noqa: E402
from calibration.methods.fitter import Fitter  # noqa: E402
from calibration.methods.shared import SharedCache  # noqa: E402
from cell_config import load_cell  # noqa: E402
from scripts.benchmarks.bench_days import DATA, UNITS  # noqa: E402

NARROW_JOINTS = (0, 3, 4, 5)
BINS_DEG = (0.0, 10.0, 30.0, 60.0, 1e9)
N_TEST_FOLDS = 5


def excess_deg(q: np.ndarray, q_train: np.ndarray) -> np.ndarray:
    """Largest excess [deg] of joints 1, 4, 5, 6 of q (N, 6) beyond the training range, shape (N,)."""
    lo, hi = q_train.min(axis=0), q_train.max(axis=0)
    out = np.maximum(lo - q, 0.0) + np.maximum(q - hi, 0.0)
    return np.degrees(out[:, NARROW_JOINTS].max(axis=1))


def position_residual(model, rec) -> np.ndarray:
    _, p = model.fk(rec.q)
    return rec.p - p


def seen_residual(fitter, interleaved: bool) -> np.ndarray:
    """Residual of pi on a recording predicted fold by fold (interleaved rows, or consecutive blocks) from the
    fit on the others."""
    rec = fitter.train
    rows = np.arange(len(rec))
    folds = rows % N_TEST_FOLDS if interleaved else rows * N_TEST_FOLDS // len(rec)
    r = np.empty((len(rec), 3))
    for f in range(N_TEST_FOLDS):
        sub = replace(fitter, train=rec.subset(folds != f), warm=fitter, _cache=SharedCache())
        r[folds == f] = position_residual(sub.physics_informed(), rec.subset(folds == f))
    return r


def unit_row(robot, train_folder: str, label: str, test_folder: str) -> dict:
    lo, hi = robot.robot.lower_rad, robot.robot.upper_rad
    train = read_recording(DATA / "PH_grad_data" / train_folder, lo, hi)
    test = read_recording(DATA / "kinematic_raw_data" / test_folder, lo, hi)
    pi = Fitter.for_arm(robot.arm(), train).physics_informed()
    r_test = position_residual(pi, test)
    e = np.linalg.norm(r_test, axis=1)
    x = excess_deg(test.q, train.q)
    bins = []
    for a, b in zip(BINS_DEG[:-1], BINS_DEG[1:]):
        m = (x >= a) & (x < b)
        bins.append({"from_deg": a, "to_deg": b, "poses": int(m.sum()),
                     "mean_mm": float(e[m].mean()) if m.any() else None,
                     "max_mm": float(e[m].max()) if m.any() else None})
    train_shift = one_sided_shift(position_residual(pi, train))
    test_shift = one_sided_shift(r_test)
    on_test = Fitter.for_arm(robot.arm(), test)
    e_inter = np.linalg.norm(seen_residual(on_test, True), axis=1)
    r_seen = seen_residual(on_test, False)
    e_seen = np.linalg.norm(r_seen, axis=1)
    seen_shift = one_sided_shift(r_seen)
    return {"unit": label, "test_mean_mm": float(e.mean()), "test_max_mm": float(e.max()),
            "corr_error_excess": float(np.corrcoef(e, x)[0, 1]), "bins": bins,
            "seen_interleaved_mean_mm": float(e_inter.mean()), "seen_interleaved_max_mm": float(e_inter.max()),
            "seen_mean_mm": float(e_seen.mean()), "seen_max_mm": float(e_seen.max()),
            "test_shift_share": test_shift.one_sided_share, "test_shifted": int(test_shift.shifted.sum()),
            "seen_shift_share": seen_shift.one_sided_share, "seen_shifted": int(seen_shift.shifted.sum()),
            "seen_max_unshifted_mm": float(e_seen[~seen_shift.shifted].max()),
            "cos_test_train_shift": float(abs(test_shift.direction @ train_shift.direction)),
            "train_shifted": int(train_shift.shifted.sum())}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    robot = load_cell().robot("R1")
    rows = []
    for label, train_folder, test_folder in ((lab, u.train, t) for u in UNITS for lab, t in u.tests):
        row = unit_row(robot, train_folder, label, test_folder)
        rows.append(row)
        b = " ".join(f"[{x['from_deg']:.0f},{x['to_deg']:.0f}):{x['poses']} "
                     + (f"{x['mean_mm']:.3f}/{x['max_mm']:.3f}" if x["poses"] else "-") for x in row["bins"])
        print(f"{row['unit']:14s} test {row['test_mean_mm']:.3f}/{row['test_max_mm']:.3f} corr(e, excess) "
              f"{row['corr_error_excess']:+.2f} | {b} | seen interleaved {row['seen_interleaved_mean_mm']:.3f}/"
              f"{row['seen_interleaved_max_mm']:.3f} blocks {row['seen_mean_mm']:.3f}/{row['seen_max_mm']:.3f} "
              f"(unshifted max {row['seen_max_unshifted_mm']:.3f}) | shift share test {row['test_shift_share']:.2f} "
              f"({row['test_shifted']}) seen {row['seen_shift_share']:.2f} ({row['seen_shifted']}) train "
              f"({row['train_shifted']}) cos {row['cos_test_train_shift']:.2f}", flush=True)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
