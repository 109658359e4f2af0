"""A tool-marker registration error of 18 mm and 0.5 deg: do the CDC methods still beat nls1 on held-out poses?

A synthetic R1 (or R2 with ``--robot R2``; :func:`calibration.diagnosis.synthetic.tool_error_case`: planted geometry 0.5 mm / 0.5 mrad and
0.3 mm of joint compliance under gravity) is measured on the cluster design with joints 1, 4, 5, 6 within 3 deg
(like the shared training recordings) and on random held-out poses that move every joint widely (like their test
recordings);
both recordings get the same tool-marker error (the marker 18 mm off and rotated 0.5 deg in the flange frame).
Every method is fitted twice: on the recording as is (the kinematic fits must absorb the frame error), and with
the frame check's frames-first fit (:func:`calibration.frames.check.framed`, what ``cellcal fit``/``compare`` do).
Prints the frame check's message and the held-out position error mean / max [mm] per method.

With joints 1, 4, 5, 6 within 3 deg (the default) the training data cannot see the marker offset along the
flange's rotation axis, with or without the planted error, and what is left on the widely moving held-out poses
is that unobservable part; ``--train-spread-deg 20`` shows the case where the frame is observable.

Seed 3 is not a frame case (it fails as much with ``--shift-mm 0 --angle-deg 0``): pi and nls1 differ by 0.12 mm
RMS on the training poses and by 1.7 mm on the held-out ones, 99 % of that difference (scaled) along directions the
77-parameter fit sees below its 1 % cutoff: wrist geometry against the structural deflection, which the wrist
band cannot tell apart (scripts/studies/pi_nls1_split.py). pi damps them toward nominal and loses to nls1 there; centred on
nls1's geometry instead it wins (0.59/1.42 against 0.86/2.08 mm, marker error planted) but loses on every shared
day's test recording (0613: 0.31 -> 0.61 mm mean), so the filter stays centred on nominal. Frames first, pi is
now left base-free (:func:`calibration.frames.check.base_free`) and beats nls1 on seed 3 too (0.832/1.942 against
0.859/2.079 mm); the paper's construction still exceeds nls1's max there, as it does with no marker error.
With ``--train-spread-deg 20`` pi and every pi+ method beat nls1 on seed 3. ``--fit-seed`` changes the
networks' initialisation and the held-out folds.

    python scripts/benchmarks/bench_frames.py [--json FILE] [--methods m1,...] [--shift-mm 18] [--angle-deg 0.5] [--seed 0]
                                   [--train-spread-deg 3] [--fit-seed 0] [--robot R1]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from calibration.data.recording import Recording  # noqa: E402
from calibration.diagnosis.synthetic import Design, tool_error_case  # noqa: E402
from calibration.evaluation.metrics import errors  # noqa: E402
from calibration.frames.check import framed  # noqa: E402
from calibration.method_names import CDC_METHODS  # noqa: E402
from calibration.methods.fitter import Fitter
from calibration.methods.options import FitOptions
from calibration.physics.gravity import GravityModel  # noqa: E402
from cell_config import load_cell  # noqa: E402

DEFAULT_METHODS = ("nominal", "nls1", "pi") + CDC_METHODS
def tool_error_case_of(shift_mm: float, angle_deg: float, seed: int, spread_deg: float, arm: str = "R1"
                       ) -> tuple[Any, Recording, Recording]:
    """(cell entry of ``arm``, training recording, held-out recording) of :func:`tool_error_case`, the training
    clusters' joints 1, 4, 5, 6 within ``spread_deg``."""
    robot = load_cell().robot(arm)
    gravity = GravityModel.from_spec(robot.robot, robot.model())
    train, test, _ = tool_error_case(robot.model(), gravity, shift_mm, angle_deg, seed, Design(spread_deg=spread_deg))
    return robot, train, test


def fit_options(fit_seed: int = 0) -> FitOptions:
    """The options of every fit here: the neural seed ``fit_seed``, the twins' rows all kept (no gross-row screening)."""
    return FitOptions(seed=fit_seed, reject_gross_rows=False)


def fitter_on(robot: Any, rec: Recording, fit_seed: int = 0) -> Fitter:
    """:meth:`Fitter.for_arm` of the cell entry's arm on ``rec``, with :func:`fit_options`."""
    return Fitter.for_arm(robot.arm(), rec, options=fit_options(fit_seed))


def run(methods: tuple[str, ...], shift_mm: float, angle_deg: float, seed: int, spread_deg: float,
        fit_seed: int = 0, arm: str = "R1") -> dict[str, Any]:
    robot, train, test = tool_error_case_of(shift_mm, angle_deg, seed, spread_deg, arm)
    framed_fitter, check = framed(robot.arm(), train, options=fit_options(fit_seed))
    out: dict[str, Any] = {"planted": {"tool_mm": shift_mm, "tool_deg": angle_deg, "seed": seed,
                                       "train_spread_deg": spread_deg, "fit_seed": fit_seed, "robot": arm},
                           "check": check.to_json(), "as_is": {}, "frames_first": {}}
    for label, fitter in (("as_is", fitter_on(robot, train, fit_seed)), ("frames_first", framed_fitter)):
        for m in methods:
            t = time.perf_counter()
            model, _ = fitter.fit(m)
            e = errors(model, test).position_mm
            out[label][m] = {"mean": float(np.mean(e)), "max": float(np.max(e)), "seconds": time.perf_counter() - t}
            print(f"{label:12s} {m:8s} {np.mean(e):.3f}/{np.max(e):.3f}", file=sys.stderr, flush=True)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", help="write every figure to this JSON file")
    parser.add_argument("--methods", default=",".join(DEFAULT_METHODS))
    parser.add_argument("--shift-mm", type=float, default=18.0)
    parser.add_argument("--angle-deg", type=float, default=0.5)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--robot", default="R1", choices=("R1", "R2"),
                        help="the arm of the cell whose nominal model and masses the synthetic twin takes (default R1)")
    parser.add_argument("--train-spread-deg", type=float, default=3.0,
                        help="half-range of joints 1, 4, 5 (6: 1.5x) in the training clusters [deg] (default 3, like "
                             "the shared days; 20 lets the training data see the whole marker frame)")
    parser.add_argument("--fit-seed", type=int, default=0,
                        help="FitOptions.seed: the networks' initialisation and the held-out cluster folds (default 0; "
                             "--seed draws the synthetic arm and its recordings)")
    args = parser.parse_args(argv)
    methods = tuple(m.strip() for m in args.methods.split(",") if m.strip())
    out = run(methods, args.shift_mm, args.angle_deg, args.seed, args.train_spread_deg, args.fit_seed, args.robot)
    print(out["check"]["message"] or "frame check: nothing found")
    print(f"\nheld-out position error mean/max [mm], tool marker off by {args.shift_mm} mm / {args.angle_deg} deg, "
          f"training joints 1, 4, 5, 6 within {args.train_spread_deg} deg\n")
    print("| method | as is | frames first |\n|---|---|---|")
    for m in methods:
        a, b = out["as_is"][m], out["frames_first"][m]
        print(f"| {m} | {a['mean']:.3f}/{a['max']:.3f} | {b['mean']:.3f}/{b['max']:.3f} |")
    nls1 = out["frames_first"].get("nls1")
    if nls1:
        worse = [m for m in methods if m in CDC_METHODS and (out["frames_first"][m]["mean"] > nls1["mean"]
                                                              or out["frames_first"][m]["max"] > nls1["max"])]
        print(f"\nCDC methods worse than nls1 (frames first): {', '.join(worse) or 'none'}")
        out["cdc_worse_than_nls1"] = worse
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
