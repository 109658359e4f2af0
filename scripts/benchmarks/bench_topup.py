"""Top-up designs on the real recordings: the protocol of the data README's "Top-up protocol" (issue 33).

For every shared day with a test recording and every split of its test path (1500 stops, rows counted from 0):

- ``interleaved``: candidates = rows whose ``row // 50`` is even, task = the others; ``interleaved-swapped``: the
  reverse;
- ``halves``: candidates = rows 0-749, task = rows 750-1499; ``halves-swapped``: the reverse;

each method is fitted on the day's training grid plus k candidate poses (stand-alone poses,
:func:`calibration.data.recording.with_added`) and judged on the task's measured poses (position mean / max [mm]):

- ``chosen``: the top-up design (:func:`calibration.methods.topup.choose`: joint angles of TRAIN, candidates and task only),
  as many of its first k poses kept as ``cellcal select`` keeps (``--risk default``: the global fit's predicted task
  error with its misfit, :mod:`calibration.methods.topup_risk`, under ``RISK_PRIOR``; ``day``: under the scales of
  the day's own training folds; ``none``: all k). A row whose chosen poses were cut says ``(kept n)``;
- ``random``: the median (of the mean, and separately of the max) over ``--random`` seeded random picks;
- ``farthest``: farthest-point picks in joint space, each the candidate farthest from TRAIN and those chosen;
- k = 0 (the grid alone) and all candidates.

``--methods`` may name ``recommended``: the model ``compare --methods all`` recommends for the day, chosen on the day's
training grid alone (clusters held out from training, :func:`app.workflows.compare.recommend_fitted`, as
``scripts/studies/recommend_days.py`` runs it; cached per day), then fitted on grid + picks like any other method. The
recommendation is made once per day on the grid, not again on grid + picks.

For the pose counts of ``--sigma-k`` the predicted position sigma (:func:`calibration.methods.topup.predicted_sigma`, the
RMS of the error norm) is checked against each method's task errors: the share of task poses beyond 2 sigma beside
the share a Gaussian error of each pose's predicted covariance puts there (:func:`calibration.methods.topup
.gaussian_share_over`: 0.74 % isotropic, up to 4.55 % along one axis), under the fixed scales
(``SIGMA_PARAM_SD_MM``/``SIGMA_RESIDUAL_MM``) and under the scales chosen on the day's training data alone
(:func:`sigma_scales_for`: the residual chosen on clusters held out at random, the q1/q4-q6 steps and the q2 and q3
edges; the parameter prior stays the fixed one, which those folds cannot bound: calibration.methods.topup).

``--risk-scales`` prints the risk model's scales each day's training folds choose and the choice of all 7 days'
folds together (what ``RISK_PRIOR`` holds). ``--designs`` names the comparison designs fitted (each costs fits:
one recommended ``pi+nn`` fit takes about 55 s on a loaded 2-core machine, a ``pi`` fit about 1 s).

Fits are cached in ``--cache`` (a JSON file keyed by day, split, method, design, k, seed and the design's
settings), so a rerun with more days or seeds refits only what is new.

    python scripts/benchmarks/bench_topup.py [--days 0613,0725] [--splits interleaved,halves] [--k 0,7,14,21,49]
                                  [--random 20] [--methods pi] [--designs farthest,random,all] [--risk default]
                                  [--json FILE] [--cache FILE]
    python scripts/benchmarks/bench_topup.py --risk-scales [--days ...] [--cache FILE]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from app.workflows.compare import recommend_fitted  # noqa: E402
from calibration.data.recording import DEFAULT_ADD_WEIGHT, Recording, read_recording, with_added  # noqa: E402
from calibration.evaluation.metrics import errors  # noqa: E402
from calibration.identification.design import select_recording  # noqa: E402
from calibration.kinematics.parameterisation import MinimalParameterisation  # noqa: E402
from calibration.method_names import METHODS, NEURAL_METHODS  # noqa: E402
from calibration.methods.fitter import Fitter  # noqa: E402
from calibration.methods.topup import (  # noqa: E402
    SIGMA_PARAM_SD_MM,
    SIGMA_RESIDUAL_MM,
    TopupPrior,
    choose,
    gaussian_share_over,
    held_out_sigma_scales,
    predicted_position_cov,
    predicted_sigma,
)
from calibration.methods.topup_risk import (  # noqa: E402
    RISK_PRIOR,
    best_scales,
    fit_risk,
    fold_log_likelihoods,
    useful_count,
)
from calibration.methods.topup_sigma import held_out_folds, sigma_fold_masks  # noqa: E402
from cell_config import load_cell  # noqa: E402

DATA = next((d / "shared" / "data" / "welding_motoman" for d in ROOT.parents
             if (d / "shared" / "data" / "welding_motoman").exists()), ROOT.parent / "shared" / "data" / "welding_motoman")
#: day -> (training folder under PH_grad_data, test folder under kinematic_raw_data)
DAYS = {"0516": ("test0516_R1", "test0516_R1"), "0613": ("test0613_R1", "test0613"),
        "0620 after": ("test0620_R1", "test0620_aftercalib"),
        "0627 before": ("test0627_beforecalib", "test0627_beforecalib"),
        "0627 after": ("test0627_aftercalib", "test0627_aftercalib"), "0725": ("test0725_R1", "test0725_R1"),
        "0801": ("test0801_R1", "test0801_R1")}
SPLITS = ("interleaved", "halves", "interleaved-swapped", "halves-swapped")
DEFAULT_K = (0, 7, 14, 21, 49)
BLOCK = 50


def split_rows(split: str, n: int) -> tuple[np.ndarray, np.ndarray]:
    """``(candidate rows, task rows)`` of a test path of n rows under ``split``."""
    rows = np.arange(n)
    if split.startswith("interleaved"):
        cand = rows[(rows // BLOCK) % 2 == 0]
    elif split.startswith("halves"):
        cand = rows[rows < n // 2]
    else:
        raise SystemExit(f"unknown split {split!r}; valid: {', '.join(SPLITS)}")
    task = np.setdiff1d(rows, cand)
    return (task, cand) if split.endswith("swapped") else (cand, task)


class Cache:
    def __init__(self, path: Path | None) -> None:
        self.path = path
        self.data: dict[str, Any] = json.loads(path.read_text()) if path and path.exists() else {}

    def get(self, key: str, make: Any) -> Any:
        if key not in self.data:
            self.data[key] = make()
            if self.path:
                self.path.write_text(json.dumps(self.data))
        return self.data[key]


def fit_and_judge(nominal: Any, train: Recording, added: Recording | None, task: Recording, method: str,
                  weight: int = 1) -> list[float]:
    rec = train if added is None or not len(added) else with_added(train, [added], weight=weight)
    model, _ = Fitter("R1", nominal, rec).fit(method)
    e = errors(model, task).position_mm
    return [float(e.mean()), float(e.max())]


#: What ``compare --methods all`` fits and may recommend (cpa needs sweeps; diagnosed is never a candidate).
RECOMMEND_METHODS = tuple(m for m in METHODS if m not in ("cpa", "diagnosed"))


def recommended_method(train: Recording) -> str:
    """The method ``compare --methods all`` recommends on ``train`` (clusters held out from training only)."""
    fitter = Fitter.for_arm(load_cell().robot("R1").arm(), train)
    fitter.prefetch(RECOMMEND_METHODS, held_out=True)
    order = [m for m in RECOMMEND_METHODS if m not in NEURAL_METHODS] + [m for m in RECOMMEND_METHODS
                                                                          if m in NEURAL_METHODS]
    models = {m: fitter.fit(m)[0] for m in order}
    return recommend_fitted(fitter, models).method


def run(args: argparse.Namespace) -> dict[str, Any]:
    nominal = load_cell().robot("R1").model()
    prior = TopupPrior(**{k: v for k, v in [("kind", args.kind), ("gp_scale_mm", args.gp_scale_mm),
                                            ("length_rad", args.length_rad), ("tail_weight", args.tail_weight)]
                          if v is not None})
    tag = hashlib.sha1(json.dumps(asdict(prior), sort_keys=True).encode()).hexdigest()[:10]
    cache = Cache(args.cache)
    out: dict[str, Any] = {"prior": asdict(prior), "weight": args.weight, "train_clusters": args.train_clusters,
                           "rows": []}
    for day in args.days:
        train_dir, test_dir = DAYS[day]
        train = read_recording(DATA / "PH_grad_data" / train_dir)
        test = read_recording(DATA / "kinematic_raw_data" / test_dir)
        day_key = day
        if args.train_clusters:  # the clusters cellcal select --budget N keeps (joint angles only)
            sel = select_recording(MinimalParameterisation(nominal, fit_tool=True), train, args.train_clusters, 0.05)
            train = train.subset(sel.rows)
            day_key = f"{day}|select{args.train_clusters}"
        for split in args.splits:
            cand_rows, task_rows = split_rows(split, len(test))
            cand, task = test.subset(cand_rows), test.subset(task_rows)
            t0 = time.perf_counter()
            kmax = max(args.k)
            pick = cache.get(f"{day_key}|{split}|choose|{tag}|{kmax}", lambda: _choose(nominal, train, cand, task, kmax,
                                                                                 prior))
            risk = _risk_along(args, cache, nominal, train, day_key, f"{day_key}|{split}|{tag}|{kmax}", cand, task,
                               pick["order"])
            design_s = time.perf_counter() - t0
            spread = farthest_from(train.q, cand.q, kmax)
            for asked in args.methods:
                method = asked if asked != "recommended" else cache.get(f"{day_key}|recommended",
                                                                        lambda: recommended_method(train))
                key = f"{day_key}|{split}|{method}"
                wkey = f"{key}|w{args.weight}"
                w = args.weight
                grid_errors = lambda: cache.get(f"{key}|errors|grid", lambda: task_errors(  # noqa: E731
                    nominal, train, cand.subset(np.zeros(0, dtype=int)), task, method, 1))
                base = cache.get(f"{key}|grid", lambda: _stats(grid_errors()))
                every = (cache.get(f"{key}|all", lambda: fit_and_judge(nominal, train, cand, task, method))
                         if "all" in args.designs else None)
                for k in args.k:
                    row: dict[str, Any] = {"day": day, "split": split, "method": method, "asked": asked, "k": k, "weight": w,
                                           "grid": base, "all": every}
                    if k == 0:
                        row.update(chosen=base, farthest=base, random=base)
                    else:
                        n = k if risk is None else useful_count(risk["criterion"], k)
                        row["kept"] = n
                        added = cand.subset(np.asarray(pick["order"][:n], dtype=int))
                        chosen_errors = (grid_errors if not n else lambda: cache.get(  # noqa: E731
                            f"{wkey}|errors|{tag}|{n}", lambda: task_errors(nominal, train, added, task, method, w)))
                        row["chosen"] = base if not n else cache.get(f"{wkey}|chosen|{tag}|{n}",
                                                                     lambda: _stats(chosen_errors()))
                        row["farthest"] = cache.get(f"{wkey}|farthest|{k}", lambda: fit_and_judge(
                            nominal, train, cand.subset(spread[:k]), task, method, w)) if "farthest" in args.designs \
                            else None
                        draws = [cache.get(f"{wkey}|random|{k}|{s}", lambda: fit_and_judge(
                            nominal, train, cand.subset(np.random.default_rng(s).choice(len(cand), k, replace=False)),
                            task, method, w)) for s in range(args.random if "random" in args.designs else 0)]
                        row["random"] = [float(np.median([d[0] for d in draws])),
                                         float(np.median([d[1] for d in draws]))] if draws else None
                        row["random_worse_share"] = (float(np.mean([d[0] > row["chosen"][0] for d in draws]))
                                                     if draws else None)
                    gain = base[0] - every[0] if every is not None else 0.0
                    row["gain_share"] = float((base[0] - row["chosen"][0]) / gain) if gain > 0 else None
                    if k in args.sigma_k:
                        added = cand.subset(np.asarray(pick["order"][:row.get("kept", k)], dtype=int))
                        e = np.asarray(grid_errors() if not row.get("kept", k) else chosen_errors())
                        scales = sigma_scales_for(nominal, train, cache.get(
                            f"{day_key}|sigma-scales", lambda: sigma_fold_errors(nominal, train)))
                        q_given = np.concatenate([train.q, added.q])
                        row["sigma"] = sigma_shares(nominal, q_given, task, e, SIGMA_PARAM_SD_MM, SIGMA_RESIDUAL_MM)
                        row["sigma_heldout"] = sigma_shares(nominal, q_given, task, e, scales["param_sd_mm"],
                                                            scales["residual_mm"])
                        row["sigma_scales"] = scales
                    out["rows"].append(row)
                    print(_line(row), flush=True)
            print(f"# {day} {split}: design {design_s:.1f} s (cached or computed)", flush=True)
    return out


def _risk_along(args: argparse.Namespace, cache: Cache, nominal: Any, train: Recording, day_key: str, key: str,
                cand: Recording, task: Recording, order: list[int]) -> dict[str, Any] | None:
    """The global fit's predicted task error along the design's order (:func:`calibration.methods.topup_risk.fit_risk`)
    under ``--risk`` (None: ``none``, every pose kept as before)."""
    if args.risk == "none":
        return None
    prior = RISK_PRIOR
    if args.risk == "day":
        prior = replace(RISK_PRIOR, **{k: v for k, v in day_risk_scales(cache, nominal, train, day_key).items()
                                       if k in ("param_sd_mm", "gp_scale_mm", "length_rad")})
    rtag = hashlib.sha1(json.dumps(asdict(prior), sort_keys=True).encode()).hexdigest()[:10]

    def make() -> dict[str, Any]:
        r = fit_risk(nominal, train.q, cand.q[np.asarray(order, dtype=int)], task.q, prior, args.weight)
        return {"criterion": r.criterion_mm2.tolist(), "rms_mm": r.rms_mm.tolist()}
    return dict(cache.get(f"{key}|risk|{rtag}|w{args.weight}", make))


def day_risk_table(cache: Cache, nominal: Any, train: Recording, day_key: str) -> dict[tuple[float, ...], float]:
    """:func:`calibration.methods.topup_risk.fold_log_likelihoods` on the day's training folds (cached)."""
    def make() -> list[list[float]]:
        folds = cache.get(f"{day_key}|sigma-scales", lambda: sigma_fold_errors(nominal, train))
        table = fold_log_likelihoods(nominal, train.q, fold_masks(nominal, train),
                                     [np.asarray(x) for x in folds["fold_errors_mm"]])
        return [[*key, ll] for key, ll in table.items()]
    return {tuple(row[:4]): row[4] for row in cache.get(f"{day_key}|risk-table", make)}


