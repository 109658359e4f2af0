"""Which local prior each choice rule takes, on training data and simulated R2 twins only (issue 31 part 4).

The local prior of the CDC methods built on pi is chosen on clusters held out from the training recording
(:meth:`calibration.methods.fitter.Fitter._choose_local_prior`: the ``linear`` interpolator, priors whose corrections
over the workspace stay within the limit, then a rule over the held-out RMS). This prints, per training recording
of ``../shared/data/welding_motoman/PH_grad_data`` (no test recording is read) and per simulated R2 day
(:func:`drivers.sim.cdc_twin.simulated_day`, seeds drawn at run time unless given; its training grid only), every
prior's held-out RMS, its own standard error, the paired standard error of its difference to the lowest, the
workspace ratio, and the prior each rule of :data:`calibration.methods.heldout.CHOICE_RULES` takes from the same
scores. The test errors that follow from a choice are ``scripts/benchmarks/bench_days.py``'s.

With ``--twin-test pi+fbf13,...`` each twin's own test path (simulated, never a recording) also gives every prior's
test mean for those methods, and each rule's; ``--null-twins`` adds, per seed, the same arm without the
configuration-dependent error (``cdc_mm`` = 0), where a weaker prior can only fit noise. ``--by-kind pi+fbf13,...``
scores the priors with each method's own interpolator too (the choice by the kind fitted).

    python scripts/studies/local_prior_rule.py [--days test0801_R1,...|none] [--r2-seeds S1,S2|N] [--null-twins]
                                               [--twin-test m1,m2] [--by-kind m1,m2] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from calibration.data.recording import read_recording  # noqa: E402
from calibration.evaluation.metrics import errors  # noqa: E402
from calibration.methods import (
    cdc_fit,  # noqa: E402
    workspace,  # noqa: E402
)
from calibration.methods import heldout as robust  # noqa: E402
from calibration.methods.fitter import Fitter  # noqa: E402
from calibration.methods.shared import SharedCache  # noqa: E402
from cell_config import load_cell  # noqa: E402
from drivers.sim.cdc_twin import PAPER_SIZE, simulated_day  # noqa: E402
from scripts.benchmarks.bench_days import DATA  # noqa: E402

#: The R1 training recordings bench_days judges (its UNITS), in date order.
DAYS = ("test0516_R1", "test0613_R1", "test0620_R1", "test0627_beforecalib", "test0627_aftercalib", "test0725_R1",
        "test0801_R1")


def twin_test(fitter: Any, test: Any, grid: list[float], methods: tuple[str, ...]) -> dict[str, dict[str, float]]:
    """Test-path mean position error [mm] of pi and of each method at every prior of ``grid`` (a simulated twin's
    own test path, never a recording), the local fits shared with ``fitter``."""
    out = {"pi": {"-": float(np.mean(errors(fitter.fit("pi")[0], test).position_mm))}}
    for m in methods:
        out[m] = {}
        for prior in grid:
            at = replace(fitter, options=replace(fitter.options, local_prior=prior), _cache=SharedCache())
            at._cache.pi, at._cache.local_by_prior = fitter._cache.pi, fitter._cache.local_by_prior
            out[m][f"{prior:g}"] = float(np.mean(errors(at.fit(m)[0], test).position_mm))
    return out


def by_kind(fitter: Any, methods: tuple[str, ...]) -> dict[str, dict[str, Any]]:
    """The prior each rule takes when the held-out clusters are scored with the interpolator each method fits (its
    own strength choice at that prior) instead of ``linear``: the choice by the kind actually fitted (training
    clusters only; priors beyond the workspace limit left out as the Fitter does)."""
    grid, _, ratios = fitter._cache.local_prior_scores["pi"]
    priors = tuple(g for g, r in zip(grid, ratios) if r <= workspace.WORKSPACE_RATIO_LIMIT)
    out = {}
    for m in methods:
        scores = []
        for prior in priors:
            at = replace(fitter, options=replace(fitter.options, local_prior=prior), _cache=SharedCache())
            at._cache.pi, at._cache.local_by_prior = fitter._cache.pi, fitter._cache.local_by_prior
            scores.append(cdc_fit._held_out_check(at, m, cdc_fit.cdc_options(at, m)).result())
        out[m] = {"priors": list(priors), "heldout_rms_mm": [round(h.rms_mm, 4) for h in scores],
                  **{name: priors[rule(priors, scores)] for name, rule in robust.CHOICE_RULES.items()}}
    return out


def scores_of(fitter: Any) -> dict[str, Any]:
    """The local-prior scores of one Fitter (pi reference) and each rule's choice from them."""
    fitter.local_prior("pi")
    grid, scores, ratios = fitter._cache.local_prior_scores["pi"]
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
    parser.add_argument("--null-twins", action="store_true", help="also a twin without configuration-dependent "
                                                                  "error (cdc_mm = 0) per seed")
    parser.add_argument("--twin-test", default="", help="methods (comma-separated) whose test-path mean on each twin "
                                                         "is computed at every prior, and per rule at its choice")
    parser.add_argument("--by-kind", default="", help="CDC methods (comma-separated, not the neural ones) whose own "
                                                       "interpolator also scores the priors (the choice by kind)")
    parser.add_argument("--json", help="write the figures to this JSON file")
    args = parser.parse_args(argv)
    days = [] if args.days == "none" else args.days.split(",")
    parts = [int(s) for s in args.r2_seeds.split(",") if s.strip()]
    seeds = parts if "," in args.r2_seeds else \
        [int(s) for s in np.random.default_rng().integers(0, 2 ** 31, parts[0])] if parts[0] > 0 else []
    out: dict[str, Any] = {}
    kinds = tuple(m for m in args.by_kind.split(",") if m)
    cell = load_cell()
    r1 = cell.robot("R1")
    for day in days:
        path = DATA / "PH_grad_data" / day
        if not path.exists():
            print(f"training recording not found: {path}", file=sys.stderr)
            return 2
        fitter = Fitter.for_arm(r1.arm(), read_recording(path, r1.robot.lower_rad, r1.robot.upper_rad))
        out[day] = scores_of(fitter)
        if kinds:
            out[day]["by_kind"] = by_kind(fitter, kinds)
        print(f"{day}: {out[day]['chosen']}", file=sys.stderr, flush=True)
    r2 = cell.robot("R2")
    methods = tuple(m for m in args.twin_test.split(",") if m)
    sizes = {"R2 sim": PAPER_SIZE, **({"R2 null": replace(PAPER_SIZE, cdc_mm=0.0)} if args.null_twins else {})}
    for seed in seeds:
        for kind, size in sizes.items():
            sim = simulated_day(r2.robot, r2.tool, seed, size, label="simulated R2")
            fitter = Fitter.for_arm(r2.arm(), sim.train)
            name = f"{kind} {seed}"
            out[name] = scores_of(fitter)
            if kinds:
                out[name]["by_kind"] = by_kind(fitter, kinds)
            if methods:
                out[name]["test_mean_mm"] = twin_test(fitter, sim.test, out[name]["grid"], methods)
            print(f"{name}: {out[name]['chosen']}", file=sys.stderr, flush=True)
    print("| data | prior: held-out RMS ± own SE (paired SE to best) [workspace ratio] | " +
          " | ".join(robust.CHOICE_RULES) + " |")
    print("|---|---|" + "---|" * len(robust.CHOICE_RULES))
    for name, r in out.items():
        cells = "; ".join(f"{g:g}: {m:.4f} ± {s:.4f} ({'–' if p is None else f'{p:.4f}'}) [{w:.2f}]" for g, m, s, p, w
                          in zip(r["grid"], r["rms_mm"], r["se_mm"], r["paired_se_to_best_mm"], r["workspace_ratio"]))
        print(f"| {name} | {cells} | " + " | ".join(f"{r['chosen'][k]:g}" for k in robust.CHOICE_RULES) + " |")
    if kinds:
        print("\nChoice by the kind fitted (held-out RMS per prior; each rule's prior)\n")
        print("| data | method | held-out RMS per prior | " + " | ".join(robust.CHOICE_RULES) + " |")
        print("|---|---|---|" + "---|" * len(robust.CHOICE_RULES))
        for n, r in out.items():
            for m, k in r.get("by_kind", {}).items():
                rms = "; ".join(f"{p:g}: {v:.4f}" for p, v in zip(k["priors"], k["heldout_rms_mm"]))
                print(f"| {n} | {m} | {rms} | " + " | ".join(f"{k[rule]:g}" for rule in robust.CHOICE_RULES) + " |")
    tested = {n: r for n, r in out.items() if "test_mean_mm" in r}
    if tested:
        print("\nTwin test paths: mean position error [mm] at each rule's prior (gain over pi)\n")
        print("| twin | pi | " + " | ".join(f"{m} {rule}" for m in methods for rule in robust.CHOICE_RULES) + " |")
        print("|---|---|" + "---|" * (len(methods) * len(robust.CHOICE_RULES)))
        for n, r in tested.items():
            t, pi = r["test_mean_mm"], r["test_mean_mm"]["pi"]["-"]
            at = [t[m][format(r["chosen"][rule], "g")] for m in methods for rule in robust.CHOICE_RULES]
            print(f"| {n} | {pi:.4f} | " + " | ".join(f"{e:.4f} ({1 - e / pi:.1%})" for e in at) + " |")
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
