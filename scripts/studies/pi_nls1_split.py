"""Where pi and nls1 differ on a narrow-wrist synthetic R1: on the training poses, on the held-out poses, and along
which of the 77-parameter fit's directions.

The case of ``scripts/benchmarks/bench_frames.py`` (:func:`calibration.diagnosis.synthetic.tool_error_case`, training joints
1, 4, 5, 6 within ``--train-spread-deg``) without a marker error. Prints the RMS / max position difference [mm]
between the pi model and nls1's geometry (no physics terms) on both recordings, the same for pi's geometric block
alone and for its structural deflection alone, and the share of the (scaled) parameter difference that lies along
directions whose singular value is below the filter's cutoff (``FitOptions.tolerance``).

    python scripts/studies/pi_nls1_split.py [--seed 3] [--train-spread-deg 3]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from calibration.physics.layout import block_slice  # noqa: E402
from scripts.benchmarks.bench_frames import fitter_on, tool_error_case_of  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--train-spread-deg", type=float, default=3.0)
    args = parser.parse_args(argv)
    robot, train, test = tool_error_case_of(0.0, 0.0, args.seed, args.train_spread_deg)
    fitter = fitter_on(robot, train)
    pi = fitter.physics_informed()
    kin, g = pi.kinematics, fitter.par.size
    _, ref = fitter.reference("geometric")  # nls1's geometry, every physics term zero

    def diff(a: np.ndarray, b: np.ndarray) -> str:
        out = []
        for rec in (train, test):
            d = np.linalg.norm(kin.pose(rec.q, a)[1] - kin.pose(rec.q, b)[1], axis=1)
            out.append(f"{np.sqrt(np.mean(d ** 2)):.3f}/{d.max():.3f}")
        return " | ".join(out)

    geometry = ref.copy()
    geometry[:g] = pi.theta[:g]
    no_deflection = pi.theta.copy()
    no_deflection[block_slice("deflection", g)] = 0.0
    print(f"position difference RMS/max [mm], seed {args.seed}, training wrist within {args.train_spread_deg} deg\n")
    print("| compared | training poses | held-out poses |\n|---|---|---|")
    print(f"| pi vs nls1 | {diff(pi.theta, ref)} |")
    print(f"| pi's geometry vs nls1 | {diff(geometry, ref)} |")
    print(f"| pi vs pi without its deflection | {diff(pi.theta, no_deflection)} |")
    obs = fitter._pi_observability()
    c = obs.V.T @ ((pi.theta - ref) / obs.scale)
    weak = obs.singular_values < obs.tolerance * obs.singular_values[0]
    print(f"\nshare of the scaled pi - nls1 difference along the {int(weak.sum())} of {weak.size} directions below the "
          f"{obs.tolerance:g} cutoff: {np.sum(c[weak] ** 2) / np.sum(c ** 2):.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