def day_risk_scales(cache: Cache, nominal: Any, train: Recording, day_key: str) -> dict[str, Any]:
    """The risk model's scales of the largest likelihood on the day's training folds alone."""
    table = day_risk_table(cache, nominal, train, day_key)
    return best_scales(table, 0).to_json()  # type: ignore[arg-type]


def risk_scales_report(args: argparse.Namespace) -> dict[str, Any]:
    """``--risk-scales``: each day's choice and the choice of the days' tables added (what RISK_PRIOR holds)."""
    nominal = load_cell().robot("R1").model()
    cache = Cache(args.cache)
    pooled: dict[tuple[float, ...], float] = {}
    out: dict[str, Any] = {"days": {}}
    for day in args.days:
        train = read_recording(DATA / "PH_grad_data" / DAYS[day][0])
        table = day_risk_table(cache, nominal, train, day)
        for key, ll in table.items():
            pooled[key] = pooled.get(key, 0.0) + ll
        out["days"][day] = best_scales(table, 0).to_json()  # type: ignore[arg-type]
        print(f"{day:<12} risk scales on its training folds: {_scales_text(out['days'][day])}", flush=True)
    out["pooled"] = best_scales(pooled, 0).to_json()  # type: ignore[arg-type]
    print(f"{'all days':<12} risk scales on every day's training folds: {_scales_text(out['pooled'])}")
    return out


