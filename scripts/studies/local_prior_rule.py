"""Which local prior each choice rule takes, on training data and simulated R2 twins only (issue 31 part 4).

The local prior of the CDC methods built on pi is chosen on clusters held out from the training recording
(:meth:`calibration.methods.fitter.Fitter._choose_local_prior`: the ``linear`` interpolator, priors whose corrections
over the workspace stay within the limit, then a rule over the held-out RMS). This prints, per training recording
of ``../shared/data/welding_motoman/PH_grad_data`` (no test recording is read) and per simulated R2 day
(:func:`drivers.sim.cdc_twin.simulated_day`, seeds drawn at run time unless given; its training grid only), every
prior's held-out RMS, its own standard error, the paired standard error of its difference to the lowest, the
workspace ratio, and the prior each rule of :data:`calibration.methods.heldout.CHOICE_RULES` takes from the same
scores. The test errors that follow from a choice are ``scripts/benchmarks/bench_days.py``'s.

    python scripts/studies/local_prior_rule.py [--days test0801_R1,...|none] [--r2-seeds S1,S2|N] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from app.workflows.fit import fitter_for  # noqa: E402
from calibration.data.recording import read_recording  # noqa: E402
from calibration.methods import heldout as robust  # noqa: E402
from calibration.methods import workspace  # noqa: E402
from cell_config import load_cell  # noqa: E402
from drivers.sim.cdc_twin import PAPER_SIZE, simulated_day  # noqa: E402
from scripts.benchmarks.bench_days import DATA  # noqa: E402

#: The R1 training recordings bench_days judges (its UNITS), in date order.
DAYS = ("test0516_R1", "test0613_R1", "test0620_R1", "test0627_beforecalib", "test0627_aftercalib", "test0725_R1",
        "test0801_R1")


def scores_of(fitter: Any) -> dict[str, Any]:
    """The local-prior scores of one Fitter (pi reference) and each rule's choice from them."""
    fitter.local_prior("pi")
    grid, scores, ratios = fitter._cache["local_prior_scores"]["pi"]
    ok = [i for i, r in enumerate(ratios) if r <= workspace.WORKSPACE_RATIO_LIMIT]
    best = min(ok, key=lambda i: scores[i].rms_mm) if ok else None
    chosen = {name: (grid[ok[rule(tuple(grid[i] for i in ok), [scores[i] for i in ok])]] if ok else max(grid))
              for name, rule in robust.CHOICE_RULES.items()}
    return {"grid": list(grid), "rms_mm": [s.rms_mm for s in scores], "se_mm": [s.se_rms_mm for s in scores],
            "paired_se_to_best_mm": [None if best is None else robust.paired_se_mm(s, scores[best]) for s in scores],
            "workspace_ratio": ratios, "chosen": chosen}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--days", default=",".join(DAYS), help="training recordings, comma-separated, or 'none'")
    parser.add_argument("--r2-seeds", default="3", help="simulated R2 seeds (comma-separated) or one count N: N "
                                                         "seeds drawn at run time (default 3)")
    parser.add_argument("--json", help="write the figures to this JSON file")
    args = parser.parse_args(argv)
    days = [] if args.days == "none" else args.days.split(",")
    parts = [int(s) for s in args.r2_seeds.split(",") if s.strip()]
    seeds = parts if "," in args.r2_seeds else \
        [int(s) for s in np.random.default_rng().integers(0, 2 ** 31, parts[0])] if parts[0] > 0 else []
    out: dict[str, Any] = {}
    cell = load_cell()
    r1 = cell.robot("R1")
    for day in days:
        path = DATA / "PH_grad_data" / day
        if not path.exists():
            print(f"training recording not found: {path}", file=sys.stderr)
            return 2
        out[day] = scores_of(fitter_for(r1, read_recording(path, r1.robot.lower_rad, r1.robot.upper_rad)))
        print(f"{day}: {out[day]['chosen']}", file=sys.stderr, flush=True)
    r2 = cell.robot("R2")
    for seed in seeds:
        sim = simulated_day(r2.robot, r2.tool, seed, PAPER_SIZE, label="simulated R2")
        out[f"R2 sim {seed}"] = scores_of(fitter_for(r2, sim.train))
        print(f"R2 sim {seed}: {out[f'R2 sim {seed}']['chosen']}", file=sys.stderr, flush=True)
    print("| data | prior: held-out RMS ± own SE (paired SE to best) [workspace ratio] | " +
          " | ".join(robust.CHOICE_RULES) + " |")
    print("|---|---|" + "---|" * len(robust.CHOICE_RULES))
    for name, r in out.items():
        cells = "; ".join(f"{g:g}: {m:.4f} ± {s:.4f} ({'–' if p is None else f'{p:.4f}'}) [{w:.2f}]" for g, m, s, p, w
                          in zip(r["grid"], r["rms_mm"], r["se_mm"], r["paired_se_to_best_mm"], r["workspace_ratio"]))
        print(f"| {name} | {cells} | " + " | ".join(f"{r['chosen'][k]:g}" for k in robust.CHOICE_RULES) + " |")
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
