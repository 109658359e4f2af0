"""How many training epochs the neural interpolators (nn, ae) need, on clusters held out from training recordings.

For every R1 training recording of ``../shared/data/welding_motoman/PH_grad_data`` (no test recording is read), on
the local cluster fits of both CDC references (the geometric one and pi) as ``compare`` makes them: train ``nn`` and
``ae`` on each of the 5 folds' training clusters with ``max_iter`` epochs (the check of :mod:`calibration.methods.heldout`,
all 5 folds) and print the held-out position RMS and its ratio to the reference's per epoch budget. Training is
deterministic and Adam's schedule depends on the step count only, so a run of E epochs is exactly the first E
epochs of a longer run: the figures are those of stopping the 300-epoch training early.

``--hidden`` sets the hidden widths to compare (``200x200x200``: three layers of 200; for ``ae`` the encoder's,
mirrored by the decoder) and ``--seeds`` the training seeds (the spread over seeds of one configuration is the
noise a change of configuration is judged against).

    python scripts/studies/neural_epochs.py [--json FILE] [--days test0801_R1,...] [--epochs 75,150,300]
        [--hidden 200x200x200,64x64x64] [--seeds 0,1] [--kinds nn,ae]
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from calibration import workers
from calibration.data.recording import read_recording  # noqa: E402
from calibration.interpolation import make_interpolator  # noqa: E402
from calibration.methods import heldout as robust  # noqa: E402
from calibration.methods.cdc import cluster_anchors
from calibration.methods.fitter import Fitter  # noqa: E402
from calibration.models.cdc import CDC_INPUTS  # noqa: E402
from cell_config import load_cell  # noqa: E402
from scripts.benchmarks.bench_days import DATA  # noqa: E402
from scripts.studies.heldout_folds import days_parser


def main(argv: list[str] | None = None) -> int:
    ap = days_parser(__doc__)
    ap.add_argument("--epochs", default="75,150,300")
    ap.add_argument("--hidden", default="200x200x200", help="comma-separated hidden widths, e.g. 200x200x200,64x64x64")
    ap.add_argument("--seeds", default="0", help="comma-separated training seeds")
    ap.add_argument("--kinds", default="nn,ae")
    args = ap.parse_args(argv)
    epochs = [int(e) for e in args.epochs.split(",")]
    widths = [tuple(int(w) for w in h.split("x")) for h in args.hidden.split(",")]
    seeds = [int(s) for s in args.seeds.split(",")]
    robot = load_cell().robot("R1")
    rows = []
    for day in args.days.split(","):
        train = read_recording(DATA / "PH_grad_data" / day, robot.robot.lower_rad, robot.robot.upper_rad)
        fitter = Fitter.for_arm(robot.arm(), train)
        groups, _ = cluster_anchors(train, fitter.options.cluster_size)
        for reference in ("geometric", "pi"):
            (kin, theta), local = fitter.reference(reference), fitter.local_fits(reference)
            for kind, hidden, seed in ((k, h, s) for k in args.kinds.split(",") for h in widths for s in seeds):
                t0 = time.perf_counter()
                by_e = {e: robust.held_out(lambda: make_interpolator(kind, random_state=seed, max_iter=e,
                                                                     hidden=hidden),
                                           kin, theta, local.anchors, local.x, groups, train, CDC_INPUTS,
                                           seed=fitter.options.seed, workers=workers.default_workers(robust.N_FOLDS))
                        for e in epochs}
                name = "x".join(map(str, hidden))
                rows.append({"day": day, "reference": reference, "kind": kind, "hidden": name, "seed": seed,
                             "seconds": round(time.perf_counter() - t0, 1),
                             "rms_mm": {e: round(h.rms_mm, 4) for e, h in by_e.items()},
                             "se_mm": {e: round(h.se_rms_mm, 4) for e, h in by_e.items()},
                             "ratio": {e: round(h.ratio, 4) for e, h in by_e.items()}})
                print(f"{day:22s} {reference:9s} {kind:3s} {name:12s} seed {seed} held-out RMS mm (ratio to "
                      f"reference) by epochs: " + "  ".join(f"{e}: {h.rms_mm:.4f} ({h.ratio:.3f})"
                                                          for e, h in by_e.items()), flush=True)
        if args.json:  # after every day: a long run interrupted keeps what it has
            args.json.write_text(json.dumps(rows, indent=2) + "\n")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
