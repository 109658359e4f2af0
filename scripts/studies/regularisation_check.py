"""Can the training data choose the regularisation of ``pi``? Two training-only rules against the test set.

``pi`` damps parameter directions below ``tolerance`` x the largest singular value (Tikhonov filter, default
1 %). This script asks whether the training recording could have chosen that strength itself:

1. blocked cluster cross-validation over a grid of tolerances (folds of contiguous clusters, as diagnose uses);
2. evidence maximisation (MacKay's fixed point for the prior-to-noise ratio of the linearised fit).

It prints, for each candidate strength, the training-only score and the real test error, so the reader sees
what each rule would have picked and what that pick gives on the test set.

Usage::

    PYTHONPATH=. python scripts/studies/regularisation_check.py [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from calibration.data.recording import Recording, read_recording  # noqa: E402
from calibration.diagnosis.selection import blocked_folds  # noqa: E402
from calibration.evaluation.metrics import errors  # noqa: E402
from calibration.identification import GeometricProblem, rotation_residual_scale, weighted_residuals  # noqa: E402
from calibration.identification.observability import analyse, filter_weights  # noqa: E402
from calibration.kinematics.parameterisation import MinimalParameterisation  # noqa: E402
from calibration.models.pi import PhysicsInformedModel  # noqa: E402
from calibration.physics.extended import ExtendedKinematics  # noqa: E402
from cell_config import load_cell  # noqa: E402

DATA = Path(__file__).resolve().parents[3] / "shared" / "data" / "welding_motoman"
TOLERANCES = (0.003, 0.01, 0.03)
A = 1641.0


def fit(kin: ExtendedKinematics, rec: Recording, ratio: float) -> np.ndarray:
    """The pi fit with the filter at tolerance ``ratio`` (prior weights ``ratio x s_max / scale``)."""
    obs = analyse(kin, rec.q, a=A, tolerance=ratio)
    return GeometricProblem(kin, rec.q, rec.R, rec.p, a=A, prior_weight=filter_weights(obs)).solve().x[0]


def test_error(kin: ExtendedKinematics, theta: np.ndarray, test: Recording) -> dict[str, float]:
    e = errors(PhysicsInformedModel("R1", "pi", kin, theta), test).position_mm
    return {"mean_mm": float(e.mean()), "max_mm": float(e.max())}


def cross_validated(kin: ExtendedKinematics, train: Recording, ratio: float, folds: int = 5) -> dict[str, float]:
    fold = blocked_folds(train.clusters(7), folds)
    e = np.concatenate([errors(PhysicsInformedModel("R1", "pi", kin, fit(kin, train.subset(fold != f), ratio)),
                               train.subset(fold == f)).position_mm for f in range(folds)])
    return {"mean_mm": float(e.mean()), "max_mm": float(e.max()), "rms_mm": float(np.sqrt(np.mean(e**2)))}


def evidence_ratio(kin: ExtendedKinematics, train: Recording, start: float, iterations: int = 30) -> float:
    """MacKay's fixed point: prior precision = gamma / |u|^2, noise variance = RSS / (n - gamma), in the scaled
    coordinates of the filter; returns the resulting ratio to s_max (comparable with a tolerance)."""
    obs = analyse(kin, train.q, a=A)
    s_max, w = obs.singular_values[0], rotation_residual_scale(A)
    ratio = start
    for _ in range(iterations):
        theta = fit(kin, train, ratio)
        R, p, J = kin.jacobian(train.q, theta)
        r, _ = weighted_residuals(train.R, train.p, R, p, w)
        J = J.copy()
        J[:, 3:] *= w
        ev = np.linalg.svd(J.reshape(-1, kin.size) * obs.scale, compute_uv=False) ** 2
        lam2 = (ratio * s_max) ** 2
        gamma = float(np.sum(ev / (ev + lam2)))
        u = theta / obs.scale
        new = float(np.sqrt(gamma / np.sum(u**2) * np.sum(r**2) / (r.size - gamma))) / s_max
        if abs(np.log(new / ratio)) < 1e-3:
            return new
        ratio = new
    return ratio


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", help="write the figures as JSON")
    args = ap.parse_args(argv)
    if not DATA.exists():
        print(f"needs the real R1 recordings in {DATA}", file=sys.stderr)
        return 2
    robot = load_cell().robot("R1")
    limits = (robot.robot.lower_rad, robot.robot.upper_rad)
    train = read_recording(DATA / "PH_grad_data" / "test0801_R1", *limits)
    test = read_recording(DATA / "kinematic_raw_data" / "test0801_R1", *limits)
    kin = ExtendedKinematics(MinimalParameterisation(robot.model(), fit_tool=True))
    out: dict = {"cross_validation": {}, "evidence": {}}
    print("| prior (x s_max) | training CV pos mean / max / rms mm | test pos mean / max mm |")
    print("|---:|---|---|")
    for tol in TOLERANCES:
        cv = cross_validated(kin, train, tol)
        te = test_error(kin, fit(kin, train, tol), test)
        out["cross_validation"][str(tol)] = {"cv": cv, "test": te}
        print(f"| {tol:g} | {cv['mean_mm']:.3f} / {cv['max_mm']:.3f} / {cv['rms_mm']:.3f} | "
              f"{te['mean_mm']:.3f} / {te['max_mm']:.3f} |", flush=True)
    pick = min(TOLERANCES, key=lambda t: out["cross_validation"][str(t)]["cv"]["rms_mm"])
    ratio = evidence_ratio(kin, train, 0.01)
    te = test_error(kin, fit(kin, train, ratio), test)
    out["cv_pick"], out["evidence"] = pick, {"ratio": ratio, "test": te}
    print(f"\nCross-validation picks {pick:g} x s_max. Evidence maximisation picks {ratio:.3g} x s_max: "
          f"test {te['mean_mm']:.3f} / {te['max_mm']:.3f} mm (pi's fixed 0.01 is "
          f"{out['cross_validation']['0.01']['test']['mean_mm']:.3f} / {out['cross_validation']['0.01']['test']['max_mm']:.3f}).")
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1), encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
