"""Robustness of every interpolating method on every shared day (training of day d -> test of day d).

Prints, per day, test position error mean / max [mm] for nominal, nls1 (references) and the CDC methods,
with each method's ``info["warning"]`` when it has one, and whether the issue-10 goal holds: no method's max
beyond 1.5 x nls1's max and beyond 2 x nominal's max. Builds the Fitter with ``Fitter.for_arm``
(nominal with the tool, link masses, joint limits); imports ``calibration`` and ``cell_config`` only.

    python scripts/benchmarks/bench_robust.py [--days 0801 0613] [--methods nn ae] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from calibration.data.recording import read_recording  # noqa: E402
from calibration.evaluation.metrics import errors  # noqa: E402
from calibration.methods.fitter import Fitter
from calibration.methods.options import FitOptions  # noqa: E402
from cell_config import load_cell  # noqa: E402

DATA = ROOT.parent.parent / "shared" / "data" / "welding_motoman"
if not DATA.exists():
    DATA = Path("/work/shared/data/welding_motoman")
#: day -> (training folder, test folder), each day's own test recording.
DAYS = {
    "0516": ("test0516_R1", "test0516_R1"),
    "0613": ("test0613_R1", "test0613"),
    "0620b": ("test0620_R1", "test0620_beforecalib"),
    "0620a": ("test0620_R1", "test0620_aftercalib"),
    "0627b": ("test0627_beforecalib", "test0627_beforecalib"),
    "0627a": ("test0627_aftercalib", "test0627_aftercalib"),
    "0725": ("test0725_R1", "test0725_R1"),
    "0801": ("test0801_R1", "test0801_R1"),
}
REFERENCES = ("nominal", "nls1")
METHODS = tuple(f"pi+{k}" for k in ("linear", "cubic", "rbf", "fbf13", "fbf7", "nn", "ae"))  # built on pi, as measured


def run_day(robot, day: str, methods: tuple[str, ...]) -> dict:
    lo, hi = robot.robot.lower_rad, robot.robot.upper_rad
    train_dir, test_dir = DAYS[day]
    train = read_recording(DATA / "PH_grad_data" / train_dir, lo, hi)
    test = read_recording(DATA / "kinematic_raw_data" / test_dir, lo, hi)
    fitter = Fitter.for_arm(robot.arm(), train, options=FitOptions(reject_gross_rows=False))  # every row, as always
    rows = {}
    for method in REFERENCES + methods:
        t0 = time.perf_counter()
        model, _ = fitter.fit(method)
        e = errors(model, test).position_mm
        warning = model.info.get("warning") if method not in REFERENCES else None
        rows[method] = {"mean": float(e.mean()), "max": float(e.max()), "seconds": time.perf_counter() - t0,
                        "warning": warning, "heldout": model.info.get("heldout"),
                        "probe_range_excess": model.info.get("probe_range_excess")}
        if "local_prior" in model.info:
            rows["local_prior"] = model.info["local_prior"]
    limit = min(1.5 * rows["nls1"]["max"], 2.0 * rows["nominal"]["max"])
    for method in methods:
        rows[method]["goal"] = rows[method]["max"] <= max(1.5 * rows["nls1"]["max"], 2.0 * rows["nominal"]["max"])
        rows[method]["goal_strict"] = rows[method]["max"] <= limit
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--days", nargs="*", default=list(DAYS), choices=list(DAYS))
    parser.add_argument("--methods", nargs="*", default=list(METHODS), choices=list(METHODS))
    parser.add_argument("--json")
    args = parser.parse_args()
    logging.basicConfig(level=logging.ERROR)
    if not DATA.exists():
        sys.exit(f"shared data absent: {DATA}")
    robot = load_cell().robot("R1")
    methods = tuple(args.methods)
    result = {}
    cols = REFERENCES + methods
    print("| day | " + " | ".join(cols) + " |")
    print("|---|" + "---|" * len(cols))
    warnings, priors = [], []
    for day in args.days:
        rows = run_day(robot, day, methods)
        result[day] = rows
        if "local_prior" in rows:
            priors.append(f"{day}: {rows['local_prior']}")
        cells = []
        for m in cols:
            mark = "" if m in REFERENCES or rows[m]["goal_strict"] else (" ✗" if not rows[m]["goal"] else " (✗)")
            mark += " w" if rows[m]["warning"] else ""
            cells.append(f"{rows[m]['mean']:.3f}/{rows[m]['max']:.3f}{mark}")
        print(f"| {day} | " + " | ".join(cells) + " |", flush=True)
        warnings += [f"{day} {m}: {rows[m]['warning']}" for m in methods if rows[m]["warning"]]
    print("\nmean/max mm on the day's own test recording. ✗: max > 1.5 x nls1 max and > 2 x nominal max; "
          "(✗): only one of the two; w: the model carries a warning")
    for w in warnings:
        print("warning:", w)
    for p in priors:
        print("local prior", p)
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