def _scales_text(s: dict[str, Any]) -> str:
    return (f"parameter prior {s['param_sd_mm']:g} mm-eq, misfit {s['gp_scale_mm']:g} mm over {s['length_rad']:g} "
            f"rad, residual {s['residual_mm']:g} mm")


def _stats(e: list[float]) -> list[float]:
    return [float(np.mean(e)), float(np.max(e))]


def task_errors(nominal: Any, train: Recording, added: Recording, task: Recording, method: str,
                weight: int) -> list[float]:
    """Position error [mm] of ``method`` fitted on ``train`` + ``added`` at every task pose (rounded to 0.1 um)."""
    rec = train if not len(added) else with_added(train, [added], weight=weight)
    model, _ = Fitter("R1", nominal, rec).fit(method)
    return np.round(errors(model, task).position_mm, 4).tolist()


def fold_masks(nominal: Any, train: Recording) -> list[np.ndarray]:
    """The training poses each held-out fold leaves out (:func:`calibration.methods.topup_sigma.sigma_fold_masks`, the
    folds ``predict``/``evaluate``/``select --given`` choose the residual on): the 5 folds of clusters the
    recommendation holds out (interpolation), the steps of q1 and q4-q6, the clusters at either edge of q2 and of q3
    (extrapolation, ``scripts/studies/extrapolation_folds.py``)."""
    return sigma_fold_masks(Fitter("R1", nominal, train))


