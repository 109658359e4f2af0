"""Pose design benchmark: 16 chosen clusters against every-k-th and random subsets, and the simulated cell's
optimal design against the paper's grid.

Real data (``--days``): on every shared R1 day with a test recording, the training recording's clusters are cut
to 16 (112 poses, 6.5 % of the paper's 1736) three ways: ``cellcal select --budget 16`` (D-optimal + space
filling, :mod:`calibration.identification.design`), every k-th cluster (k = ceil(K / 16)) and random draws of 16 clusters (the
median over ``--draws`` draws of each figure). Each subset is fitted with ``pi`` and ``fbf13`` and the choice
made on the training subset alone (``choice``: fbf13 when its interpolation beats its pi reference on held-out
training clusters, else pi; the selection of issue 10's ``Comparison.recommended`` is not in this branch), and
tested on that day's full test recording (position error mean / max [mm]). The goal is the paper's full-data FBF
accuracy: <= 0.31 mm mean and <= 0.74 mm max. ``0620 before`` is left out: that test file disagrees with its
own day's training recording by a frame (the data README), so no training subset can reach it.

Sparse anchors: every 16th training cluster of 0801 with pi and every CDC kind (linear, cubic, rbf, fbf13,
fbf7) on 0801's test, the row of issue 14's table where fbf13 reached 3.8 mm.

Simulated cell (``--sim``): the physics twin of the simulated cell's R1 (``SimCellOptions``' planted geometric
errors and gravity compliance, seeded as the cell seeds it), measured with ``SimCellOptions``' noise, on (a) the
paper's grid (248 clusters, 1736 poses) and (b) ``plan --design optimal --budget 196`` (28 clusters); both
fitted with pi / fbf13 / the choice and validated on poses over the whole workspace (q1 and the wrist far
beyond the grid's 2 deg; drawn wider than the design's own candidate box), each checked safe; and, for the
record, on the demo's validation poses inside the grid's own region (wrist within 5 deg, ``grid_region``).

Spread weight (``--spread-check``, training data only): pi on the 16 clusters selected with lambda = 0 (D alone),
1 (the default) and 3, scored on the training clusters left out.

    python scripts/benchmarks/bench_design.py [--json FILE] [--quick] [--days | --sim | --spread-check]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from calibration.data.recording import Recording, read_recording  # noqa: E402
from calibration.evaluation.metrics import errors  # noqa: E402
from calibration.identification.design import select_recording  # noqa: E402
from calibration.kinematics import so3  # noqa: E402
from calibration.kinematics.parameterisation import MinimalParameterisation  # noqa: E402
from cell_config import load_cell  # noqa: E402
from scripts.benchmarks.bench_days import DATA, UNITS, make_fitter, mean_max  # noqa: E402

BUDGET_CLUSTERS = 16
SIM_BUDGET_POSES = 196
GOAL = {"mean": 0.31, "max": 0.74}
METHODS = ("pi", "fbf13")
#: Methods of the sparse-anchor row (the issue's table).
SPARSE_METHODS = ("pi", "linear", "cubic", "rbf", "fbf13", "fbf7")
#: Test recordings left out, with the reason.
EXCLUDED = {"0620 before": "frame-mismatched with its own day's training recording (data README)"}
NOISE_MM = 0.05
#: Validation box of the simulated cell [deg] for q1, q4, q5, q6 (q2, q3 in the paper's band).
SIM_VALIDATION_DEG = ((-60.0, 60.0), (-140.0, 140.0), (-80.0, 60.0), (-140.0, 140.0))
SIM_VALIDATION_N = 500


def fit_and_test(robot: Any, train: Recording, test: Recording, *others: Recording) -> dict[str, Any]:
    """pi, fbf13 and the training-only choice between them, each on ``test`` (mean / max [mm]); on each of
    ``others`` too (under ``"others"``, a list)."""
    fitter = make_fitter(robot, train)
    models = {m: fitter.fit(m)[0] for m in METHODS}
    h = models["fbf13"].info["heldout"]
    chosen = "fbf13" if h["rms_mm"] < h["reference_rms_mm"] else "pi"

    def on(rec: Recording) -> dict[str, Any]:
        out: dict[str, Any] = {m: mean_max(errors(models[m], rec).position_mm) for m in METHODS}
        out["choice"] = {**out[chosen], "method": chosen}
        return out

    result = on(test)
    if others:
        result["others"] = [on(rec) for rec in others]
    return result


def clusters_subset(rec: Recording, ids: np.ndarray) -> Recording:
    return rec.subset(np.flatnonzero(np.isin(rec.clusters(), ids)))


def median_of(draws: list[dict[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for m in (*METHODS, "choice"):
        out[m] = {k: float(np.median([d[m][k] for d in draws])) for k in ("mean", "max")}
    out["choice"]["methods"] = {m: sum(d["choice"]["method"] == m for d in draws) for m in METHODS}
    return out


def bench_days(data: Path, draws: int, log: Any) -> dict[str, Any]:
    cell = load_cell()
    robot = cell.robot("R1")
    lim = (robot.robot.lower_rad, robot.robot.upper_rad)
    par = MinimalParameterisation(robot.model(), fit_tool=True)
    results: dict[str, Any] = {}
    for unit in UNITS:
        tests = [(label, folder) for label, folder in unit.tests if label not in EXCLUDED]
        if not tests or not (data / "PH_grad_data" / unit.train).exists():
            continue
        train = read_recording(data / "PH_grad_data" / unit.train, *lim)
        ids = np.unique(train.clusters())
        K = len(ids)
        k = math.ceil(K / BUDGET_CLUSTERS)
        start = time.perf_counter()
        sel = select_recording(par, train, BUDGET_CLUSTERS, NOISE_MM)
        select_s = time.perf_counter() - start
        subsets = {"select": train.subset(sel.rows), f"every {k}th": clusters_subset(train, ids[::k])}
        rng = np.random.default_rng(0)
        random_sets = [clusters_subset(train, rng.choice(ids, BUDGET_CLUSTERS, replace=False)) for _ in range(draws)]
        for label, folder in tests:
            test = read_recording(data / "kinematic_raw_data" / folder, *lim)
            row: dict[str, Any] = {"train_clusters": K, "select_seconds": round(select_s, 2),
                                   "select_clusters": list(sel.clusters)}
            for name, sub in subsets.items():
                row[name] = {**fit_and_test(robot, sub, test), "clusters": int(len(np.unique(sub.clusters()))),
                             "poses": len(sub)}
                log(f"{label:12s} {name:10s} " + "  ".join(f"{m} {row[name][m]['mean']:.3f}/{row[name][m]['max']:.3f}"
                                                          for m in (*METHODS, "choice")))
            row[f"random (median of {draws})"] = median_of([fit_and_test(robot, s, test) for s in random_sets])
            r = row[f"random (median of {draws})"]
            log(f"{label:12s} {'random':10s} " + "  ".join(f"{m} {r[m]['mean']:.3f}/{r[m]['max']:.3f}"
                                                          for m in (*METHODS, "choice")))
            c = row["select"]["choice"]
            row["goal_met"] = bool(c["mean"] <= GOAL["mean"] and c["max"] <= GOAL["max"])
            results[label] = row
    return {"budget_clusters": BUDGET_CLUSTERS, "goal_mm": GOAL, "excluded": EXCLUDED, "units": results}


def bench_sparse(data: Path, log: Any) -> dict[str, Any]:
    """The issue's sparse-anchor row: every 16th training cluster of 0801, every CDC kind and pi, on 0801's test."""
    robot = load_cell().robot("R1")
    lim = (robot.robot.lower_rad, robot.robot.upper_rad)
    train = read_recording(data / "PH_grad_data" / "test0801_R1", *lim)
    test = read_recording(data / "kinematic_raw_data" / "test0801_R1", *lim)
    ids = np.unique(train.clusters())
    sub = clusters_subset(train, ids[::math.ceil(len(ids) / BUDGET_CLUSTERS)])
    fitter = make_fitter(robot, sub)
    out: dict[str, Any] = {"clusters": int(len(np.unique(sub.clusters()))), "poses": len(sub)}
    for m in SPARSE_METHODS:
        model, _ = fitter.fit(m)
        out[m] = mean_max(errors(model, test).position_mm)
        if "strength" in model.info:
            out[m]["strength"] = model.info["strength"]
    log("0801 every 16th: " + "  ".join(f"{m} {out[m]['mean']:.3f}/{out[m]['max']:.3f}" for m in SPARSE_METHODS))
    return out


def spread_check(data: Path, log: Any, weights: tuple[float, ...] = (0.0, 1.0, 3.0)) -> dict[str, Any]:
    """Training data only: pi fitted on the 16 clusters selected with each spread weight, position error on the
    training clusters left out (the evidence behind the default weight; no test recording is read)."""
    robot = load_cell().robot("R1")
    lim = (robot.robot.lower_rad, robot.robot.upper_rad)
    par = MinimalParameterisation(robot.model(), fit_tool=True)
    out: dict[str, Any] = {}
    for unit in UNITS:
        train = read_recording(data / "PH_grad_data" / unit.train, *lim)
        row = {}
        for w in weights:
            sel = select_recording(par, train, BUDGET_CLUSTERS, NOISE_MM, spread_weight=w)
            rest = train.subset(np.setdiff1d(np.arange(len(train)), sel.rows))
            model, _ = make_fitter(robot, train.subset(sel.rows)).fit("pi")
            row[f"{w:g}"] = mean_max(errors(model, rest).position_mm)
        out[unit.name] = row
        log(f"spread weight, {unit.name:12s} left-out training clusters: " + "  ".join(
            f"{k}: {v['mean']:.3f}/{v['max']:.3f}" for k, v in row.items()))
    return out


def measure(truth: Any, q: np.ndarray, noise_mm: float, noise_deg: float, rng: np.random.Generator,
            extra: dict[str, np.ndarray] | None = None) -> Recording:
    """Noisy static samples of the twin at q (per-sample noise of the simulated mocap)."""
    R, p = truth.pose(q)
    p = p + rng.normal(0.0, noise_mm, p.shape)
    R = R @ so3.exp(rng.normal(0.0, math.radians(noise_deg), (len(q), 3)))
    return Recording(q, p, so3.R_to_quat(R), dict(extra or {}), "sim")


def workspace_validation(safety: Any, others: dict[str, np.ndarray], seed: int, n: int = SIM_VALIDATION_N
                         ) -> np.ndarray:
    """R1 validation poses over the whole workspace [rad] (n, 6): q2, q3 in the paper's band, q1 and the wrist in
    ``SIM_VALIDATION_DEG`` (far beyond the grid's 2 deg), each checked safe with the other arms at ``others``."""
    from app.collection.plans.poses import paper_q3_bounds, plan_validation
    from calibration.errors import CellCalError

    lo = np.radians([SIM_VALIDATION_DEG[0][0], -55.0, -70.0, *[b[0] for b in SIM_VALIDATION_DEG[1:]]])
    hi = np.radians([SIM_VALIDATION_DEG[0][1], 50.0, 50.0, *[b[1] for b in SIM_VALIDATION_DEG[1:]]])
    lim_lo, lim_hi = safety.limits("R1")
    lo, hi = np.maximum(lo, lim_lo), np.minimum(hi, lim_hi)

    def accept(q: np.ndarray) -> bool:
        b = paper_q3_bounds(math.degrees(q[1]))
        if not b[0] <= math.degrees(q[2]) <= b[1]:
            return False
        try:
            safety.check_configs("R1", q, others)
        except CellCalError:
            return False
        return True

    val = plan_validation("R1", lo, hi, n, seed=seed + 1, margin_deg=0.0, accept=accept, max_tries=2000)
    return np.array([t.q for t in val])


def bench_sim(seed: int, log: Any) -> dict[str, Any]:
    from app.collection.plans.design import DesignSpec, optimal_plan
    from app.collection.plans.poses import plan_anchor_grid
    from app.collection.plans.session import validation_plan
    from app.collection.runtime.sim import SimCellOptions, park_q
    from app.collection.safety import CellSafety
    from drivers.sim.truth import cell_truths

    cell = load_cell()
    robot = cell.robot("R1")
    opts = SimCellOptions(seed=seed)
    truth = cell_truths(cell, opts.seed, opts.errors, ("R1", "R2"))["R1"]
    safety = CellSafety(cell)
    others = {n: park_q(n) for n in cell.robots if n != "R1"}
    par = MinimalParameterisation(robot.model(), fit_tool=True)
    rng = np.random.default_rng(seed)

    grid = plan_anchor_grid("R1")
    grid_q = np.array([t.q for t in grid])
    grid_rec = measure(truth, grid_q, opts.noise_pos_mm, opts.noise_rot_deg, rng,
                       {"cluster": np.array([t.cluster for t in grid], dtype=float)})
    start = time.perf_counter()
    spec = DesignSpec(budget=SIM_BUDGET_POSES, noise_mm=NOISE_MM, seed=seed)
    plan, figs = optimal_plan("R1", par, safety, others, spec, park_q("R1"))
    plan_s = time.perf_counter() - start
    opt_rec = measure(truth, plan.q, opts.noise_pos_mm, opts.noise_rot_deg, rng,
                      {"cluster": np.array([t.cluster for t in plan.targets], dtype=float)})

    val = workspace_validation(safety, others, seed)
    val_rec = measure(truth, val, opts.noise_pos_mm, opts.noise_rot_deg, rng)
    near = validation_plan("R1", safety, others, SIM_VALIDATION_N, seed=seed + 2)  # the demo's: wrist within 5 deg
    near_rec = measure(truth, near.q, opts.noise_pos_mm, opts.noise_rot_deg, rng)
    out: dict[str, Any] = {"seed": seed, "validation_poses": SIM_VALIDATION_N,
                           "validation_box_deg": {"q1": SIM_VALIDATION_DEG[0], "q4": SIM_VALIDATION_DEG[1],
                                                  "q5": SIM_VALIDATION_DEG[2], "q6": SIM_VALIDATION_DEG[3]},
                           "plan_seconds": round(plan_s, 2),
                           "figures": {k: f.to_json() for k, f in figs.items()}}
    for name, rec in (("paper grid", grid_rec), ("optimal", opt_rec)):
        r = fit_and_test(robot, rec, val_rec, near_rec)
        out[name] = {**r, "poses": len(rec), "grid_region": r.pop("others")[0]}
        r = out[name]
        log(f"sim {name:10s} ({len(rec)} poses) whole workspace: " + "  ".join(
            f"{m} {r[m]['mean']:.3f}/{r[m]['max']:.3f}" for m in (*METHODS, "choice")))
        g = r["grid_region"]
        log(f"sim {name:10s} ({len(rec)} poses) grid region (wrist +-5 deg): " + "  ".join(
            f"{m} {g[m]['mean']:.3f}/{g[m]['max']:.3f}" for m in (*METHODS, "choice")))
    g, o = out["paper grid"]["choice"], out["optimal"]["choice"]
    out["optimal_beats_grid"] = bool(o["mean"] < g["mean"] and o["max"] < g["max"])
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", help="write every figure to this JSON file")
    parser.add_argument("--data", type=Path, default=DATA, help=f"the welding_motoman folder (default {DATA})")
    parser.add_argument("--quick", action="store_true", help="5 random draws instead of 20")
    parser.add_argument("--draws", type=int, help="random draws per day (default 20, 5 with --quick)")
    only = parser.add_mutually_exclusive_group()
    only.add_argument("--days", action="store_true", help="only the real-data part")
    only.add_argument("--sim", action="store_true", help="only the simulated cell")
    parser.add_argument("--seed", type=int, default=0, help="seed of the simulated cell")
    parser.add_argument("--spread-check", action="store_true",
                        help="only the training-data check of the spread weight (0, 1, 3) on left-out clusters")
    args = parser.parse_args(argv)
    draws = args.draws or (5 if args.quick else 20)
    log = lambda s: print(s, flush=True)  # noqa: E731
    result: dict[str, Any] = {}
    start = time.perf_counter()
    if args.spread_check:
        result["spread_check"] = spread_check(args.data, log)
    elif not args.sim:
        if args.data.exists():
            result["sparse_0801"] = bench_sparse(args.data, log)
            result["days"] = bench_days(args.data, draws, log)
        else:
            log(f"no data at {args.data}: real-data part skipped")
    if not (args.days or args.spread_check):
        result["sim"] = bench_sim(args.seed, log)
    result["seconds"] = round(time.perf_counter() - start, 1)
    if "days" in result:
        print("\nselect --budget 16, then the training-only choice, on each day's full test (mean/max mm; goal "
              f"<= {GOAL['mean']}/{GOAL['max']}):")
        for label, row in result["days"]["units"].items():
            c = row["select"]["choice"]
            verdict = "ok" if row["goal_met"] else "MISSED"
            print(f"  {label:12s} {c['method']:6s} {c['mean']:.3f}/{c['max']:.3f}  {verdict}")
    if "sim" in result:
        s = result["sim"]
        print(f"sim: optimal ({s['optimal']['poses']} poses) {s['optimal']['choice']['mean']:.3f}/"
              f"{s['optimal']['choice']['max']:.3f} vs paper grid ({s['paper grid']['poses']}) "
              f"{s['paper grid']['choice']['mean']:.3f}/{s['paper grid']['choice']['max']:.3f}: "
              f"{'beats it' if s['optimal_beats_grid'] else 'does NOT beat it'}")
    print(f"{result['seconds']} s")
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
