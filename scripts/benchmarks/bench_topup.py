"""Top-up designs on the real recordings: the protocol of the data README's "Top-up protocol" (issue 33).

For every shared day with a test recording and every split of its test path (1500 stops, rows counted from 0):

- ``interleaved``: candidates = rows whose ``row // 50`` is even, task = the others; ``interleaved-swapped``: the
  reverse;
- ``halves``: candidates = rows 0-749, task = rows 750-1499; ``halves-swapped``: the reverse;

each method is fitted on the day's training grid plus k candidate poses (stand-alone poses,
:func:`calibration.data.recording.with_added`) and judged on the task's measured poses (position mean / max [mm]):

- ``chosen``: the top-up design (:func:`calibration.methods.topup.choose`: joint angles of TRAIN, candidates and task only);
- ``random``: the median (of the mean, and separately of the max) over ``--random`` seeded random picks;
- ``farthest``: farthest-point picks in joint space, each the candidate farthest from TRAIN and those chosen;
- k = 0 (the grid alone) and all candidates.

The chosen design also predicts each task pose's position sigma; the table gives the share of task poses whose
measured error exceeds 2 sigma after the chosen poses (a Gaussian 3-D error norm exceeds 2 sigma_rms in ~7 %).

Fits are cached in ``--cache`` (a JSON file keyed by day, split, method, design, k, seed and the design's
settings), so a rerun with more days or seeds refits only what is new.

    python scripts/benchmarks/bench_topup.py [--days 0613,0725] [--splits interleaved,halves] [--k 0,7,14,21,49]
                                  [--random 20] [--methods pi] [--json FILE] [--cache FILE]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from calibration.data.recording import DEFAULT_ADD_WEIGHT, Recording, read_recording, with_added  # noqa: E402
from calibration.evaluation.metrics import errors  # noqa: E402
from calibration.identification.design import select_recording  # noqa: E402
from calibration.kinematics.parameterisation import MinimalParameterisation  # noqa: E402
from calibration.methods.fitter import Fitter  # noqa: E402
from calibration.methods.topup import TopupPrior, choose, predicted_sigma  # noqa: E402
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
            design_s = time.perf_counter() - t0
            spread = farthest_from(train.q, cand.q, kmax)
            for method in args.methods:
                key = f"{day_key}|{split}|{method}"
                wkey = f"{key}|w{args.weight}"
                w = args.weight
                base = cache.get(f"{key}|grid", lambda: fit_and_judge(nominal, train, None, task, method))
                every = cache.get(f"{key}|all", lambda: fit_and_judge(nominal, train, cand, task, method))
                for k in args.k:
                    row: dict[str, Any] = {"day": day, "split": split, "method": method, "k": k, "weight": w,
                                           "grid": base, "all": every}
                    if k == 0:
                        row.update(chosen=base, farthest=base, random=base)
                    else:
                        order = pick["order"][:k]
                        row["chosen"] = cache.get(f"{wkey}|chosen|{tag}|{k}", lambda: fit_and_judge(
                            nominal, train, cand.subset(np.asarray(order)), task, method, w))
                        row["farthest"] = cache.get(f"{wkey}|farthest|{k}", lambda: fit_and_judge(
                            nominal, train, cand.subset(spread[:k]), task, method, w))
                        draws = [cache.get(f"{wkey}|random|{k}|{s}", lambda: fit_and_judge(
                            nominal, train, cand.subset(np.random.default_rng(s).choice(len(cand), k, replace=False)),
                            task, method, w)) for s in range(args.random)]
                        row["random"] = [float(np.median([d[0] for d in draws])),
                                         float(np.median([d[1] for d in draws]))] if draws else None
                        row["random_worse_share"] = (float(np.mean([d[0] > row["chosen"][0] for d in draws]))
                                                     if draws else None)
                    if k in args.sigma_k:
                        row["sigma"] = cache.get(f"{wkey}|sigma-global|{tag}|{k}", lambda: sigma_check(
                            nominal, train, cand, task, pick["order"][:k], method, w, prior))
                    out["rows"].append(row)
                    print(_line(row), flush=True)
            print(f"# {day} {split}: design {design_s:.1f} s (cached or computed)", flush=True)
    return out


def sigma_check(nominal: Any, train: Recording, cand: Recording, task: Recording, order: list[int], method: str,
                weight: int, prior: TopupPrior) -> dict[str, float]:
    """The design's predicted position sigma (RMS of the error norm) at every task pose after ``order``, against the
    errors of ``method`` fitted with those poses: the share of task poses whose error exceeds 2 sigma (for a
    Gaussian error of that RMS norm, isotropic: P(chi2_3 > 12) = 0.74 %), and over 1 sigma (Gaussian: 39 %)."""
    added = cand.subset(np.asarray(order, dtype=int))
    sigma = predicted_sigma(nominal, np.concatenate([train.q, added.q]), task.q, prior)
    model, _ = Fitter("R1", nominal, with_added(train, [added], weight=weight)).fit(method)
    e = errors(model, task).position_mm
    return {"sigma_mean_mm": float(sigma.mean()), "sigma_max_mm": float(sigma.max()),
            "share_over_1_sigma": float(np.mean(e > sigma)), "share_over_2_sigma": float(np.mean(e > 2 * sigma)),
            "corr_sigma_error": float(np.corrcoef(sigma, e)[0, 1])}


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
    return (f"{r['day']:<12} {r['split']:<20} {r['method']:<5} k={r['k']:>3}  chosen {_fmt(r['chosen'])}  random "
            f"{_fmt(r['random'])}  farthest {_fmt(r['farthest'])}  grid {_fmt(r['grid'])}  all {_fmt(r['all'])}"
            + ("" if "sigma" not in r else f"  sigma {r['sigma']['sigma_mean_mm']:.3f} >2s "
               f"{100 * r['sigma']['share_over_2_sigma']:.1f}% >1s {100 * r['sigma']['share_over_1_sigma']:.0f}%"))


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
    out = run(args)
    if args.json:
        args.json.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
