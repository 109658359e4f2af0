"""Should the pi fit damp a rigid motion of the whole arm (a base-frame error) toward nominal? Both ways.

``FitOptions.pi_base_free``: pi's Tikhonov filter toward nominal either damps every geometric parameter as it is
(``damped``), or damps what is left of them after their best rigid motion of the arm (``base free``,
:func:`calibration.methods.base_free_prior`; :meth:`ExtendedKinematics.base_motion` gives the 6 directions), so a
mocap-to-base registration error costs the fit nothing. Printed, for both:

- **twins** (``--twins``): the synthetic arms of ``scripts/bench_frames.py`` (planted geometry and joint
  compliance; training on clusters with joints 1, 4, 5, 6 within 3 deg, held-out poses that move every joint
  widely), with the base frame off by each ``--errors`` size (mm/deg: within what the frame check lets through),
  fitted as is: nls1 and pi both ways, held-out position mean / max [mm], on both arms;
- **training days** (``--days``): on every R1 training recording of ``../shared/data/welding_motoman/PH_grad_data``
  (no test recording is read), pi both ways scored on clusters held out from training (the 5 folds of the
  recommendation: RMS [mm], and the paired standard error of the difference over clusters), and on the three
  extrapolation folds of ``scripts/extrapolation_folds.py`` (the q1/q4-q6 steps, the q2 edges, the q3 edges held
  out; mean / max [mm]).

    PYTHONPATH=. python scripts/pi_base_frame.py [--json FILE] [--no-twins] [--no-days] [--days test0801_R1,...]
        [--seeds 0,1,2,3,4] [--errors 0/0,1.5/0.1,3/0.2]
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.analysis.fitting import fitter_for  # noqa: E402
from calibration import so3  # noqa: E402
from calibration.cdc import cluster_anchors  # noqa: E402
from calibration.frames import put_in  # noqa: E402
from calibration.methods import FitOptions  # noqa: E402
from calibration.metrics import errors  # noqa: E402
from calibration.models.rebased import make_T  # noqa: E402
from calibration.recording import read_recording  # noqa: E402
from calibration.selection import cluster_rms  # noqa: E402
from cell_config import load_cell  # noqa: E402
from scripts.bench_days import mean_max  # noqa: E402
from scripts.bench_frames import fitter_on, tool_error_case_of  # noqa: E402
from scripts.extrapolation_folds import EDGE_JOINTS, edge_mask, step_mask  # noqa: E402
from scripts.heldout_folds import DATA, days_parser  # noqa: E402

WAYS = {"damped": False, "base free": True}
#: The planted base error's rotation axis and shift direction (any direction not along a joint axis).
ERROR_AXIS = np.array([0.6, -0.8, 0.0])
ERROR_SHIFT = np.array([0.48, 0.36, -0.8])


def base_error_case(arm: str, seed: int, shift_mm: float, angle_deg: float) -> tuple[Any, Any, Any]:
    """(cell entry, training, held-out recording) of a twin of :func:`tool_error_case_of` (no marker error) whose
    base frame is off by ``shift_mm`` and ``angle_deg``."""
    robot, train, test = tool_error_case_of(0.0, 0.0, seed, 3.0, arm)
    T_base = make_T(so3.exp(np.radians(angle_deg) * ERROR_AXIS / np.linalg.norm(ERROR_AXIS)),
                    shift_mm * ERROR_SHIFT / np.linalg.norm(ERROR_SHIFT))
    return robot, put_in(train, T_base, np.eye(4)), put_in(test, T_base, np.eye(4))


def twins(seeds: list[int], sizes: list[tuple[float, float]]) -> list[dict[str, Any]]:
    rows = []
    for arm in ("R1", "R2"):
        for seed in seeds:
            for shift_mm, angle_deg in sizes:
                robot, train, test = base_error_case(arm, seed, shift_mm, angle_deg)
                row: dict[str, Any] = {"robot": arm, "seed": seed, "base_mm": shift_mm, "base_deg": angle_deg}
                fitter = fitter_on(robot, train)
                row["nls1"] = mean_max(errors(fitter.fit("nls1")[0], test).position_mm)
                for way, free in WAYS.items():
                    f = replace(fitter, options=replace(fitter.options, pi_base_free=free), _cache={})
                    row[f"pi {way}"] = mean_max(errors(f.fit("pi")[0], test).position_mm)
                rows.append(row)
                print(f"| {arm} | {seed} | {shift_mm:g} / {angle_deg:g} | "
                      + " | ".join(f"{row[k]['mean']:.3f}/{row[k]['max']:.3f}" for k in ["nls1"] + [f"pi {w}" for w in WAYS])
                      + " |", flush=True)
    return rows


def days(names: list[str]) -> list[dict[str, Any]]:
    robot = load_cell().robot("R1")
    rows = []
    folds = ("steps", "q2 edges", "q3 edges")
    for day in names:
        t0 = time.process_time()
        rec = read_recording(DATA / "PH_grad_data" / day, robot.robot.lower_rad, robot.robot.upper_rad)
        groups, _ = cluster_anchors(rec)
        row: dict[str, Any] = {"day": day}
        per_cluster = {}
        for way, free in WAYS.items():
            options = FitOptions(pi_base_free=free)
            e = fitter_for(robot, rec, options=options).held_out_errors("pi")
            per_cluster[way] = cluster_rms(e, groups)
            row[f"heldout {way}"] = round(float(np.sqrt(np.mean(e ** 2))), 4)
            for fold, held in [("steps", step_mask(rec))] + [(f"q{j + 1} edges", edge_mask(rec, j))
                                                             for j in EDGE_JOINTS]:
                model, _ = fitter_for(robot, rec.subset(~held), options=options).fit("pi")
                row[f"{fold} {way}"] = mean_max(errors(model, rec.subset(held)).position_mm)
        d = per_cluster["base free"] - per_cluster["damped"]
        row["heldout diff se"] = round(float(d.std(ddof=1) / np.sqrt(len(d))), 4)
        row["cpu_s"] = round(time.process_time() - t0, 1)
        rows.append(row)
        print(f"| {day} | " + " / ".join(f"{row[f'heldout {w}']:.4f}" for w in WAYS)
              + f" (paired se {row['heldout diff se']:.4f}) | "
              + " | ".join(" / ".join(f"{row[f'{f} {w}']['mean']:.3f}/{row[f'{f} {w}']['max']:.3f}" for w in WAYS)
                           for f in folds) + " |", flush=True)
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = days_parser(__doc__)
    ap.add_argument("--no-twins", action="store_true")
    ap.add_argument("--no-days", action="store_true")
    ap.add_argument("--seeds", default="0,1,2,3,4")
    ap.add_argument("--errors", default="0/0,1.5/0.1,3/0.2", help="base-frame errors mm/deg, comma-separated")
    args = ap.parse_args(argv)
    out: dict[str, Any] = {}
    if not args.no_twins:
        sizes = [tuple(float(v) for v in e.split("/")) for e in args.errors.split(",")]
        print("twins, fitted as is (no frame check); held-out position mean/max mm\n")
        print("| arm | seed | base frame off mm / deg | nls1 | " + " | ".join(f"pi {w}" for w in WAYS) + " |\n|---"
              + "|---" * (3 + len(WAYS)) + "|")
        out["twins"] = twins([int(s) for s in args.seeds.split(",")], sizes)  # type: ignore[arg-type]
    if not args.no_days:
        print("\ntraining days: pi " + " / ".join(WAYS) + "; held-out clusters RMS mm; extrapolation folds mean/max mm\n")
        print("| training day | held-out clusters | steps | q2 edges | q3 edges |\n|---|---|---|---|---|")
        out["days"] = days(args.days.split(","))
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
