"""Should the pi fit damp the tool marker's registration toward nominal? Both ways, on twins and on training data.

``FitOptions.pi_registration_free`` says which parts of the marker's registration on the flange pi's Tikhonov filter
toward nominal leaves free: ``none`` (damped with the arm's own parameters, the fit before), ``rotation`` (the
tool-marker rotation, the default) or ``all`` (the flange-point shift too). Printed, for the three:

- **twins** (``--twins``): the synthetic arms of ``scripts/benchmarks/bench_frames.py`` (planted geometry and joint
  compliance; training on clusters with joints 1, 4, 5, 6 within 3 deg, held-out poses that move every joint
  widely), the tool marker registered off by each ``--errors`` size (mm/deg, within what the frame check lets
  through, and 18/0.5, which it catches), fitted as is (no frame check): nls1 and pi both ways, held-out position
  mean / max [mm], on both arms;
- **training days** (``--days``): on every R1 training recording of ``../shared/data/welding_motoman/PH_grad_data``
  (no test recording is read), pi both ways scored on clusters held out from training (the 5 folds of the
  recommendation: RMS [mm], and the paired standard error of the difference over clusters), and on the three
  extrapolation folds of ``scripts/studies/extrapolation_folds.py`` (the q1/q4-q6 steps, the q2 edges, the q3 edges held
  out; mean / max [mm]).

    PYTHONPATH=. python scripts/studies/pi_registration.py [--json FILE] [--no-twins] [--no-days] [--days test0801_R1,...]
        [--seeds 0,1,2,3,4] [--errors 0/0,1.5/0.3,3/0.1,18/0.5]
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from calibration.data.folds import EDGE_JOINTS, edge_mask, step_mask  # noqa: E402
from calibration.data.recording import read_recording  # noqa: E402
from calibration.evaluation.metrics import errors  # noqa: E402
from calibration.methods.cdc import cluster_anchors  # noqa: E402
from calibration.methods.fitter import Fitter  # noqa: E402
from calibration.methods.options import FitOptions  # noqa: E402
from calibration.methods.recommend import cluster_rms  # noqa: E402
from calibration.methods.shared import SharedCache  # noqa: E402
from cell_config import load_cell  # noqa: E402
from scripts.benchmarks.bench_days import (
    DATA,  # noqa: E402
    mean_max,  # noqa: E402
)
from scripts.benchmarks.bench_frames import fitter_on, tool_error_case_of  # noqa: E402
from scripts.studies.heldout_folds import days_parser

#: The ways pi is fitted: label -> the FitOptions fields that differ from the defaults.
WAYS: dict[str, dict[str, Any]] = {"damped": {"pi_registration_free": "none"},
                                   "rotation free": {"pi_registration_free": "rotation"},
                                   "free": {"pi_registration_free": "all"}}


def tool_case(arm: str, seed: int, shift_mm: float, angle_deg: float) -> tuple[Any, Any, Any]:
    """(cell entry, training, held-out recording) of a twin whose tool marker is off by ``shift_mm``/``angle_deg``."""
    return tool_error_case_of(shift_mm, angle_deg, seed, 3.0, arm)


def twins(seeds: list[int], sizes: list[tuple[float, float]], ways: dict[str, dict[str, Any]] = WAYS,
          case: Callable[[str, int, float, float], tuple[Any, Any, Any]] = tool_case,
          keys: tuple[str, str] = ("tool_mm", "tool_deg")) -> list[dict[str, Any]]:
    """Per arm, seed and error size of ``case``: nls1 and pi fitted each of ``ways``, held-out mean / max [mm]."""
    rows = []
    for arm in ("R1", "R2"):
        for seed in seeds:
            for shift_mm, angle_deg in sizes:
                robot, train, test = case(arm, seed, shift_mm, angle_deg)
                row: dict[str, Any] = {"robot": arm, "seed": seed, keys[0]: shift_mm, keys[1]: angle_deg}
                base = fitter_on(robot, train)
                row["nls1"] = mean_max(errors(base.fit("nls1")[0], test).position_mm)
                for way, fields in ways.items():
                    fitter = replace(base, options=replace(base.options, **fields), _cache=SharedCache())
                    row[f"pi {way}"] = mean_max(errors(fitter.fit("pi")[0], test).position_mm)
                rows.append(row)
                print(f"| {arm} | {seed} | {shift_mm:g} / {angle_deg:g} | "
                      + " | ".join(f"{row[k]['mean']:.3f}/{row[k]['max']:.3f}" for k in ["nls1"] + [f"pi {w}" for w in ways])
                      + " |", flush=True)
    return rows


def days(names: list[str], ways: dict[str, dict[str, Any]] = WAYS) -> list[dict[str, Any]]:
    """Per R1 training recording: pi fitted each of ``ways``, on held-out clusters and the extrapolation folds."""
    robot = load_cell().robot("R1")
    rows = []
    folds = ("steps", "q2 edges", "q3 edges")
    for day in names:
        t0 = time.process_time()
        rec = read_recording(DATA / "PH_grad_data" / day, robot.robot.lower_rad, robot.robot.upper_rad)
        groups, _ = cluster_anchors(rec)
        row: dict[str, Any] = {"day": day}
        per_cluster = {}
        for way, fields in ways.items():
            options = FitOptions(**fields)
            e = Fitter.for_arm(robot.arm(), rec, options=options).held_out_errors("pi")
            per_cluster[way] = cluster_rms(e, groups)
            row[f"heldout {way}"] = round(float(np.sqrt(np.mean(e ** 2))), 4)
            for fold, held in [("steps", step_mask(rec))] + [(f"q{j + 1} edges", edge_mask(rec, j))
                                                             for j in EDGE_JOINTS]:
                model, _ = Fitter.for_arm(robot.arm(), rec.subset(~held), options=options).fit("pi")
                row[f"{fold} {way}"] = mean_max(errors(model, rec.subset(held)).position_mm)
        first = next(iter(ways))
        for way in list(ways)[1:]:
            d = per_cluster[way] - per_cluster[first]
            row[f"heldout {way} diff se"] = round(float(d.std(ddof=1) / np.sqrt(len(d))), 4)
        row["cpu_s"] = round(time.process_time() - t0, 1)
        rows.append(row)
        print(f"| {day} | " + " / ".join(f"{row[f'heldout {w}']:.4f}" for w in ways)
              + " (paired se " + ", ".join(f"{row[f'heldout {w} diff se']:.4f}" for w in list(ways)[1:]) + ") | "
              + " | ".join(" / ".join(f"{row[f'{f} {w}']['mean']:.3f}/{row[f'{f} {w}']['max']:.3f}" for w in ways)
                           for f in folds) + " |", flush=True)
    return rows


def run(argv: list[str] | None, doc: str, ways: dict[str, dict[str, Any]], default_errors: str, what: str,
        case: Callable[[str, int, float, float], tuple[Any, Any, Any]] = tool_case,
        keys: tuple[str, str] = ("tool_mm", "tool_deg")) -> int:
    """The command line of this script and of its siblings: twins with ``what`` off by each ``--errors`` size
    (``case``), and the training days, for each of ``ways``."""
    ap = days_parser(doc)
    ap.add_argument("--no-twins", action="store_true")
    ap.add_argument("--no-days", action="store_true")
    ap.add_argument("--seeds", default="0,1,2,3,4")
    ap.add_argument("--errors", default=default_errors, help=f"{what} errors mm/deg, comma-separated")
    args = ap.parse_args(argv)
    out: dict[str, Any] = {}
    if not args.no_twins:
        sizes = [tuple(float(v) for v in e.split("/")) for e in args.errors.split(",")]
        print("twins, fitted as is (no frame check); held-out position mean/max mm\n")
        print(f"| arm | seed | {what} off mm / deg | nls1 | " + " | ".join(f"pi {w}" for w in ways) + " |\n|---"
              + "|---" * (3 + len(ways)) + "|")
        out["twins"] = twins([int(s) for s in args.seeds.split(",")], sizes, ways, case, keys)  # type: ignore[arg-type]
    if not args.no_days:
        print("\ntraining days: pi " + " / ".join(ways) + "; held-out clusters RMS mm; extrapolation folds mean/max mm\n")
        print("| training day | held-out clusters | steps | q2 edges | q3 edges |\n|---|---|---|---|---|")
        out["days"] = days(args.days.split(","), ways)
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1) + "\n", encoding="utf-8")
    return 0


def main(argv: list[str] | None = None) -> int:
    return run(argv, __doc__, WAYS, "0/0,1.5/0.3,3/0.1,18/0.5", "tool marker")


if __name__ == "__main__":
    sys.exit(main())
