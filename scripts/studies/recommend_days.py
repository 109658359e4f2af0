"""The recommendation and the robustness flags of ``compare --methods all`` on every R1 training recording.

For every R1 training recording of ``../shared/data/welding_motoman/PH_grad_data`` (no test recording is read):
fit every method ``compare --methods all`` fits (but ``cpa``, which needs sweeps, and ``diagnosed``, which has no
held-out figure and so is never a candidate), then choose the model as ``compare`` does
(:func:`app.workflows.compare.recommend_fitted`, clusters held out from training). Printed per recording: the
recommended and the best method, and the CDC methods whose fit carries a robustness warning. With ``--json`` every
candidate's held-out RMS and p-value too, so two runs (before / after a change to the fits) can be set side by side
with ``--against OLD.json``.

    python scripts/studies/recommend_days.py [--json FILE] [--days test0801_R1,...] [--against OLD.json]
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

from app.workflows.compare import recommend_fitted  # noqa: E402
from calibration.data.recording import read_recording  # noqa: E402
from calibration.method_names import CDC_METHODS, METHODS, NEURAL_METHODS  # noqa: E402
from calibration.methods.fitter import Fitter  # noqa: E402
from cell_config import load_cell  # noqa: E402
from scripts.benchmarks.bench_days import DATA  # noqa: E402
from scripts.studies.heldout_folds import DAYS

METHODS_RUN = tuple(m for m in METHODS if m not in ("cpa", "diagnosed"))


def day_row(robot, day: str) -> dict:
    train = read_recording(DATA / "PH_grad_data" / day, robot.robot.lower_rad, robot.robot.upper_rad)
    fitter = Fitter.for_arm(robot.arm(), train)
    t0 = time.perf_counter()
    fitter.prefetch(METHODS_RUN, held_out=True)
    order = [m for m in METHODS_RUN if m not in NEURAL_METHODS] + [m for m in METHODS_RUN if m in NEURAL_METHODS]
    models = {m: fitter.fit(m)[0] for m in order}
    rec = recommend_fitted(fitter, models)
    return {"day": day, "seconds": round(time.perf_counter() - t0, 1), "recommended": rec.method, "best": rec.best,
            "flagged": sorted(m for m, model in models.items() if m in CDC_METHODS and model.info.get("warning")),
            "candidates": rec.candidates, "not_candidates": sorted(rec.not_candidates),
            "heldout_check": {m: model.info["heldout"] for m, model in models.items() if m in CDC_METHODS},
            "heldout_errors_mm": {m: None if e is None else np.round(e, 6).tolist()
                                  for m, e in ((m, fitter.held_out_errors(m)) for m in models)}}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", type=Path)
    ap.add_argument("--days", default=",".join(DAYS))
    ap.add_argument("--against", type=Path, help="an earlier --json output to compare with")
    args = ap.parse_args(argv)
    robot = load_cell().robot("R1")
    old = {r["day"]: r for r in json.loads(args.against.read_text())} if args.against else {}
    rows, same = [], True
    for day in args.days.split(","):
        row = day_row(robot, day)
        rows.append(row)
        line = f"{day:22s} recommended {row['recommended']:10s} best {row['best']:10s} flagged {row['flagged']}"
        if day in old:
            o = old[day]
            agree = (o["recommended"], o["best"], o["flagged"]) == (row["recommended"], row["best"], row["flagged"])
            same &= agree
            line += " | SAME as before" if agree else (f" | BEFORE: recommended {o['recommended']} best {o['best']} "
                                                        f"flagged {o['flagged']}")
        print(line + f" ({row['seconds']} s)", flush=True)
        if args.json:  # after every day: a long run interrupted keeps what it has
            args.json.write_text(json.dumps(rows, indent=2) + "\n")
    if old:
        print("recommendation, best and flags the same on every day" if same else "SOME DAY DIFFERS")
    return 0


if __name__ == "__main__":
    sys.exit(main())
