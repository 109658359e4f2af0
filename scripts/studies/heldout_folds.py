"""How many of the 5 held-out folds the neural kinds' robustness check needs, on training recordings only.

For every R1 training recording of ``../shared/data/welding_motoman/PH_grad_data`` (no test recording is read):
fit the local cluster fits as ``compare`` does, train ``nn`` and ``ae`` on each of the 5 folds' training
clusters (the check of :mod:`calibration.methods.heldout`) and score the held-out poses of the first 1..5 folds. Printed
per recording and kind: the held-out / reference RMS ratio over all 5 folds and over the first k, and whether
the ratio crosses ``robust.HELDOUT_RATIO_LIMIT`` (the flag) either way.

    python scripts/studies/heldout_folds.py [--json FILE] [--days test0801_R1,...]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from calibration import workers
from calibration.data.recording import read_recording  # noqa: E402
from calibration.interpolation import make_interpolator  # noqa: E402
from calibration.methods import heldout as robust  # noqa: E402
from calibration.methods.cdc import cluster_anchors
from calibration.methods.fitter import Fitter  # noqa: E402
from calibration.models.cdc import CDC_INPUTS  # noqa: E402
from cell_config import load_cell  # noqa: E402
from scripts.benchmarks.bench_days import DATA  # noqa: E402

#: Every R1 training recording of the shared data (PH_grad_data), in date order.
DAYS = ("test0516_R1", "test0524_R1", "test0613_R1", "test0620_R1", "test0627_beforecalib", "test0627_aftercalib",
        "test0725_R1", "test0801_R1")


def days_parser(doc: str | None) -> argparse.ArgumentParser:
    """The day scripts' options: ``--json FILE`` and ``--days`` (comma-separated R1 training recordings)."""
    ap = argparse.ArgumentParser(description=(doc or "").split("\n\n")[0])
    ap.add_argument("--json", type=Path)
    ap.add_argument("--days", default=",".join(DAYS))
    return ap


def run_days(argv: list[str] | None, doc: str | None, row: Callable[[Any, str], dict],
             show: Callable[[str, dict], None]) -> int:
    """A day script's main: ``row(robot, day)`` for every day asked for, ``show(day, row)`` as each comes, all rows
    to ``--json``."""
    args = days_parser(doc).parse_args(argv)
    robot = load_cell().robot("R1")
    rows = []
    for day in args.days.split(","):
        rows.append(row(robot, day))
        show(day, rows[-1])
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + "\n")
    return 0


def main(argv: list[str] | None = None) -> int:
    args = days_parser(__doc__).parse_args(argv)
    robot = load_cell().robot("R1")
    rows = []
    for day in args.days.split(","):
        train = read_recording(DATA / "PH_grad_data" / day, robot.robot.lower_rad, robot.robot.upper_rad)
        fitter = Fitter.for_arm(robot.arm(), train)
        local, pi = fitter.local_fits(), fitter.physics_informed()
        groups, _ = cluster_anchors(train, fitter.options.cluster_size)
        for kind in ("nn", "ae"):
            t0 = time.perf_counter()
            check = robust.HeldOutCheck(lambda: make_interpolator(kind, random_state=fitter.options.seed),
                                        pi.kinematics, pi.theta, local.anchors, local.x, groups, train, CDC_INPUTS,
                                        seed=fitter.options.seed, workers=workers.default_workers(robust.N_FOLDS))
            preds = check._predictions()
            by_k = {k: check.figures(preds, k) for k in range(1, robust.N_FOLDS + 1)}
            full = by_k[robust.N_FOLDS]
            row = {"day": day, "kind": kind, "seconds": round(time.perf_counter() - t0, 1),
                   "ratio": {k: round(h.ratio, 4) for k, h in by_k.items()},
                   "rms_mm": {k: round(h.rms_mm, 4) for k, h in by_k.items()},
                   "se_mm": {k: round(h.se_rms_mm, 4) for k, h in by_k.items()},
                   "flag": {k: h.ratio > robust.HELDOUT_RATIO_LIMIT for k, h in by_k.items()}}
            rows.append(row)
            print(f"{day:22s} {kind:3s} ratio 5 folds {full.ratio:.3f} | first k: "
                  + " ".join(f"{k}:{h.ratio:.3f}" for k, h in by_k.items())
                  + " | flag same as 5 folds for k=" + ",".join(str(k) for k, h in by_k.items()
                                                           if (h.ratio > robust.HELDOUT_RATIO_LIMIT)
                                                           == (full.ratio > robust.HELDOUT_RATIO_LIMIT)),
                  flush=True)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
