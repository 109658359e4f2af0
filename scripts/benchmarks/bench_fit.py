"""Benchmark of the CDC fit and of prediction on the R1 training set (or a synthetic one when absent).

Prints the median over repeated runs of: the whole Fourier CDC fit (the global physics-informed fit the local
fits start from and are pulled toward + all local cluster fits as one batched problem + the Fourier
interpolation), its parts, the NN interpolator's fit and the ratio between them, and the fbf13 prediction
throughput.

    python scripts/benchmarks/bench_fit.py [--runs 5] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from calibration.data.recording import read_recording  # noqa: E402
from calibration.methods.fitter import Fitter  # noqa: E402
from cell_config import load_cell  # noqa: E402

TRAIN = ROOT.parent / "shared" / "data" / "welding_motoman" / "PH_grad_data" / "test0801_R1"


def synthetic_training(nominal):
    sys.path.insert(0, str(ROOT))
    from calibration.kinematics.parameterisation import MinimalParameterisation
    from tests.conftest import cluster_design, measure, planted_parameters

    par = MinimalParameterisation(nominal, True)
    truth = par.model(planted_parameters(par))
    q, cluster = cluster_design(step_deg=5.0, spread_wrist=False)
    return measure(truth.fk, q, 0.03, 0.01, 0, cluster)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--json")
    args = parser.parse_args()
    nominal = load_cell().robot("R1").model()
    if TRAIN.exists():
        train, source = read_recording(TRAIN), str(TRAIN)
    else:
        train, source = synthetic_training(nominal), "synthetic (shared data absent)"
    parts: dict[str, list[float]] = {"reference": [], "local": [], "fourier": [], "cdc": [], "nn": []}
    model = None
    for _ in range(args.runs):
        fitter = Fitter("R1", nominal, train)
        t0 = time.perf_counter()
        fitter.physics_informed()
        t1 = time.perf_counter()
        fitter.local_fits()
        t2 = time.perf_counter()
        model, _ = fitter.fit("pi+fbf13")  # the CDC on pi: the reference and local fits timed above
        t3 = time.perf_counter()
        parts["reference"].append(t1 - t0)
        parts["local"].append(t2 - t1)
        parts["fourier"].append(t3 - t2)
        parts["cdc"].append(t3 - t0)
    for _ in range(max(1, args.runs // 2)):
        t0 = time.perf_counter()
        fitter.fit("pi+nn")
        parts["nn"].append(time.perf_counter() - t0)
    q = np.random.default_rng(0).uniform(-1, 1, (100_000, 6))
    model.fk(q[:1000])
    rates = []
    for _ in range(args.runs):
        t0 = time.perf_counter()
        model.fk(q)
        rates.append(len(q) / (time.perf_counter() - t0))
    med = {k: statistics.median(v) for k, v in parts.items()}
    result = {
        "data": source, "samples": len(train), "clusters": int(len(np.unique(train.clusters()))), "runs": args.runs,
        "cdc_fit_seconds_median": med["cdc"], "reference_fit_seconds_median": med["reference"],
        "local_fits_seconds_median": med["local"], "fourier_fit_seconds_median": med["fourier"],
        "nn_fit_seconds_median": med["nn"], "nn_over_cdc_ratio": med["nn"] / med["cdc"],
        "predict_poses_per_second": statistics.median(rates),
    }
    for k, v in result.items():
        print(f"{k:28s} {v:.4g}" if isinstance(v, float) else f"{k:28s} {v}")
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
