"""Cross-day rebase variants on 21 poses: how many ordered pairs of days meet 1.25 x the same-day test mean?

As ``scripts/benchmarks/bench_days.py``'s cross-day matrix (model fitted on day A's training recording, tested on day B's test
recording, rebased on the 3 clusters of B's training recording spread widest over (q2, q3)), for one method and
several ways of using the 21 poses:

- ``frames``: both 6-DOF frames (``cellcal rebase``, directions the poses cannot see held);
- ``base``: the base frame only (6);
- ``translations``: both translations only (6);
- ``frames+offsets``: both frames and the joint offsets of joints 2-5 (joint 1's and 6's are frame rotations),
  with a ridge toward the old model's zero offsets, its strength chosen per pair by leave-one-cluster-out over
  the 3 clusters (``inf`` = frames only is a candidate);
- ``frames+refit`` (pi only): both frames, then the pi model's parameters refitted on the 21 poses with a ridge
  toward the old model (mm-scaled, as the CDC local fits), strength chosen the same way, then the frames again;
- ``frames+wrist offsets``: both frames and the joint offsets of joints 4 and 5 (``cellcal rebase --offsets``;
  on these still-wrist poses the SVD holds what it cannot see);
- ``frames+prior``: both frames with a Gaussian prior on their 12 corrections, its mean and covariance those of the
  full rebases (on all training poses) of the other pairs of days that involve neither A nor B (training data of
  other days only), its strength chosen per pair by leave-one-cluster-out over the 3 clusters (``inf`` = no prior);
- ``design clusters: ...``: the same rebases (both frames; ``cellcal rebase``'s choice) on 3 other clusters of
  B's training recording, those the rebase design criterion picks (``cellcal plan --design optimal --for rebase``'s
  D-optimality on the 12 frame directions, at the nominal arm, from the joint angles alone); their training column
  is on the clusters outside those 3;
- ``chosen``: the one of ``frames``, ``base`` and ``translations`` leave-one-cluster-out prefers;
- ``auto (cellcal rebase)``: :func:`calibration.frames.rebase.rebase_auto`, the translations unless both frames do better
  by more than a standard error on the clusters held out in turn.

Every per-pair choice uses the 21 poses only (never B's test recording). The last column, each variant's mean error
on the clusters of B's training recording outside the 21 poses, is what a default variant may be chosen on
(training data only). Also printed: ``frames`` on all of B's training poses, a bound on what frames alone can do.

    python scripts/benchmarks/bench_rebase_variants.py [--method pi] [--json FILE] [--skip-offsets] [--skip-refit] [--skip-prior]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from calibration.data.recording import (  # noqa: E402
    Recording,
    read_recording,
    take_out,  # noqa: E402
)
from calibration.frames.rebase import RebaseProblem, RebaseRefused, corrections, rebase_auto  # noqa: E402
from calibration.frames.rebase_design import REBASE_OFFSETS  # noqa: E402
from calibration.identification import DEFAULT_ORIENTATION_WEIGHT, GeometricProblem  # noqa: E402
from calibration.kinematics import so3  # noqa: E402
from calibration.kinematics.poe import pose_error  # noqa: E402
from calibration.models.rebased import wrap_pose  # noqa: E402
from cell_config import load_cell  # noqa: E402
from scripts.benchmarks.bench_days import (
    CLUSTER_SIZE,
    DATA,
    GOAL_RATIO,
    UNITS,
    design_clusters,
    make_fitter,
    spread_clusters,
)

Predict = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]
FRAME_VARIANTS = {"frames": {}, "base": {"frames": ("base",)}, "translations": {"rotations": False}}
OFFSET_JOINTS = [1, 2, 3, 4]  # joints 2..5 (0-based)
OFFSET_GRID = (np.inf, 1.0, 1e-1, 1e-2, 1e-3)
REFIT_GRID = (np.inf, 10.0, 3.0, 1.0, 0.3)
PRIOR_GRID = (np.inf, 10.0, 1.0, 0.1, 0.01)  # prior residual weight: sqrt(1 / strength) x the mm residuals' scale
W_ROT = float(np.sqrt(2 * DEFAULT_ORIENTATION_WEIGHT))



def auto_or_refused(model: Any, rec: Recording) -> tuple[Any, str]:
    """``cellcal rebase``'s model and choice; the model as given when it refuses (no frame change confirmed)."""
    try:
        rebased, _, choice = rebase_auto(model, rec)
    except RebaseRefused:
        return model, "refused"
    return rebased, choice

def frames_only(model: Any, rec: Recording, **options: Any) -> Predict:
    return RebaseProblem.from_recording(model, rec, **options).solve().model(model).fk


