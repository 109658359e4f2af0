"""The extrapolation guard in time: a warm-up drift diagnosed on a short recording, predicted hours later.

For each seed, a twin with planted geometric errors and a concealed warm-up growth of links p23 and p34 (time
constant 1800 s, ``calibration.diagnosis.synthetic.make_case``) is recorded on the synthetic cluster design with
samples ``--period`` seconds apart (2 s: a recording of about 670 s, a third of the time constant, which sees the curve's
slope and not its asymptote; 12 s: 67 min, over two time constants). ``diagnose`` (training data only) builds its
model; then it is evaluated on 300 random poses taken later, at times spread uniformly over ``--late`` (seconds
after the start), with the guard's hold in time on (the model as saved) and off (the same model with its region's
time range removed, which leaves the joint guard as it is). Printed per seed: whether a thermal drift was found,
its fitted time constant, and the later poses' position mean / max [mm] with and without the hold.

    python scripts/benchmarks/bench_time_guard.py [--seeds 0,1,2,3,4] [--period 2,12] [--magnitude 0.3] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))


def late_poses(design: Any, n: int, seed: int, late_s: tuple[float, float]) -> tuple[np.ndarray, dict[str, Any]]:
    """n random poses of the design's ranges, taken at times uniform over ``late_s`` [s] (the arm's temperature
    following them)."""
    from calibration.diagnosis.synthetic import heldout_design, temperature_c

    q, cols = heldout_design(design, n, seed)
    rng = np.random.default_rng(seed)
    cols["t"] = np.sort(rng.uniform(*late_s, n))
    cols["temp_c"] = temperature_c(cols["t"], rng)
    return q, cols


def run(seed: int, period_s: float, magnitude_mm: float, late_s: tuple[float, float]) -> dict[str, Any]:
    from calibration.diagnosis import diagnose
    from calibration.diagnosis.synthetic import Design, make_case, measure
    from calibration.evaluation.metrics import errors
    from calibration.physics import GravityModel
    from cell_config import load_cell

    spec = load_cell().robot("R1")
    nominal = spec.model()
    gravity = GravityModel.from_spec(spec.robot, nominal)
    design = Design(period_s=period_s)
    twin, fit, _ = make_case(nominal, gravity, {"thermal_drift": magnitude_mm}, seed, design)
    res = diagnose("R1", nominal, fit, heldout=None, gravity=gravity)
    q, cols = late_poses(design, 300, seed + 7, late_s)
    late = measure(twin, q, cols, design, np.random.default_rng(seed + 9), "late")
    row: dict[str, Any] = {"seed": seed, "period_s": period_s, "recording_s": float(fit.extra["t"].max()),
                           "found": list(res.model.info.get("effects_found", []))}
    drift = [e for e in res.model.effects if e.kind == "thermal_drift"]
    row["tau_s"] = drift[0].tau_s if drift else None
    unheld = res.model.with_region(res.model.region().without_context())  # the joint guard as it is
    for name, model in (("held", res.model), ("free", unheld)):
        e = errors(model, late).position_mm
        row[name] = {"mean_mm": float(e.mean()), "max_mm": float(e.max())}
    return row


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", default="0,1,2,3,4")
    ap.add_argument("--period", default="2,12", help="seconds between samples, one run per value")
    ap.add_argument("--magnitude", type=float, default=0.3, help="RMS tool displacement of the drift [mm]")
    ap.add_argument("--late", default="3600,14400", help="the later poses' time span [s] (default 1 h to 4 h)")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    late_s = tuple(float(x) for x in args.late.split(","))
    rows = []
    for period in (float(p) for p in args.period.split(",")):
        for seed in (int(s) for s in args.seeds.split(",")):
            r = run(seed, period, args.magnitude, late_s)  # type: ignore[arg-type]
            rows.append(r)
            tau = f"{r['tau_s']:.0f} s" if r["tau_s"] else "-"
            print(f"period {period:4g} s (recording {r['recording_s']:6.0f} s) seed {seed}: found "
                  f"{','.join(r['found']) or 'nothing'}, tau {tau}; later poses held "
                  f"{r['held']['mean_mm']:.3f}/{r['held']['max_mm']:.3f}, free "
                  f"{r['free']['mean_mm']:.3f}/{r['free']['max_mm']:.3f} mm", flush=True)
        these = [r for r in rows if r["period_s"] == period]
        print(f"period {period:g} s, median over seeds: held "
              f"{statistics.median(r['held']['mean_mm'] for r in these):.3f}/"
              f"{statistics.median(r['held']['max_mm'] for r in these):.3f}, free "
              f"{statistics.median(r['free']['mean_mm'] for r in these):.3f}/"
              f"{statistics.median(r['free']['max_mm'] for r in these):.3f} mm")
    if args.json:
        args.json.write_text(json.dumps({"rows": rows, "magnitude_mm": args.magnitude, "late_s": late_s}, indent=2)
                             + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
