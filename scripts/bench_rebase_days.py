"""Does a rebase ever make a model worse on the new day? Every ordered pair of shared R1 days, several cluster triples.

For every source day A (its model fitted on A's training recording) and every test recording T of another day B
(the 48 pairs of ``scripts/bench_days.py``), the model of A is rebased (:func:`calibration.rebase.rebase_auto`,
what ``cellcal rebase`` and ``recalibrate --rebase`` do) on ``--triples`` triples of 7-pose grid clusters of B's
*training* recording, spread over the (q2, q3) grid: the first is bench_days' (farthest-point sampling from the
anchor farthest from the anchors' mean), each next one farthest-point sampling from another start anchor (the
anchors in turn, by angle about their mean). Each result is judged on T only (never used by the rebase):

- worse: the rebased model's mean or max position error on T exceeds the given model's (as is);
- refused: the rebase found no frame change confirmed by its own held-out clusters (nothing handed back);
- within 1.25x: the model handed back (the rebased one; the given one when refused) is within 1.25 times B's own
  same-day calibration with the same method (its mean on T).

The same figures for the rebase before issue 31 (the translations or both frames, chosen on the same held-out
clusters, never refused) come from the same held-out errors, for comparison.

Source fits are cached in ``--cache`` (model files; default /tmp/cellcal_bench_rebase_days), so a rerun takes
minutes. Methods: pi, nls1 and pi+fbf13 (the recommended model needs every method's held-out refits per day:
too slow here; pi+fbf13 stands for the CDC models).

    python scripts/bench_rebase_days.py [--json FILE] [--methods pi,nls1,pi+fbf13] [--triples 5] [--cache DIR]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "scripts"))

from bench_days import CLUSTER_SIZE, DATA, GOAL_RATIO, UNITS, make_fitter, spread_clusters  # noqa: E402
from calibration.models import load_model, save_model  # noqa: E402
from calibration.poe import pose_error  # noqa: E402
from calibration.rebase import CHOICES, choice_options, choose_directions, rebase  # noqa: E402
from calibration.recording import Recording, read_recording  # noqa: E402
from cell_config import load_cell  # noqa: E402

DEFAULT_METHODS = ("pi", "nls1", "pi+fbf13")


def triples(rec: Recording, n: int) -> list[list[int]]:
    """``n`` distinct triples of clusters of ``rec`` spread over (q2, q3) (see the module docstring)."""
    cluster = rec.clusters(CLUSTER_SIZE)
    ids = np.unique(cluster)
    anchors = np.array([rec.q[np.flatnonzero(cluster == c)[0], 1:3] for c in ids])
    out = [sorted(spread_clusters(rec))]
    d = anchors - anchors.mean(axis=0)
    starts = np.argsort(np.arctan2(d[:, 1], d[:, 0]))
    for s in starts[:: max(1, len(starts) // (3 * n))]:
        chosen = [int(s)]
        while len(chosen) < 3:
            dist = np.min(np.linalg.norm(anchors[:, None] - anchors[chosen][None], axis=2), axis=1)
            chosen.append(int(np.argmax(dist)))
        t = sorted(int(ids[i]) for i in chosen)
        if t not in out:
            out.append(t)
        if len(out) == n:
            break
    return out


def fitted(cache: Path, robot: Any, unit: str, train: Recording, method: str) -> Any:
    path = cache / f"{unit.replace(' ', '_')}_{method.replace('+', '_')}.json"
    if not path.exists():
        model, seconds = make_fitter(robot, train).fit(method)
        save_model(model, path)
        print(f"fitted {method} on {unit} in {seconds:.1f} s", file=sys.stderr, flush=True)
    return load_model(path)


def stats(model: Any, rec: Recording) -> dict[str, float]:
    e = pose_error(rec.R, rec.p, *model.fk(rec.q))[0]
    return {"mean": float(np.mean(e)), "max": float(np.max(e))}


def old_choice(means: dict[str, float], errs_sd: dict[str, float]) -> str:
    """The rule before issue 31: translations unless both frames do better by more than a standard error."""
    best = min(("translations", "frames"), key=means.get)
    return next(k for k in ("translations", "frames") if means[k] <= means[best] + errs_sd[best])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json")
    ap.add_argument("--methods", default=",".join(DEFAULT_METHODS))
    ap.add_argument("--triples", type=int, default=5)
    ap.add_argument("--cache", default="/tmp/cellcal_bench_rebase_days")
    args = ap.parse_args(argv)
    methods = [m for m in args.methods.split(",") if m]
    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    robot = load_cell().robot("R1")
    start = time.perf_counter()
    train = {u.name: read_recording(DATA / "PH_grad_data" / u.train) for u in UNITS}
    tests = {label: read_recording(DATA / "kinematic_raw_data" / folder) for u in UNITS for label, folder in u.tests}
    unit_of = {label: u.name for u in UNITS for label, _ in u.tests}
    picks = {u.name: triples(train[u.name], args.triples) for u in UNITS}
    rows: list[dict[str, Any]] = []
    for m in methods:
        models = {u.name: fitted(cache, robot, u.name, train[u.name], m) for u in UNITS}
        own = {label: stats(models[unit_of[label]], t) for label, t in tests.items()}
        for a in UNITS:
            for b in UNITS:
                if b.name == a.name:
                    continue
                for k, triple in enumerate(picks[b.name]):
                    rec = train[b.name].subset(np.isin(train[b.name].clusters(CLUSTER_SIZE), triple))
                    choice, means = choose_directions(models[a.name], rec)
                    rebased = {}
                    for c in ("translations", "frames"):
                        rebased[c] = rebase(models[a.name], rec, **choice_options(c))[0]
                    sd = _standard_errors(models[a.name], rec)
                    old = old_choice(means, sd)
                    new_model = None
                    if choice != "none":
                        new_model = rebase(models[a.name], rec, **choice_options(choice))[0]
                    for label, t in tests.items():
                        if unit_of[label] != b.name:
                            continue
                        given = stats(models[a.name], t)
                        new = given if new_model is None else stats(new_model, t)
                        before = stats(rebased[old], t)
                        rows.append({"method": m, "source": a.name, "test": label, "triple": triple, "k": k,
                                     "choice": choice, "old_choice": old, "held_out_means": means, "given": given,
                                     "rebased": new, "old_rebased": before, "own": own[label]})
        print(f"{m} done at {time.perf_counter() - start:.0f} s", file=sys.stderr, flush=True)
    summary = summarise(rows, methods)
    print_table(summary, args.triples)
    if args.json:
        Path(args.json).write_text(json.dumps({"rows": rows, "summary": summary, "triples": picks,
                                               "seconds": time.perf_counter() - start}, indent=1))
    return 0


def _standard_errors(model: Any, rec: Recording) -> dict[str, float]:
    """Standard error of the held-out mean of the translations and of both frames (the old rule's)."""
    cluster = rec.clusters(CLUSTER_SIZE)
    out = {}
    for c in ("translations", "frames"):
        parts = []
        for g in np.unique(cluster):
            held = rec.subset(cluster == g)
            m = rebase(model, rec.subset(cluster != g), **choice_options(c))[0]
            parts.append(pose_error(held.R, held.p, *m.fk(held.q))[0])
        e = np.concatenate(parts)
        out[c] = float(np.std(e, ddof=1) / np.sqrt(e.size))
    return out


def _worse(r: dict[str, float], given: dict[str, float]) -> bool:
    return r["mean"] > given["mean"] or r["max"] > given["max"]


def summarise(rows: list[dict[str, Any]], methods: list[str]) -> dict[str, Any]:
    out = {}
    for m in methods:
        rs = [r for r in rows if r["method"] == m]
        first = [r for r in rs if r["k"] == 0]
        out[m] = {
            "tried": len(rs), "pairs": len(first),
            "worse_mean": sum(r["rebased"]["mean"] > r["given"]["mean"] for r in rs),
            "worse_max": sum(r["rebased"]["max"] > r["given"]["max"] for r in rs),
            "refused": sum(r["choice"] == "none" for r in rs),
            "within": sum(r["rebased"]["mean"] <= GOAL_RATIO * r["own"]["mean"] for r in rs),
            "within_first_triple": sum(r["rebased"]["mean"] <= GOAL_RATIO * r["own"]["mean"] for r in first),
            "old_worse_mean": sum(r["old_rebased"]["mean"] > r["given"]["mean"] for r in rs),
            "old_worse_max": sum(r["old_rebased"]["max"] > r["given"]["max"] for r in rs),
            "old_within": sum(r["old_rebased"]["mean"] <= GOAL_RATIO * r["own"]["mean"] for r in rs),
            "old_within_first_triple": sum(r["old_rebased"]["mean"] <= GOAL_RATIO * r["own"]["mean"] for r in first),
            "worst_ratio_to_given": max(r["rebased"]["mean"] / r["given"]["mean"] for r in rs),
            "old_worst_ratio_to_given": max(r["old_rebased"]["mean"] / r["given"]["mean"] for r in rs),
            "choices": {c: sum(r["choice"] == c for r in rs) for c in CHOICES},
        }
    return out


def print_table(summary: dict[str, Any], n: int) -> None:
    print(f"\n| method | pairs x triples | worse than given: mean / max | refused | within {GOAL_RATIO}x own | "
          f"within {GOAL_RATIO}x, first triple (pairs) | before issue 31: worse mean / max, within, first triple | "
          "worst mean ratio to given (now / before) | choices |")
    print("|---|---|---|---|---|---|---|---|---|")
    for m, s in summary.items():
        print(f"| {m} | {s['pairs']} x {n} = {s['tried']} | {s['worse_mean']} / {s['worse_max']} | {s['refused']} | "
              f"{s['within']} | {s['within_first_triple']} of {s['pairs']} | {s['old_worse_mean']} / "
              f"{s['old_worse_max']}, {s['old_within']}, {s['old_within_first_triple']} of {s['pairs']} | "
              f"{s['worst_ratio_to_given']:.2f} / {s['old_worst_ratio_to_given']:.2f} | "
              + ", ".join(f"{c} {k}" for c, k in s["choices"].items()) + " |")


if __name__ == "__main__":
    raise SystemExit(main())
