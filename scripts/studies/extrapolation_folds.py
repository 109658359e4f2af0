"""``diagnosed`` against ``nls1`` where they must extrapolate, on the shared days' training recordings only.

For every R1 training recording of ``../shared/data/welding_motoman/PH_grad_data`` (no test recording is read):
the clusters whose anchors lie at the edges of the training range of joint 2 or joint 3 (the lowest and highest
``EDGE_SHARE`` of the anchors), or the samples that step joints 1, 4, 5 or 6 away from their anchor, are held out,
``nls1``, ``pi`` and ``diagnosed`` are fitted on the others, and each is scored on the held-out samples (position
error mean / max [mm]). ``diagnosed`` is also scored with its guard changed: off, the old fixed 2 deg margin, held
hard at the edge, every effect held in every joint (the rule before ``by_effect``), and ``by_effect``; that is how
:func:`calibration.models.guard.data_margin_rad` and the rule ``by_effect`` were chosen. A ``pi`` model (the ``pi``
fit, and ``diagnosed`` when the diagnosis saved one) is also scored with its structural deflection, or its
deflection and its compliance, held in q2 and q3 at the edge of the training range: why a ``pi`` model has no
guard. Unlike the held-out-cluster check inside a diagnosis (set-aside clusters spread over the range:
interpolation), here a model must extrapolate, as it does on a test recording that leaves the training band.

    PYTHONPATH=. python scripts/studies/extrapolation_folds.py [--json FILE] [--days test0801_R1,...] [--save DIR] [--load DIR]

``--save DIR`` writes each fold's fitted models; ``--load DIR`` scores those files instead of fitting again (the
guard acts only when a fitted model is evaluated, never in its fit, so a guard rule can be scored on the same fits).
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from calibration.data.folds import EDGE_JOINTS, edge_mask, step_mask  # noqa: E402
from calibration.data.recording import Recording, read_recording  # noqa: E402
from calibration.diagnosis import StructuralDeflection  # noqa: E402
from calibration.evaluation.metrics import errors  # noqa: E402
from calibration.kinematics.poe import pose_error  # noqa: E402
from calibration.models import load_model, save_model  # noqa: E402
from calibration.models.guard import (
    DEFAULT_MARGIN_RAD,
    MIN_MARGIN_RAD,
    REGION_KEY,
    RULE_BY_EFFECT,
    RULE_EVERY_JOINT,
    Region,  # noqa: E402
)
from cell_config import load_cell  # noqa: E402
from scripts.benchmarks.bench_days import DATA, cell, make_fitter, mean_max  # noqa: E402
from scripts.studies.heldout_folds import days_parser  # noqa: E402

#: The guard variants each fold also scores ``diagnosed`` with (the fitted model, its training region changed).
VARIANTS = ("unguarded", "fixed 2 deg margin", "held hard at the edge", "every effect in every joint",
            "by effect")
#: The ``pi`` kind's terms held in q2 and q3 at the edge of the training range (0-based joints held, per term).
_Q2Q3 = StructuralDeflection().fitted_joints(6)  # the deflection's own declaration: q2, q3
PI_VARIANTS = {"deflection held": {"q_deflection": _Q2Q3},
               "compliance and deflection held": {"q_compliance": _Q2Q3, "q_deflection": _Q2Q3}}


def guard_variants(model: Any) -> dict[str, Any]:
    """``model`` without its guard, with the old fixed 2 deg clamp margin, clamped hard at the edge, with every
    effect held in every joint (the rule of regions saved before ``by_effect``) and with each effect held in its
    fitted joints the data saw narrowly (``by_effect``, the rule of a fit now; the column to read when ``--load``
    scores models saved before it) (a model without a guard of its joint effects, e.g. a ``pi`` model: none)."""
    region = model.region()
    if region is None or not getattr(model, "effects", ()):
        return {}
    with_region = lambda r: replace(model, info={**model.info, REGION_KEY: r.to_dict()})  # noqa: E731
    lo, hi = region.lower_rad, region.upper_rad
    return {"unguarded": replace(model, info={k: v for k, v in model.info.items() if k != REGION_KEY}),
            "fixed 2 deg margin": with_region(Region(lo, hi, DEFAULT_MARGIN_RAD, region.rule)),
            "held hard at the edge": with_region(Region(lo, hi, MIN_MARGIN_RAD / 10, region.rule)),
            "every effect in every joint": with_region(Region(lo, hi, region.margin_rad, RULE_EVERY_JOINT)),
            "by effect": with_region(Region(lo, hi, region.margin_rad, RULE_BY_EFFECT))}


def pi_variants(model: Any, rec: Recording) -> dict[str, dict[str, float]]:
    """Position error mean / max [mm] on ``rec`` of a ``pi`` model with its terms held as :data:`PI_VARIANTS` says,
    softly clamped into its training region (any other model: none)."""
    region = model.region()
    if model.kind != "pi" or region is None:
        return {}
    out = {}
    for label, held in PI_VARIANTS.items():
        R, p = model.kinematics.pose(rec.q, model.theta, **{k: region.clamp(rec.q, j) for k, j in held.items()})
        out[label] = mean_max(pose_error(rec.R, rec.p, R, p)[0])
    return out


def main(argv: list[str] | None = None) -> int:
    ap = days_parser(__doc__)
    ap.add_argument("--save", type=Path, help="save each fold's fitted models in this folder")
    ap.add_argument("--load", type=Path, help="score the models --save wrote in this folder instead of fitting")
    ap.add_argument("--folds", default="steps,q2 edges,q3 edges",
                    help="comma-separated fold names (steps: the q1, q4-q6 steps)")
    args = ap.parse_args(argv)
    robot = load_cell().robot("R1")
    rows = []
    print("| training day | held out | held-out poses | nls1 mean/max mm | pi mean/max mm | diagnosed mean/max mm | "
          "no worse | " + " | ".join(f"diagnosed, {k}" for k in VARIANTS) + " | "
          + " | ".join(f"pi, {k}" for k in PI_VARIANTS) + " | effects | cpu s |")
    print("|---" * (9 + len(VARIANTS) + len(PI_VARIANTS)) + "|")
    for day in args.days.split(","):
        rec = read_recording(DATA / "PH_grad_data" / day, robot.robot.lower_rad, robot.robot.upper_rad)
        folds = [("steps", step_mask(rec))] + [(f"q{j + 1} edges", edge_mask(rec, j)) for j in EDGE_JOINTS]
        folds = [f for f in folds if f[0] in args.folds.split(",")]
        for name, held in folds:
            t0 = time.process_time()
            stem = f"{day}_{name.replace(' ', '_')}"
            if args.load:
                nls1, pi, diagnosed = (load_model(args.load / f"{stem}_{m}.json") for m in ("nls1", "pi", "diagnosed"))
            else:
                fitter = make_fitter(robot, rec.subset(~held))
                nls1, pi, diagnosed = (fitter.fit(m)[0] for m in ("nls1", "pi", "diagnosed"))
            test = rec.subset(held)
            if args.save:
                args.save.mkdir(parents=True, exist_ok=True)
                for m in (nls1, pi, diagnosed):
                    save_model(m, args.save / f"{stem}_{m.method}.json")
            a, p, b = (mean_max(errors(m, test).position_mm) for m in (nls1, pi, diagnosed))
            guard = {label: mean_max(errors(m, test).position_mm) for label, m in guard_variants(diagnosed).items()}
            terms_held = pi_variants(pi, test)
            row = {"day": day, "fold": name, "heldout": int(held.sum()), "nls1": a, "pi": p, "diagnosed": b,
                   "no_worse": bool(b["mean"] <= a["mean"] and b["max"] <= a["max"]),
                   "effects": list(diagnosed.info.get("effects_found", [])), "diagnosed_guard_variants": guard,
                   "pi_terms_held": terms_held, "cpu_s": round(time.process_time() - t0, 1)}
            rows.append(row)
            print(f"| {day} | {name} | {row['heldout']} | {cell(a)} | {cell(p)} | {cell(b)} | "
                  f"{'yes' if row['no_worse'] else 'NO'} | "
                  + " | ".join(cell(guard.get(k)) for k in VARIANTS) + " | "
                  + " | ".join(cell(terms_held.get(k)) for k in PI_VARIANTS) + " | "
                  f"{', '.join(row['effects']) or '-'} | {row['cpu_s']:.0f} |", flush=True)
    n_ok = sum(r["no_worse"] for r in rows)
    print(f"\ndiagnosed no worse than nls1 (mean and max) on {n_ok} of {len(rows)} folds.")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