FOLD_NAMES = ("random clusters",) * 5 + ("steps", "q2 edges", "q3 edges")


def sigma_fold_errors(nominal: Any, train: Recording) -> dict[str, Any]:
    """Position errors [mm] of pi refitted without each fold of :func:`fold_masks`, at that fold's poses."""
    _, errs = held_out_folds(Fitter("R1", nominal, train))
    return {"fold_errors_mm": [np.round(x, 4).tolist() for x in errs]}


def sigma_scales_for(nominal: Any, train: Recording, folds: dict[str, Any]) -> dict[str, Any]:
    """:func:`calibration.methods.topup.held_out_sigma_scales` on the training recording alone (the fold errors of
    :func:`sigma_fold_errors`), with each fold kind's share beyond 2 sigma under the scales chosen."""
    masks = fold_masks(nominal, train)
    errs = [np.asarray(x) for x in folds["fold_errors_mm"]]
    scales = held_out_sigma_scales(nominal, train.q, masks, errs)
    kinds = {}
    for name in dict.fromkeys(FOLD_NAMES):
        idx = [i for i, n in enumerate(FOLD_NAMES) if n == name]
        sig = np.concatenate([predicted_sigma(nominal, train.q[~masks[i]], train.q[masks[i]],
                                              param_sd_mm=scales.param_sd_mm, residual_mm=scales.residual_mm)
                              for i in idx])
        ee = np.concatenate([errs[i] for i in idx])
        kinds[name] = {"error_mean_mm": float(ee.mean()), "sigma_mean_mm": float(sig.mean()),
                       "share_over_2_sigma": float(np.mean(ee > 2 * sig))}
    return {**scales.to_json(), "folds": kinds}


