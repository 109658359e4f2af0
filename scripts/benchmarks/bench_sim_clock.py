"""Benchmark the reproducible (stepped) simulated cell against the free-running one on the same session.

Collects one short R1 session (anchor grid ``--step`` deg, 5 validation poses) on a :class:`SimCell` over Zenoh,
alternating free-running and ``deterministic=True`` runs, and prints the wall time of each, the median ratio,
and whether the stepped runs measured identical samples (they must) while the free-running ones did not.

    python scripts/benchmarks/bench_sim_clock.py [--runs 2] [--step 30] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from app.collection.collect import (  # noqa: E402
    DEMO_COLLECT,
    collect_arm,
    export,  # noqa: E402
)
from app.collection.plans.session import PlanSpec, session_plan  # noqa: E402
from app.collection.runtime.sim import SimCell, SimCellOptions  # noqa: E402
from app.collection.safety import CellSafety  # noqa: E402
from cell_config import load_cell  # noqa: E402


def collect_once(deterministic: bool, step_deg: float, folder: Path) -> tuple[float, bytes]:
    """(wall seconds of the collection, the exported recording's bytes without its time column)."""
    cell = load_cell()
    safety = CellSafety(cell)
    with SimCell(cell, SimCellOptions(seed=0, deterministic=deterministic)) as sim:
        parked = {n: d.read_joints().q for n, d in sim.others("R1").items()}
        spec = PlanSpec(q2_step_deg=step_deg, q3_step_deg=step_deg, cpa=False, n_validation=5, seed=0)
        plan = session_plan("R1", safety, parked, spec, sim.drivers["R1"].read_joints().q)
        t0 = time.monotonic()
        collect_arm(sim, safety, "R1", plan, folder / "session", DEMO_COLLECT, progress=False,
                    clock=sim.clock.now)
        seconds = time.monotonic() - t0
    export(folder / "session", folder / "rec.csv")
    lines = (folder / "rec.csv").read_text().splitlines()
    t_col = lines[0].split(",").index("t")
    return seconds, "\n".join(",".join(v for i, v in enumerate(line.split(",")) if i != t_col)
                              for line in lines).encode()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=2, help="runs of each kind")
    parser.add_argument("--step", type=float, default=30.0, help="anchor grid step [deg]")
    parser.add_argument("--json", help="write the figures as JSON")
    args = parser.parse_args()
    times: dict[bool, list[float]] = {False: [], True: []}
    samples: dict[bool, set[bytes]] = {False: set(), True: set()}
    for _ in range(args.runs):
        for det in (False, True):
            with tempfile.TemporaryDirectory() as tmp:
                seconds, rec = collect_once(det, args.step, Path(tmp))
            times[det].append(seconds)
            samples[det].add(rec)
            print(f"{'stepped' if det else 'free-running':>12}: {seconds:.2f} s", flush=True)
    ratio = statistics.median(times[True]) / statistics.median(times[False])
    out = {"free_running_s": times[False], "stepped_s": times[True], "ratio_stepped_to_free": ratio,
           "stepped_runs_identical": len(samples[True]) == 1, "free_running_runs_identical": len(samples[False]) == 1}
    print(f"stepped / free-running wall time: x{ratio:.2f}; stepped runs identical: {out['stepped_runs_identical']}; "
          f"free-running runs identical: {out['free_running_runs_identical']}")
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
