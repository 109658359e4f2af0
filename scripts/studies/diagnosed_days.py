"""``diagnosed`` against ``nls1`` on every shared day's test recording, each fitted on that day's training only.

For each training recording of ``../shared/data/welding_motoman`` (the units of :mod:`scripts.benchmarks.bench_days`), fit
``nls1`` and ``diagnosed`` on it and test both on the day's test recording(s), which neither fit saw. Prints the
position error mean / max [mm] of each, the effects the diagnosis kept, how many test poses lie outside the
training range and by how much (the extrapolation guard's count), and ``diagnosed`` without its guard (the
model's training region removed) to show what the guard changes. The goal of issue 13: ``diagnosed`` no worse
than ``nls1`` on any day.

    PYTHONPATH=. python scripts/studies/diagnosed_days.py [--json FILE] [--days 0801,0725,...]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from calibration.data.recording import read_recording  # noqa: E402
from calibration.evaluation.metrics import errors  # noqa: E402
from calibration.models.guard import REGION_KEY, extrapolation  # noqa: E402
from cell_config import load_cell  # noqa: E402
from scripts.benchmarks.bench_days import DATA, UNITS, make_fitter, mean_max  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", help="write every figure to this JSON file")
    ap.add_argument("--data", type=Path, default=DATA, help=f"the welding_motoman folder (default {DATA})")
    ap.add_argument("--days", help="comma-separated unit names (default: all): " + ",".join(u.name for u in UNITS))
    args = ap.parse_args(argv)
    if not args.data.exists():
        print(f"shared recordings not found at {args.data}", file=sys.stderr)
        return 2
    chosen = [d.strip() for d in args.days.split(",")] if args.days else [u.name for u in UNITS]
    unknown = [d for d in chosen if d not in {u.name for u in UNITS}]
    if unknown:
        print(f"unknown day {unknown[0]!r}; valid: {', '.join(u.name for u in UNITS)}", file=sys.stderr)
        return 2
    robot = load_cell().robot("R1")
    limits = (robot.robot.lower_rad, robot.robot.upper_rad)
    rows = []
    print("| training → test | nls1 mean/max mm | diagnosed mean/max mm | no worse | diagnosed without guard | "
          "effects kept | test poses outside training range | max excess deg | guard acted (max shift mm) | fit s |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for unit in (u for u in UNITS if u.name in chosen):
        train = read_recording(args.data / "PH_grad_data" / unit.train, *limits)
        fitter = make_fitter(robot, train)
        t0 = time.perf_counter()
        nls1, _ = fitter.fit("nls1")
        diagnosed, _ = fitter.fit("diagnosed")
        seconds = time.perf_counter() - t0
        unguarded = replace(diagnosed, info={k: v for k, v in diagnosed.info.items() if k != REGION_KEY})
        for label, folder in unit.tests:
            test = read_recording(args.data / "kinematic_raw_data" / folder, *limits)
            a, b, c = (mean_max(errors(m, test).position_mm) for m in (nls1, diagnosed, unguarded))
            ex = extrapolation(diagnosed, test.q)
            row = {"train": unit.name, "test": label, "nls1": a, "diagnosed": b, "diagnosed_unguarded": c,
                   "no_worse": bool(b["mean"] <= a["mean"] and b["max"] <= a["max"]),
                   "effects": list(diagnosed.info.get("effects_found", [])), "extrapolation": ex,
                   "fit_seconds": seconds}
            rows.append(row)
            print(f"| {unit.name} → {label} | {a['mean']:.3f}/{a['max']:.3f} | {b['mean']:.3f}/{b['max']:.3f} | "
                  f"{'yes' if row['no_worse'] else 'NO'} | {c['mean']:.3f}/{c['max']:.3f} | "
                  f"{', '.join(row['effects']) or '-'} | {ex['outside_training_range']} of {ex['poses']} | "
                  f"{ex['max_excess_deg']:.1f} | {'yes' if ex['guard_acted'] else 'no'} "
                  f"({ex['guard_shift_mm_max']:.3f}) | {seconds:.0f} |", flush=True)
    n_ok = sum(r["no_worse"] for r in rows)
    print(f"\ndiagnosed no worse than nls1 (mean and max) on {n_ok} of {len(rows)} test recordings.")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1, default=float), encoding="utf-8")
    return 0 if n_ok == len(rows) else 1


if __name__ == "__main__":
    sys.exit(main())
