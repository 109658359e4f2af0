"""Benchmark the dual-robot planner: warm and cold solve times and relative-pose residuals.

Usage: ``python scripts/benchmarks/bench_dual.py [--n 200] [--json FILE] [--no-compile]``

A 200-waypoint sweep of the workpiece from tucked-in to outstretched, solved with the nominal models and
with a synthetic configuration-dependent (fbf13-style: 13 Fourier terms in q2, q3) model on both arms, and
with the same model hidden behind ``predict`` only (the frozen-parameter fixed-point fallback).
Warm: each waypoint starts from the previous solution. Cold: each starts from the fixed reference guess
(``Q_REF_DEG``); "from q=0" starts from all-zero joints (both wrists singular) as a harder cold case.
Figures are medians over waypoints; residuals are the largest over all runs. The top-level
``warm_ms_median``/``cold_ms_median`` are the worst of the nominal and casadi-CDC runs (synthetic and fitted; the
speed goals); the frozen fallback is reported under ``cdc_frozen``.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # 12x12 algebra: threads only add latency
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from app.dual.paths import Q_REF_DEG, relative_pose, sweep_path  # noqa: E402
from app.dual.planner import DualPlanner, PlannerOptions  # noqa: E402
from calibration.errors import ModelError  # noqa: E402
from calibration.kinematics.parameterisation import MinimalParameterisation  # noqa: E402
from calibration.methods.cdc import geometric_cdc
from calibration.models.cdc import CdcModel  # noqa: E402
from cell_config.loader import load_cell  # noqa: E402


class SyntheticFbf13:
    """fbf13-style interpolator: parameters = basis(q2, q3) (N, 13) @ coefficients (13, m)."""

    kind = "fbf13-synthetic"

    def __init__(self, m: int, seed: int) -> None:
        rng = np.random.default_rng(seed)
        n = m // 4
        scale = np.r_[np.full(2 * n, 0.3), np.full(2 * n, 5e-4)]  # origin offsets [mm], tilts [rad]
        self.coefficients = rng.normal(0.0, 1.0, (13, m)) * scale / np.r_[1.0, np.repeat([1.0, 2.0, 3.0], 4)][:, None]

    def basis(self, x: np.ndarray) -> np.ndarray:
        a, b = x[:, 0], x[:, 1]
        cols = [np.ones(x.shape[0]) * 1.0]
        for k in (1, 2, 3):
            cols += [np.sin(k * a), np.cos(k * a), np.sin(k * b), np.cos(k * b)]
        return np.stack(cols, axis=1)

    def predict(self, x: np.ndarray) -> np.ndarray:
        return self.basis(np.asarray(x, dtype=float)) @ self.coefficients

    def casadi_predict(self, u: object) -> object:
        """The declared casadi form (``Interpolator.casadi_predict``): the same basis on casadi symbols."""
        import casadi as ca

        a, b = u[0], u[1]  # type: ignore[index]
        cols = [1.0]
        for k in (1, 2, 3):
            cols += [ca.sin(k * a), ca.cos(k * a), ca.sin(k * b), ca.cos(k * b)]
        return ca.mtimes(ca.DM(self.coefficients.T), ca.vertcat(*cols))

    def out_of_range(self, x: np.ndarray) -> np.ndarray:
        return np.zeros(len(x), dtype=bool)


class PredictOnly:
    """The same interpolator seen only through ``predict``: exercises the frozen-parameter fixed point."""

    kind = "predict-only"

    def __init__(self, inner: SyntheticFbf13) -> None:
        self.predict, self.out_of_range = inner.predict, inner.out_of_range

    def casadi_predict(self, u: object) -> object:
        """Declines like ``Interpolator.casadi_predict`` of a kind without a casadi form."""
        raise ModelError(f"{self.kind}: no exact casadi form (seen through predict only)")


def fitted_fbf13(cell: object) -> dict[str, object]:
    """fbf13 models fitted by ``Fitter`` on noisy data measured from the simulated cell's twins."""
    from app.dual.sim import fit_model_sets, make_twins

    return fit_model_sets(cell, make_twins(cell), ("fbf13",))["fbf13"]


