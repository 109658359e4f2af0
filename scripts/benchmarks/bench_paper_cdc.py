"""Where the paper's FBF figure (0801 test: 0.31 / 0.74 mm mean / max) is lost: an ablation of the CDC construction.

The paper's construction (method ``fbf13``) varies the minimal POE geometry of each cluster around a purely
geometric global fit and interpolates it over (q2, q3) with 13 Fourier terms. This script changes one part at
a time and prints, per variant, the fbf13 position RMS on clusters held out from the training recording (what the
defaults are chosen on) next to the test recording's mean / max (reported, never used to choose):

- the global reference the local fits vary around: nominal, nls1 (truncated SVD: ``fbf13``'s), the geometric
  fit with Tikhonov damping, + tool-marker rotation, + joint compliance, the full pi (``pi+fbf13``'s);
- the local prior strength;
- which parameters the local fits may move (all 27, joints 1-3 + flange, joints 2-3, joints 2-6 + flange);
- the orientation weight a of the local fits (1641 or 0: position only).

    python scripts/benchmarks/bench_paper_cdc.py [--day test0801_R1] [--test test0801_R1] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "scripts"))

from bench_days import DATA, make_fitter  # noqa: E402

from calibration.data.recording import read_recording  # noqa: E402
from calibration.evaluation.metrics import errors  # noqa: E402
from calibration.identification import GeometricProblem  # noqa: E402
from calibration.identification.observability import analyse, filter_weights  # noqa: E402
from calibration.interpolation import make_interpolator  # noqa: E402
from calibration.methods import heldout as robust  # noqa: E402
from calibration.methods.cdc import LocalFits, build_cdc, cluster_anchors
from calibration.models.cdc import CDC_INPUTS  # noqa: E402
from calibration.physics.extended import ExtendedKinematics  # noqa: E402
from calibration.physics.layout import block_slice
from cell_config import load_cell  # noqa: E402

PRIORS = (0.03, 0.3, 1.0, 3.0)


def damped_global(fitter, kin: ExtendedKinematics, blocks: tuple[str, ...]) -> np.ndarray:
    """The global fit of the geometry plus ``blocks``, damped like pi (Tikhonov at the observability cutoff)."""
    g, train = fitter.par.size, fitter.train
    cols = list(range(g))
    for b in blocks:
        sl = block_slice(b, g)
        cols += list(range(sl.start, sl.stop))
    obs = analyse(kin, train.q, a=fitter.options.a, tolerance=fitter.options.tolerance)
    return GeometricProblem(kin, train.q, train.R, train.p, a=fitter.options.a, basis=np.eye(kin.size)[:, cols],
                            prior_weight=filter_weights(obs)).solve().x[0]


def local_fits(fitter, kin, theta, a: float, prior: float, cols: list[int]) -> LocalFits:
    """:func:`calibration.methods.cdc.fit_local` with the local fits restricted to parameter columns ``cols``."""
    train, g = fitter.train, fitter.par.size
    groups, anchor_q = cluster_anchors(train, fitter.options.cluster_size)
    view = kin.geometry_view(theta)
    res = GeometricProblem(view, train.q, train.R, train.p, groups=groups, a=a, prior_weight=prior / view.scale(),
                           x_ref=theta[:g], basis=np.eye(g)[:, cols]).solve()
    return LocalFits(anchor_q[:, list(CDC_INPUTS)], res.x, res.rms_mm, theta, res.converged, res.seconds)


def columns_of(names: list[str], joints: set[int], flange: bool) -> list[int]:
    """Indices of the parameters of ``joints`` (1-based; ``origin3_a_mm``, ``tilt3_b_rad``) and the flange shift."""
    def joint(name: str) -> int | None:
        return None if name.startswith("flange") else int(name.removeprefix("origin").removeprefix("tilt")[0])
    return [i for i, n in enumerate(names) if (joint(n) in joints) or (flange and joint(n) is None)]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--day", default="test0801_R1", help="training folder under PH_grad_data")
    parser.add_argument("--test", default="test0801_R1", help="test folder under kinematic_raw_data")
    parser.add_argument("--json", help="write the figures to this JSON file")
    args = parser.parse_args(argv)
    if not DATA.exists():
        print(f"shared recordings not found at {DATA}", file=sys.stderr)
        return 2
    robot = load_cell().robot("R1")
    limits = (robot.robot.lower_rad, robot.robot.upper_rad)
    train = read_recording(DATA / "PH_grad_data" / args.day, *limits)
    test = read_recording(DATA / "kinematic_raw_data" / args.test, *limits)
    fitter = make_fitter(robot, train)
    kin, g = ExtendedKinematics(fitter.par), fitter.par.size
    groups, _ = cluster_anchors(train, fitter.options.cluster_size)
    names = fitter.par.names()
    geometric = np.zeros(kin.size)
    geometric[:g] = fitter.global_fit()
    references = {"nominal": np.zeros(kin.size), "nls1 (fbf13's)": geometric,
                  "geometry, damped": damped_global(fitter, kin, ()),
                  "+ tool rotation": damped_global(fitter, kin, ("tool",)),
                  "+ tool, compliance": damped_global(fitter, kin, ("tool", "compliance")),
                  "pi (pi+fbf13's)": fitter.physics_informed().theta}
    column_sets = {"all 27": list(range(g)), "joints 1-3 + flange": columns_of(names, {1, 2, 3}, True),
                   "joints 2-3": columns_of(names, {2, 3}, False),
                   "joints 2-6 + flange": columns_of(names, {2, 3, 4, 5, 6}, True)}
    rows = []

    def run(reference: str, prior: float, columns: str, a: float) -> None:
        theta = references[reference]
        local = local_fits(fitter, kin, theta, a, prior, column_sets[columns])
        h = robust.held_out(lambda: make_interpolator("fbf13"), kin, theta, local.anchors, local.x, groups, train,
                            CDC_INPUTS, seed=fitter.options.seed)
        e = errors(build_cdc("R1", "fbf13", kin, local), test).position_mm
        ref = np.linalg.norm(test.p - kin.pose(test.q, theta)[1], axis=1)
        rows.append({"reference": reference, "prior": prior, "columns": columns, "a": a,
                     "heldout_rms_mm": h.rms_mm, "heldout_se_mm": h.se_rms_mm, "test_mean_mm": float(e.mean()),
                     "test_max_mm": float(e.max()), "reference_test_mean_mm": float(ref.mean()),
                     "reference_test_max_mm": float(ref.max())})
        r = rows[-1]
        print(f"| {reference} | {prior:g} | {columns} | {a:g} | "
              f"{r['heldout_rms_mm']:.3f} ± {r['heldout_se_mm']:.3f} | "
              f"{r['reference_test_mean_mm']:.3f}/{r['reference_test_max_mm']:.3f} | "
              f"{r['test_mean_mm']:.3f}/{r['test_max_mm']:.3f} |", flush=True)

    print(f"## fbf13 on {args.day} → {args.test}: held-out clusters of training (choice) and test (report only)\n")
    print("| global reference | local prior | local parameters | a | held-out RMS mm | reference test mean/max | "
          "fbf13 test mean/max |")
    print("|---|---|---|---|---|---|---|")
    for reference in references:
        for prior in PRIORS:
            run(reference, prior, "all 27", fitter.options.a)
    for columns in list(column_sets)[1:]:
        run("nls1 (fbf13's)", 0.3, columns, fitter.options.a)
    run("nls1 (fbf13's)", 0.3, "all 27", 0.0)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
