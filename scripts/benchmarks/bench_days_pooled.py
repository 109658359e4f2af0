"""Leave one day out: does an arm fitted on all the other days (one pair of frames each) move better to a new day?

For each day B with a test recording: one pi arm over every other training recording
(:func:`calibration.frames.multiday.fit_days`), rebased on the same 21 poses of B as ``bench_days.py``
(:func:`calibration.frames.rebase.rebase_auto`), tested on B's test recording(s); the ratio to B's same-day pi fit is the
issue's goal (<= 1.25).

    python scripts/benchmarks/bench_days_pooled.py [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from calibration.data.recording import read_recording  # noqa: E402
from calibration.evaluation.metrics import errors  # noqa: E402
from calibration.frames.multiday import fit_days  # noqa: E402
from calibration.frames.rebase import RebaseRefused, rebase_auto  # noqa: E402
from cell_config import load_cell  # noqa: E402
from scripts.benchmarks.bench_days import CLUSTER_SIZE, DATA, GOAL_RATIO, OPTIONS, UNITS, make_fitter, spread_clusters  # noqa: E402

EXTRA_TRAIN = ("0524", "test0524_R1")  # a training recording without a test recording: always in the pools


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", help="write every figure to this JSON file")
    args = parser.parse_args(argv)
    if not DATA.exists():
        print(f"shared recordings not found at {DATA}", file=sys.stderr)
        return 2
    start = time.perf_counter()
    robot = load_cell().robot("R1")
    limits = (robot.robot.lower_rad, robot.robot.upper_rad)
    names = [u.name for u in UNITS] + [EXTRA_TRAIN[0]]
    folders = {u.name: u.train for u in UNITS} | {EXTRA_TRAIN[0]: EXTRA_TRAIN[1]}
    train = {n: read_recording(DATA / "PH_grad_data" / folders[n], *limits) for n in names}
    tests = {lb: read_recording(DATA / "kinematic_raw_data" / f, *limits) for u in UNITS for lb, f in u.tests}
    rows = []
    for u in UNITS:
        b = u.name
        pool = [train[n] for n in names if n != b]
        joint = fit_days(robot.arm(), pool, options=OPTIONS)
        arm = joint.fitter.fit("pi")[0]
        poses = train[b].subset(np.isin(train[b].clusters(CLUSTER_SIZE), spread_clusters(train[b])))
        try:
            rebased, _, choice = rebase_auto(arm, poses)
        except RebaseRefused:  # no frame change confirmed on the held-out clusters: the pooled arm as is
            rebased, choice = arm, "refused"
        own = make_fitter(robot, train[b]).fit("pi")[0]
        for label, _ in u.tests:
            t = tests[label]
            same = float(np.mean(errors(own, t).position_mm))
            e = errors(rebased, t).position_mm
            rows.append({"tested_on": label, "pool": [n for n in names if n != b], "directions": choice,
                         "same_day_mean_mm": same, "pooled_rebased": {"mean": float(np.mean(e)), "max": float(e.max())},
                         "ratio": float(np.mean(e)) / same, "kinematics_changed": joint.kinematics_changed})
            print(f"{label}: pooled + rebase {np.mean(e):.3f}/{e.max():.3f} mm against same-day {same:.3f} "
                  f"(x{rows[-1]['ratio']:.2f}, {choice})", file=sys.stderr, flush=True)
    print(f"## Leave one day out: a pi arm over the other days, rebased on 21 poses (goal x{GOAL_RATIO})\n")
    print("| tested on | pooled + rebase mean/max [mm] | same-day pi mean [mm] | ratio | directions |")
    print("|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['tested_on']} | {r['pooled_rebased']['mean']:.3f}/{r['pooled_rebased']['max']:.3f} | "
              f"{r['same_day_mean_mm']:.3f} | {r['ratio']:.2f} | {r['directions']} |")
    ratios = np.array([r["ratio"] for r in rows])
    print(f"\n{int(np.sum(ratios <= GOAL_RATIO))} of {len(rows)} within x{GOAL_RATIO}; "
          f"median x{np.median(ratios):.2f}; {time.perf_counter() - start:.0f} s")
    if args.json:
        Path(args.json).write_text(json.dumps({"goal_ratio": GOAL_RATIO, "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