def with_offsets(model: Any, rec: Recording, ridge: float) -> Predict:
    """Frames (their observable directions) and joint offsets of OFFSET_JOINTS, ridge ``ridge`` [1/mm at 1 m]."""
    from scipy.optimize import least_squares

    if np.isinf(ridge):
        return frames_only(model, rec)
    basis = RebaseProblem.from_recording(model, rec).basis
    nb = basis.shape[1]

    def predict(z: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        dq = np.zeros(6)
        dq[OFFSET_JOINTS] = z[nb:]
        T_b, T_t = corrections(basis @ z[:nb])
        return wrap_pose(T_b, *model.fk(q + dq), T_t)

    def residuals(z: np.ndarray) -> np.ndarray:
        R, p = predict(z, rec.q)
        return np.concatenate([(rec.p - p).ravel(), (W_ROT * so3.log(rec.R @ np.swapaxes(R, 1, 2))).ravel(),
                               np.sqrt(ridge) * 1000.0 * z[nb:]])

    z = least_squares(residuals, np.zeros(nb + len(OFFSET_JOINTS)), method="lm", x_scale="jac").x
    return lambda q: predict(z, q)


def with_refit(model: Any, rec: Recording, prior: float) -> Predict:
    """Frames, then the pi parameters with a ridge ``prior`` toward the old ones, then the frames again."""
    first = RebaseProblem.from_recording(model, rec).solve()
    if np.isinf(prior):
        return first.model(model).fk
    c = take_out(rec, first.T_base_correction, first.T_tool_correction)
    kin = model.kinematics
    theta = GeometricProblem(kin, c.q, c.R, c.p, a=DEFAULT_ORIENTATION_WEIGHT, prior_weight=prior / kin.scale(),
                             x_ref=model.theta).solve().x[0]
    inner = model.with_vector(theta)
    return RebaseProblem.from_recording(inner, rec).solve().model(inner).fk


def with_prior(model: Any, rec: Recording, prior: tuple[np.ndarray, np.ndarray] | None, strength: float
               ) -> Predict:
    """Both frames, ``delta`` pulled toward the prior mean with ``||L^-1 (delta - mean)|| / sqrt(strength)`` (L the
    prior covariance's Cholesky factor; residuals in mm, 1 deg as 1 mm); ``inf`` or no prior: frames only."""
    from scipy.optimize import least_squares

    if prior is None or np.isinf(strength):
        return frames_only(model, rec)
    problem = RebaseProblem.from_recording(model, rec)
    mean, L_inv = prior

    def residuals(delta: np.ndarray) -> np.ndarray:
        T_b, T_t = corrections(delta)
        return np.concatenate([problem.frames.residuals(T_b, T_t).ravel(), L_inv @ (delta - mean) / np.sqrt(strength)])

    delta = least_squares(residuals, mean.copy(), method="lm", x_scale="jac").x
    T_b, T_t = corrections(delta)
    return lambda q: wrap_pose(T_b, *model.fk(q), T_t)


def day_prior(full: dict[tuple[str, str], np.ndarray], a: str, b: str) -> tuple[np.ndarray, np.ndarray] | None:
    """Mean (12,) and inverse Cholesky factor (12, 12) of the full rebases of the pairs that involve neither a nor b."""
    d = np.array([v for (x, y), v in full.items() if not {x, y} & {a, b}])
    if len(d) < 3:
        return None
    cov = np.cov(d.T) + 1e-10 * np.eye(12)
    return d.mean(axis=0), np.linalg.inv(np.linalg.cholesky(cov))


def loco_errors(fit: Callable[[Recording], Predict], rec: Recording) -> np.ndarray:
    """Position error of every pose when its cluster is held out from the fit on the others [mm]."""
    cl = rec.clusters(CLUSTER_SIZE)
    errs = []
    for c in np.unique(cl):
        predict, held = fit(rec.subset(cl != c)), rec.subset(cl == c)
        errs.append(pose_error(held.R, held.p, *predict(held.q))[0])
    return np.concatenate(errs)


def chosen(fits: dict[Any, Callable[[Recording], Predict]], rec: Recording) -> Any:
    scores = {k: float(np.mean(loco_errors(f, rec))) for k, f in fits.items()}
    return min(scores, key=scores.get)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--method", default="pi")
    parser.add_argument("--json", help="write every ratio to this JSON file")
    parser.add_argument("--skip-offsets", action="store_true", help="leave out frames+offsets (the slowest)")
    parser.add_argument("--skip-refit", action="store_true", help="leave out frames+refit")
    parser.add_argument("--skip-prior", action="store_true", help="leave out frames+prior")
    args = parser.parse_args(argv)
    if not DATA.exists():
        print(f"shared recordings not found at {DATA}", file=sys.stderr)
        return 2
    start = time.perf_counter()
    robot = load_cell().robot("R1")
    limits = (robot.robot.lower_rad, robot.robot.upper_rad)
    train = {u.name: read_recording(DATA / "PH_grad_data" / u.train, *limits) for u in UNITS}
    tests = {lb: read_recording(DATA / "kinematic_raw_data" / f, *limits) for u in UNITS for lb, f in u.tests}
    unit_of = {lb: u.name for u in UNITS for lb, _ in u.tests}
    models = {u.name: make_fitter(robot, train[u.name]).fit(args.method)[0] for u in UNITS}
    same = {lb: float(np.mean(pose_error(t.R, t.p, *models[unit_of[lb]].fk(t.q))[0])) for lb, t in tests.items()}
    poses = {n: r.subset(np.isin(r.clusters(CLUSTER_SIZE), spread_clusters(r))) for n, r in train.items()}
    picked = {n: design_clusters(robot, r) for n, r in train.items()}
    full = {} if args.skip_prior else {
        (a.name, b.name): RebaseProblem.from_recording(models[a.name], train[b.name]).solve().delta
        for a in UNITS for b in UNITS if a.name != b.name}
    rows: list[dict[str, Any]] = []
    for a in UNITS:
        m = models[a.name]
        for b in UNITS:
            if b.name == a.name:
                continue
            rec = poses[b.name]
            predicts: dict[str, Predict] = {k: frames_only(m, rec, **o) for k, o in FRAME_VARIANTS.items()}
            pick = chosen({k: (lambda r, o=o: frames_only(m, r, **o)) for k, o in FRAME_VARIANTS.items()}, rec)
            predicts["chosen"] = predicts[pick]
            auto, auto_choice = auto_or_refused(m, rec)
            predicts["auto (cellcal rebase)"] = auto.fk
            predicts["frames+wrist offsets"] = frames_only(m, rec, offsets=REBASE_OFFSETS)
            extra: dict[str, Any] = {"chosen": pick, "auto": auto_choice}
            if not args.skip_prior:
                prior = day_prior(full, a.name, b.name)
                k = chosen({g: (lambda r, g=g: with_prior(m, r, prior, g)) for g in PRIOR_GRID}, rec)
                predicts["frames+prior"], extra["prior_strength"] = with_prior(m, rec, prior, k), k
            if not args.skip_offsets:
                ridge = chosen({g: (lambda r, g=g: with_offsets(m, r, g)) for g in OFFSET_GRID}, rec)
                predicts["frames+offsets"], extra["offsets_ridge"] = with_offsets(m, rec, ridge), ridge
            if args.method == "pi" and not args.skip_refit:
                prior = chosen({g: (lambda r, g=g: with_refit(m, r, g)) for g in REFIT_GRID}, rec)
                predicts["frames+refit"], extra["refit_prior"] = with_refit(m, rec, prior), prior
            rest = train[b.name].subset(~np.isin(train[b.name].clusters(CLUSTER_SIZE),
                                                 spread_clusters(train[b.name])))
            heldout = {k: float(np.mean(pose_error(rest.R, rest.p, *p(rest.q))[0])) for k, p in predicts.items()}
            cl = train[b.name].clusters(CLUSTER_SIZE)
            d_rec, d_rest = train[b.name].subset(np.isin(cl, picked[b.name])), \
                train[b.name].subset(~np.isin(cl, picked[b.name]))
            d_auto, extra["design_auto"] = auto_or_refused(m, d_rec)
            extra["design_chosen"] = chosen({k: (lambda r, o=o: frames_only(m, r, **o))
                                             for k, o in FRAME_VARIANTS.items()}, d_rec)
            for k, pr in (("design clusters: frames", frames_only(m, d_rec)),
                          ("design clusters: translations", frames_only(m, d_rec, rotations=False)),
                          ("design clusters: chosen", frames_only(m, d_rec, **FRAME_VARIANTS[extra["design_chosen"]])),
                          ("design clusters: auto", d_auto.fk)):
                predicts[k] = pr
                heldout[k] = float(np.mean(pose_error(d_rest.R, d_rest.p, *pr(d_rest.q))[0]))
            predicts["frames, all training poses"] = frames_only(m, train[b.name])
            for lb, t in tests.items():
                if unit_of[lb] != b.name:
                    continue
                ratios = {k: float(np.mean(pose_error(t.R, t.p, *p(t.q))[0])) / same[lb] for k, p in predicts.items()}
                rows.append({"from": a.name, "tested_on": lb, "same_day_mean_mm": same[lb], "ratios": ratios,
                             "heldout_training_mm": heldout,
                             **{k: (str(v) if isinstance(v, float) else v) for k, v in extra.items()}})
            print(f"{a.name} -> {b.name}: " + ", ".join(f"{k} {v:.2f}" for k, v in rows[-1]["ratios"].items()),
                  file=sys.stderr, flush=True)
    print(f"## Cross-day rebase variants, {args.method}: ordered pairs within {GOAL_RATIO} x the same-day test "
          f"mean ({len(rows)} pairs)\n")
    print("| variant | meet | median ratio | worst ratio | training: mean on B's other clusters, median over pairs "
          "[mm] |\n|---|---|---|---|---|")
    for k in rows[0]["ratios"]:
        r = np.array([row["ratios"][k] for row in rows])
        h = [row["heldout_training_mm"][k] for row in rows if k in row["heldout_training_mm"]]
        print(f"| {k} | {int(np.sum(r <= GOAL_RATIO))} | {np.median(r):.3f} | {r.max():.2f} | "
              f"{f'{np.median(h):.3f}' if h else '–'} |")
    print(f"\n{time.perf_counter() - start:.0f} s")
    if args.json:
        Path(args.json).write_text(json.dumps({"method": args.method, "goal_ratio": GOAL_RATIO, "pairs": rows},
                                              indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