def sigma_shares(nominal: Any, q_given: np.ndarray, task: Recording, e: np.ndarray, param_sd_mm: float,
                 residual_mm: float) -> dict[str, float]:
    """The predicted position sigma (RMS of the error norm) at every task pose given ``q_given``, against the errors
    ``e``: the share of task poses beyond 2 sigma (and 1 sigma), and the share a Gaussian error of each pose's
    predicted covariance would put beyond 2 sigma (0.74 % isotropic, up to 4.55 % along one axis)."""
    cov = predicted_position_cov(nominal, q_given, task.q, param_sd_mm=param_sd_mm, residual_mm=residual_mm)
    sigma = np.sqrt(np.trace(cov, axis1=1, axis2=2))
    return {"param_sd_mm": param_sd_mm, "residual_mm": residual_mm,
            "sigma_mean_mm": float(sigma.mean()), "sigma_max_mm": float(sigma.max()),
            "share_over_1_sigma": float(np.mean(e > sigma)), "share_over_2_sigma": float(np.mean(e > 2 * sigma)),
            "gaussian_share_over_2_sigma": gaussian_share_over(cov), "corr_sigma_error": float(np.corrcoef(sigma, e)[0, 1])}


def farthest_from(q_train: np.ndarray, q_cand: np.ndarray, k: int) -> np.ndarray:
    """k candidate indices, each the one farthest (joint space, Euclidean) from TRAIN and those chosen before."""
    d = np.min(np.linalg.norm(q_cand[:, None] - q_train[None, ::7], axis=2), axis=1)
    chosen = []
    for _ in range(min(k, len(q_cand))):
        i = int(np.argmax(d))
        chosen.append(i)
        d = np.minimum(d, np.linalg.norm(q_cand - q_cand[i], axis=1))
        d[i] = -1.0
    return np.asarray(chosen, dtype=int)


