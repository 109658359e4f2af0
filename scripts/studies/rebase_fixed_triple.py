"""One source model rebased on the same clusters of every other shared R1 day: before and after issue 31.

Issue 31 rebased pi of 0801 on the 7-pose clusters 10, 120 and 230 (in file order) of a day the project does not
have, and doubled that day's test error. This does the same on the shared days' training recordings (the clusters
given by their index in file order), and prints each test recording's position error mean/max [mm] for the model
as given, the rebase before issue 31 (the translations, or both frames in full when their held-out mean beats the
translations' by more than a standard error) and now (:func:`calibration.frames.rebase.choose_directions`; ``none``:
refused, the model as given).

    python scripts/studies/rebase_fixed_triple.py [--source 0801] [--method pi] [--clusters 10,120,230] [--cache DIR]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "scripts"))

from bench_days import CLUSTER_SIZE, DATA, UNITS  # noqa: E402
from bench_rebase_days import fitted, stats  # noqa: E402

from calibration.data.recording import read_recording  # noqa: E402
from calibration.frames.rebase import choice_options, choose_directions, rebase  # noqa: E402
from cell_config import load_cell  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--source", default="0801")
    ap.add_argument("--method", default="pi")
    ap.add_argument("--clusters", default="10,120,230", help="indices of clusters in file order")
    ap.add_argument("--cache", default="/tmp/cellcal_bench_rebase_days")
    args = ap.parse_args(argv)
    index = [int(i) for i in args.clusters.split(",")]
    unit = {u.name: u for u in UNITS}[args.source]
    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    model = fitted(cache, load_cell().robot("R1"), unit.name, read_recording(DATA / "PH_grad_data" / unit.train),
                   args.method)
    fmt = "{mean:.3f}/{max:.3f}".format
    print(f"| {args.method} of {args.source} on | clusters | given | before issue 31 | now |")
    print("|---|---|---|---|---|")
    for u in UNITS:
        if u.name == unit.name:
            continue
        train = read_recording(DATA / "PH_grad_data" / u.train)
        ids = np.unique(train.clusters(CLUSTER_SIZE))
        triple = [int(ids[i]) for i in index]
        rec = train.subset(np.isin(train.clusters(CLUSTER_SIZE), triple))
        old, _ = choose_directions(model, rec, candidates=("translations", "frames"))
        new, _ = choose_directions(model, rec)
        before = rebase(model, rec, **choice_options(old))[0]
        now = model if new == "none" else rebase(model, rec, **choice_options(new))[0]
        for label, folder in u.tests:
            test = read_recording(DATA / "kinematic_raw_data" / folder)
            print(f"| {label} | {triple} | {fmt(**stats(model, test))} | {fmt(**stats(before, test))} ({old}) | "
                  f"{fmt(**stats(now, test))} ({'refused' if new == 'none' else new}) |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
