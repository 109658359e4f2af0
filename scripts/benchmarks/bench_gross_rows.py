"""Gross measurement errors in a training recording (issue 30): pi's test mean with a few 50 mm rows, with and without
the gross-row rejection of :meth:`calibration.methods.fitter.Fitter.without_gross_rows`.

Each day's training recording (``PH_grad_data``) gets 1 or 10 rows moved by ``--error-mm`` in a random direction (a
marker swap; seeded), pi is fitted as ``cellcal fit`` fits it (:meth:`calibration.methods.fitter.Fitter.for_arm`), and its
position error mean on that day's test recording is compared with the clean fit's. Also printed: the rows rejected on
the clean recording (none expected) and whether they are exactly the planted ones.

    python scripts/benchmarks/bench_gross_rows.py [--days 0801,0516] [--seeds 3] [--error-mm 50] [--json FILE]
    python scripts/benchmarks/bench_gross_rows.py --clean    # the rows rejected on every shared recording as it is (none expected)
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from calibration.data.recording import Recording, read_recording  # noqa: E402
from calibration.kinematics.poe import pose_error  # noqa: E402
from calibration.methods.fitter import Fitter  # noqa: E402
from calibration.methods.heldout import GROSS_SCORE  # noqa: E402
from calibration.methods.options import FitOptions  # noqa: E402
from cell_config import load_cell  # noqa: E402

DATA = next((d / "shared" / "data" / "welding_motoman" for d in ROOT.parents
             if (d / "shared" / "data" / "welding_motoman").exists()), ROOT.parent / "shared" / "data" / "welding_motoman")
#: Same-day pairs: training recording -> test recording.
PAIRS = {"0516": ("test0516_R1", "test0516_R1"), "0613": ("test0613_R1", "test0613"),
         "0620": ("test0620_R1", "test0620_beforecalib"), "0725": ("test0725_R1", "test0725_R1"),
         "0801": ("test0801_R1", "test0801_R1")}


def corrupt(rec: Recording, n: int, error_mm: float, seed: int) -> tuple[Recording, np.ndarray]:
    """``rec`` with ``n`` random rows moved by ``error_mm`` in random directions; and those rows (0-based)."""
    rng = np.random.default_rng(seed)
    rows = np.sort(rng.choice(len(rec), n, replace=False))
    d = rng.normal(size=(n, 3))
    p = rec.p.copy()
    p[rows] += error_mm * d / np.linalg.norm(d, axis=1, keepdims=True)
    return Recording(rec.q, p, rec.quat, rec.extra, rec.source), rows


def test_mean(robot, train: Recording, test: Recording, reject: bool) -> tuple[float, tuple[int, ...]]:
    fitter = Fitter.for_arm(robot.arm(), train, None, FitOptions(reject_gross_rows=reject))
    model, _ = fitter.fit("pi")
    R, p = model.fk(test.q)
    return float(np.mean(pose_error(test.R, test.p, R, p)[0])), (fitter.gross.rows if fitter.gross else ())


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--days", default="0801")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--error-mm", type=float, default=50.0)
    ap.add_argument("--json")
    ap.add_argument("--clean", action="store_true", help="only screen every shared recording as it is")
    args = ap.parse_args()
    robot = load_cell().robot("R1")
    if args.clean:
        for folder in sorted(DATA.glob("*/*")):
            rec = read_recording(folder)
            fitter = Fitter.for_arm(robot.arm(), rec)
            g = fitter.gross
            R, p = fitter.fit("nls1")[0].fk(rec.q)
            scores = [float(np.max((e - np.median(e)) / (1.4826 * np.median(np.abs(e - np.median(e))))))
                      for e in pose_error(rec.R, rec.p, R, p)]
            print(f"{folder.parent.name}/{folder.name}: {len(g.rows)} of {g.n_samples} rows rejected, {g.beyond} beyond "
                  f"the bounds ({g.bound_mm:.2f} mm, {g.bound_deg:.2f} deg); largest score under nls1: position "
                  f"{scores[0]:.1f}, orientation {scores[1]:.1f} (bound {GROSS_SCORE:g})")
        return 0
    out = []
    for day in args.days.split(","):
        train_name, test_name = PAIRS[day]
        train = read_recording(DATA / "PH_grad_data" / train_name)
        test = read_recording(DATA / "kinematic_raw_data" / test_name)
        clean, rejected = test_mean(robot, train, test, True)
        clean_off, _ = test_mean(robot, train, test, False)
        print(f"{day}: clean pi test mean {clean:.4f} mm (rejection off: {clean_off:.4f} mm), rows rejected on the "
              f"clean recording: {len(rejected)}")
        out.append({"day": day, "clean_mm": clean, "clean_off_mm": clean_off, "clean_rejected": len(rejected)})
        for n in (1, 10):
            for seed in range(args.seeds):
                bad, rows = corrupt(train, n, args.error_mm, seed)
                on, found = test_mean(robot, bad, test, True)
                off, _ = test_mean(robot, bad, test, False)
                exact = set(found) == set(rows.tolist())
                print(f"  {n:2d} rows of {args.error_mm:g} mm, seed {seed}: off {off:.4f} mm ({off / clean - 1:+.1%}), "
                      f"on {on:.4f} mm ({on / clean - 1:+.2%}); rejected {len(found)}, exactly the planted: {exact}")
                out.append({"day": day, "rows": n, "seed": seed, "off_mm": off, "on_mm": on, "rejected": len(found),
                            "exact": exact})
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
