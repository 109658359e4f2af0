"""Candidate changes to the pi fit, judged on clusters held out from the training recordings only.

For every R1 training recording (no test recording is read), pi refitted on each of the 5 folds' other clusters
(:func:`calibration.methods.heldout.cluster_folds`, the folds of ``compare``'s recommendation) and scored on the held-out
clusters, as fitted now (``plain``) and with one change:

- ``trim``: poses whose residual norm is beyond the median + 3.5 scaled MADs are dropped and pi refitted, until
  the set stops changing (at most 3 refits): an outlier rejection blind to direction;
- ``shift``: the poses :func:`calibration.diagnosis.shifts.one_sided_shift` finds shifted are dropped and pi
  refitted, likewise: a rejection of one-sided measurement jumps only;
- ``noise_a``: the orientation weight from the per-channel noise floors of the full fit
  (:func:`calibration.diagnosis.noise.channel_weight`) instead of a = 1641.

Printed per recording and variant: held-out position mean / p95 / max [mm], and the same over the "clean"
poses (those the full-recording ``shift`` rejection keeps, the same set for every variant, so a rejection is not
scored on the poses it gave up).

    python scripts/studies/sameday_candidates.py [--json FILE] [--days test0801_R1,...]
"""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from calibration.data.recording import read_recording  # noqa: E402
from calibration.diagnosis.noise import channel_weight, noise_floor  # noqa: E402
from calibration.diagnosis.shifts import one_sided_shift  # noqa: E402
from calibration.identification.geometric import rotation_residual_scale, weighted_residuals  # noqa: E402
from calibration.methods import heldout as robust  # noqa: E402
from calibration.methods.cdc import cluster_anchors  # noqa: E402
from calibration.methods.fitter import Fitter  # noqa: E402
from calibration.methods.options import FitOptions  # noqa: E402
from calibration.methods.shared import SharedCache  # noqa: E402
from scripts.benchmarks.bench_days import DATA  # noqa: E402
from scripts.studies.heldout_folds import run_days

MAD_FACTOR = 3.5
MAX_REFITS = 3
VARIANTS = ("plain", "trim", "shift", "noise_a")


def residual(model, rec) -> np.ndarray:
    _, p = model.fk(rec.q)
    return rec.p - p


def trimmed(e: np.ndarray) -> np.ndarray:
    """Poses kept by the norm rule: residual norm within the median + MAD_FACTOR scaled MADs."""
    med = np.median(e)
    return e <= med + MAD_FACTOR * 1.4826 * np.median(np.abs(e - med))


def rejecting_fit(fitter, rule):
    """pi refitted without the poses ``rule(residual (N, 3)) -> kept (N,)`` rejects, until stable; and the mask."""
    keep = np.ones(len(fitter.train), bool)
    current = fitter
    for _ in range(MAX_REFITS):
        new = rule(residual(current.physics_informed(), fitter.train))
        if np.array_equal(new, keep):
            break
        keep = new
        current = replace(fitter, train=fitter.train.subset(keep), warm=fitter, _cache=SharedCache())
    return current.physics_informed(), keep


RULES = {"trim": lambda r: trimmed(np.linalg.norm(r, axis=1)), "shift": lambda r: ~one_sided_shift(r).shifted}


def noise_weight(fitter) -> float:
    pi = fitter.physics_informed()
    R, p = pi.fk(fitter.train.q)
    w = rotation_residual_scale(fitter.options.a)
    r = weighted_residuals(fitter.train.R, fitter.train.p, R, p, w)[0].reshape(len(fitter.train), 6)
    floors = noise_floor(r, fitter.train.clusters(fitter.options.cluster_size), pi.n_parameters, w)
    return channel_weight(floors, fitter.options.a)[0]


def day_rows(robot, day: str) -> dict:
    train = read_recording(DATA / "PH_grad_data" / day, robot.robot.lower_rad, robot.robot.upper_rad)
    train.extra["cluster"] = train.clusters(7).astype(float)  # clusters survive dropped rows
    full = Fitter.for_arm(robot.arm(), train)
    a = noise_weight(full)
    full_a = Fitter.for_arm(robot.arm(), train, options=FitOptions(a=a))
    _, clean = rejecting_fit(full, RULES["shift"])
    groups, anchors = cluster_anchors(train, full.options.cluster_size)
    folds = robust.cluster_folds(len(anchors), robust.N_FOLDS, full.options.seed)[groups]
    e = {v: np.empty(len(train)) for v in VARIANTS}
    for f in range(robust.N_FOLDS):
        held = train.subset(folds == f)
        sub = replace(full, train=train.subset(folds != f), warm=full, _cache=SharedCache())
        e["plain"][folds == f] = np.linalg.norm(residual(sub.physics_informed(), held), axis=1)
        for v in ("trim", "shift"):
            e[v][folds == f] = np.linalg.norm(residual(rejecting_fit(sub, RULES[v])[0], held), axis=1)
        sub_a = replace(full_a, train=train.subset(folds != f), warm=full_a, _cache=SharedCache())
        e["noise_a"][folds == f] = np.linalg.norm(residual(sub_a.physics_informed(), held), axis=1)

    def figures(x: np.ndarray) -> dict:
        return {"mean": float(x.mean()), "p95": float(np.percentile(x, 95)), "max": float(x.max()),
                "clean_mean": float(x[clean].mean()), "clean_p95": float(np.percentile(x[clean], 95)),
                "clean_max": float(x[clean].max())}

    return {"day": day, "noise_a": a, "clean_poses": int(clean.sum()), "poses": len(train),
            "variants": {v: figures(e[v]) for v in VARIANTS}}


def show(day: str, row: dict) -> None:
    print(f"{day} (noise a = {row['noise_a']:.0f}; clean {row['clean_poses']} of {row['poses']} poses)")
    for v, x in row["variants"].items():
        print(f"   {v:8s} mean {x['mean']:.4f} p95 {x['p95']:.3f} max {x['max']:.3f} | clean mean "
              f"{x['clean_mean']:.4f} p95 {x['clean_p95']:.3f} max {x['clean_max']:.3f}", flush=True)


def main(argv: list[str] | None = None) -> int:
    return run_days(argv, __doc__, day_rows, show)


if __name__ == "__main__":
    sys.exit(main())