def run(planner: DualPlanner, n: int) -> dict[str, float]:
    q0 = np.radians(Q_REF_DEG)
    T_rel = relative_pose(planner, q0)
    path = sweep_path(planner, n)
    planner.plan(path[:3], T_rel, q0)  # warm-up (first calls, caches)
    warm = planner.plan(path, T_rel, q0, warm=True)
    cold = planner.plan(path, T_rel, q0, warm=False)
    cold_zero = planner.plan(path, T_rel, np.zeros(12), warm=False)  # q = 0: both wrists singular
    both = warm.waypoints + cold.waypoints + cold_zero.waypoints
    return {"warm_ms_median": float(np.median([w.solve_ms for w in warm.waypoints])),
            "warm_ms_p95": float(np.percentile([w.solve_ms for w in warm.waypoints], 95)),
            "warm_iter_median": float(np.median([w.iterations for w in warm.waypoints])),
            "cold_ms_median": float(np.median([w.solve_ms for w in cold.waypoints])),
            "cold_ms_p95": float(np.percentile([w.solve_ms for w in cold.waypoints], 95)),
            "cold_iter_median": float(np.median([w.iterations for w in cold.waypoints])),
            "cold_zero_ms_median": float(np.median([w.solve_ms for w in cold_zero.waypoints])),
            "failed_warm": len(warm.failed), "failed_cold": len(cold.failed), "failed_cold_zero": len(cold_zero.failed),
            "max_residual_mm": float(max(w.residual_mm for w in both)),
            "max_residual_deg": float(max(w.residual_deg for w in both)),
            "max_track_mm": float(max(w.track_mm for w in warm.waypoints)),
            "min_clearance_mm": float(min(w.clearance_mm for w in warm.waypoints))}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=200, help="waypoints in the sweep")
    ap.add_argument("--json", type=Path, help="write the figures to this file")
    ap.add_argument("--no-compile", action="store_true", help="interpreted casadi function instead of C")
    args = ap.parse_args(argv)
    cell = load_cell()
    opts = PlannerOptions(compile="off" if args.no_compile else "wait")
    models = {}
    for i, name in enumerate(("R1", "R2")):
        par = MinimalParameterisation(cell.robot(name).model())
        models[name] = CdcModel(name, "fbf13", *geometric_cdc(par), SyntheticFbf13(par.size, seed=i))
    results = {"cpus": os.cpu_count(), "n_waypoints": args.n}
    opaque = {n: CdcModel(n, "opaque", m.kinematics, m.theta_ref, PredictOnly(m.interpolator))
              for n, m in models.items()}
    fitted = fitted_fbf13(cell)
    configs = {"nominal": {}, "cdc_fbf13": {"model_R1": models["R1"], "model_R2": models["R2"]},
               "cdc_fitted": {"model_R1": fitted["R1"], "model_R2": fitted["R2"]},
               "cdc_frozen": {"model_R1": opaque["R1"], "model_R2": opaque["R2"]}}
    labels = list(configs)
    for label, kw in configs.items():
        t = time.perf_counter()
        planner = DualPlanner(cell, options=opts, **kw)
        build_s = time.perf_counter() - t
        r = run(planner, args.n)
        r["build_s"] = build_s
        r["model_kinds"] = f"{planner.fks['R1'].kind}/{planner.fks['R2'].kind}"
        results[label] = r
        print(f"{label:10s} ({r['model_kinds']}): build {build_s:.2f} s"
              f" | warm median {r['warm_ms_median']:.2f} ms (p95 {r['warm_ms_p95']:.2f},"
              f" {r['warm_iter_median']:.0f} it) | cold median {r['cold_ms_median']:.2f} ms"
              f" (p95 {r['cold_ms_p95']:.2f}, {r['cold_iter_median']:.0f} it;"
              f" from q=0 {r['cold_zero_ms_median']:.2f} ms)"
              f" | failed {r['failed_warm']}/{r['failed_cold']}/{r['failed_cold_zero']}"
              f" | max residual {r['max_residual_mm']:.2e} mm {r['max_residual_deg']:.2e} deg"
              f" | track {r['max_track_mm']:.2f} mm | clearance {r['min_clearance_mm']:.0f} mm")
    for key in ("warm_ms_median", "cold_ms_median"):  # goal figures: worst of the casadi-expressible models
        results[key] = max(results[k][key] for k in ("nominal", "cdc_fbf13", "cdc_fitted"))
    for key in ("max_residual_mm", "max_residual_deg"):
        results[key] = max(results[k][key] for k in labels)
    ratio = results["cdc_fbf13"]["warm_ms_median"] / results["nominal"]["warm_ms_median"]
    print(f"goal figures (nominal, cdc synthetic + fitted): warm {results['warm_ms_median']:.2f} ms, cold {results['cold_ms_median']:.2f}"
          f" ms (goals 5 / 50 ms); residual (all) {results['max_residual_mm']:.2e} mm,"
          f" {results['max_residual_deg']:.2e} deg (goal 1e-6); warm ratio cdc/nominal {ratio:.2f}")
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