def _choose(nominal: Any, train: Recording, cand: Recording, task: Recording, k: int, prior: TopupPrior
            ) -> dict[str, Any]:
    res = choose(nominal, train.q, cand.q, task.q, k, prior)
    sigma = {"0": [float(np.mean(res.sigma_before_mm)), float(np.max(res.sigma_before_mm))]}
    return {"order": list(res.order), "sigma": sigma, "criterion": res.criterion_mm2.tolist()}


def _fmt(v: Any) -> str:
    return "      -      " if v is None else f"{v[0]:.3f}/{v[1]:.3f}"


def _line(r: dict[str, Any]) -> str:
    kept = "" if r.get("kept", r["k"]) == r["k"] else f" (kept {r['kept']})"
    return (f"{r['day']:<12} {r['split']:<20} {r['method']:<5} k={r['k']:>3}{kept}  chosen {_fmt(r['chosen'])}  random "
            f"{_fmt(r['random'])}  farthest {_fmt(r['farthest'])}  grid {_fmt(r['grid'])}  all {_fmt(r['all'])}"
            + ("" if r.get("gain_share") is None or not r["k"] else f"  gain {100 * r['gain_share']:.0f}%")
            + "".join(f"  {name} sigma {r[key]['sigma_mean_mm']:.3f} >2s {100 * r[key]['share_over_2_sigma']:.1f}% "
                      f"(gauss {100 * r[key]['gaussian_share_over_2_sigma']:.1f}%)"
                      for key, name in (("sigma", "fixed"), ("sigma_heldout", "held-out")) if key in r))


#: The issue's goals for 21 chosen poses on the interleaved split: task mean and max [mm], share of the all-candidate
#: gain in mean.
GOAL_MEAN_MM, GOAL_MAX_MM, GOAL_GAIN = 0.22, 0.75, 0.8


def goal_lines(rows: list[dict[str, Any]]) -> list[str]:
    """The issue's goals, one line per day, split and method: 21 chosen poses on the interleaved split within
    0.22 mm mean, 0.75 mm max and 80 % of the all-candidate gain; the chosen poses better (in mean) than the median
    random pick; on the halves splits never worse than k = 0."""
    out = []
    for r in rows:
        if not r["k"]:
            continue
        tags = []
        if r["split"] == "interleaved" and r["k"] == 21:
            c = r["chosen"]
            tags += [f"mean {c[0]:.3f} {'ok' if c[0] <= GOAL_MEAN_MM else 'MISSED'}",
                     f"max {c[1]:.3f} {'ok' if c[1] <= GOAL_MAX_MM else 'MISSED'}",
                     "gain -" if r["gain_share"] is None else
                     f"gain {100 * r['gain_share']:.0f}% {'ok' if r['gain_share'] >= GOAL_GAIN else 'MISSED'}"]
        if r.get("random") is not None and r.get("random_worse_share") is not None:
            tags.append(f"beats median random {'ok' if r['chosen'][0] < r['random'][0] else 'MISSED'}")
        if r["split"].startswith("halves"):
            d = r["chosen"][0] - r["grid"][0]
            tags.append(f"vs k=0 {d:+.3f} {'ok' if d <= 0 else 'MISSED'}")
        if tags:
            out.append(f"goal {r['day']:<12} {r['split']:<20} {r['method']:<8} k={r['k']:>3}: " + "; ".join(tags))
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--days", default=",".join(DAYS), help="comma-separated days (" + ", ".join(DAYS) + ")")
    p.add_argument("--splits", default=",".join(SPLITS), help="comma-separated splits")
    p.add_argument("--k", default=",".join(map(str, DEFAULT_K)), help="comma-separated pose counts")
    p.add_argument("--random", type=int, default=20, help="random picks per k (their median is reported)")
    p.add_argument("--methods", default="pi", help="comma-separated methods fitted on grid + picks")
    p.add_argument("--weight", type=int, default=DEFAULT_ADD_WEIGHT,
                   help="weight of each added pose (fit --add-weight); 'all' is always fitted at weight 1")
    p.add_argument("--kind", choices=("pi", "geometric"), help="the design's parametric part (default pi)")
    p.add_argument("--gp-scale-mm", type=float, help="the design's GP scale (default: calibration.methods.topup)")
    p.add_argument("--length-rad", type=float, help="the design's GP length scale (default: calibration.methods.topup)")
    p.add_argument("--tail-weight", type=float, help="the design's G-term weight (default: calibration.methods.topup)")
    p.add_argument("--sigma-k", default="0,21", help="pose counts whose predicted sigma is checked against the errors")
    p.add_argument("--train-clusters", type=int, help="train on the N clusters cellcal select --budget N keeps "
                                                        "(the cell-time comparison: 16 clusters = 112 poses)")
    p.add_argument("--designs", default="farthest,random,all",
                   help="designs fitted beside the chosen poses and the grid: farthest, random, all (each costs fits)")
    p.add_argument("--risk", choices=("default", "day", "none"), default="default",
                   help="how many of the chosen poses to keep (calibration.methods.topup_risk): 'default' as cellcal "
                        "select does (RISK_PRIOR), 'day' with the scales of the day's own training folds, 'none' "
                        "keeps all k")
    p.add_argument("--risk-scales", action="store_true",
                   help="only print the risk scales each day's training folds choose, and all days' together")
    p.add_argument("--cache", type=Path, default=Path("/tmp/bench_topup_cache.json"), help="fit cache (JSON)")
    p.add_argument("--json", type=Path, help="write every row as JSON")
    args = p.parse_args(argv)
    args.days = [d.strip() for d in args.days.split(",")]
    bad = [d for d in args.days if d not in DAYS]
    if bad:
        raise SystemExit(f"unknown day {bad[0]!r}; valid: {', '.join(DAYS)}")
    args.splits = [s.strip() for s in args.splits.split(",")]
    args.k = [int(k) for k in args.k.split(",")]
    args.sigma_k = [int(k) for k in args.sigma_k.split(",") if k.strip()]
    args.methods = [m.strip() for m in args.methods.split(",")]
    args.designs = [d.strip() for d in args.designs.split(",") if d.strip()]
    bad = [d for d in args.designs if d not in ("farthest", "random", "all")]
    if bad:
        raise SystemExit(f"unknown design {bad[0]!r}; valid: farthest, random, all")
    if args.risk_scales:
        out = risk_scales_report(args)
        if args.json:
            args.json.write_text(json.dumps(out, indent=1))
        return 0
    out = run(args)
    for line in goal_lines(out["rows"]):
        print(line)
    if args.json:
        args.json.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
