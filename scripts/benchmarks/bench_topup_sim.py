"""The top-up design from scratch in the simulated cell: a task-driven plan of at most 100 poses against the paper's
1736-pose grid, judged on the task's own configurations (issue 33).

The truth is the simulated cell's arm (:func:`calibration.physics.planted_twin`: planted geometric errors and a
gravity-driven joint compliance of ``--compliance-mm``). The task is a dual plan's R1 waypoints (``cellcal plan-dual
--path sweep:N``). Designs, each measured with Gaussian noise (0.03 mm, 0.02 deg) and fitted with pi:

- ``grid``: the paper's anchor grid (5 deg steps, 248 clusters of 7 = 1736 poses);
- ``optimal``: ``plan --design optimal --task PLAN --budget K`` (:func:`app.collection.plans.design.topup_plan`
  with no poses given): K poses chosen by the top-up criterion among safe candidates.

It also prints the cell time each plan needs by the dry run's estimate (:func:`app.collection.dry_run.summarize_plan`, 20 %
speed, ``--dwell-s`` at each target): the grid, the optimal plan from scratch, and a 21-pose top-up of the grid.

    python scripts/benchmarks/bench_topup_sim.py --plan PLAN.json [--budget 100] [--seeds 0,1,2] [--compliance-mm 0.1]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from app.collection.dry_run import summarize_plan  # noqa: E402
from app.collection.plans.design import topup_plan  # noqa: E402
from app.collection.plans.poses import build_plan, plan_anchor_grid  # noqa: E402
from app.collection.runtime.sim import park_q  # noqa: E402
from app.collection.safety import CellSafety  # noqa: E402
from app.jobs.task import read_task  # noqa: E402
from calibration.data.recording import Recording  # noqa: E402
from calibration.kinematics import so3  # noqa: E402
from calibration.methods.fitter import Fitter  # noqa: E402
from calibration.physics import GravityModel  # noqa: E402
from calibration.physics.twin import PlantedErrors, planted_twin  # noqa: E402
from cell_config import load_cell  # noqa: E402


def measure(twin, q: np.ndarray, rng: np.random.Generator, cluster: np.ndarray) -> Recording:
    R, p = twin.pose(q)
    p = p + rng.normal(0, 0.03, p.shape)
    R = so3.exp(rng.normal(0, np.radians(0.02), p.shape)) @ R
    return Recording(q, p, so3.R_to_quat(R), {"cluster": cluster.astype(float)}, "sim")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--plan", required=True, help="dual plan whose R1 waypoints are the task")
    ap.add_argument("--budget", type=int, default=100)
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--compliance-mm", type=float, default=0.1)
    ap.add_argument("--dwell-s", type=float, default=1.0, help="time at each target for the cell-time estimate [s]")
    args = ap.parse_args(argv)
    cell = load_cell()
    cr = cell.robot("R1")
    nominal = cr.model()
    q_task = read_task(args.plan, "R1", cell)
    grid = plan_anchor_grid("R1")
    q_grid = np.array([t.q for t in grid])
    c_grid = np.array([t.cluster for t in grid])
    safety = CellSafety(cell)
    others = {n: park_q(n) for n in cell.robots if n != "R1"}
    top = topup_plan("R1", nominal, safety, others, np.zeros((0, 6)), q_task, args.budget, q_start=park_q("R1"))
    q_opt = top.plan.q
    print(f"task: {len(q_task)} R1 waypoints; grid {len(q_grid)} poses; optimal {len(q_opt)} poses "
          f"(predicted sigma of a global fit over the task: {top.sigma_after_mm.mean():.3f} mean, "
          f"{top.sigma_after_mm.max():.3f} worst)")
    top21 = topup_plan("R1", nominal, safety, others, q_grid, q_task, 21, q_start=park_q("R1"))
    for name, plan in (("grid", build_plan(grid)), (f"optimal from scratch ({len(q_opt)} poses)", top.plan),
                       ("top-up of the grid (21 poses)", top21.plan)):
        dry = summarize_plan(plan, safety, others, park_q("R1"), per_target_s=args.dwell_s)
        print(f"cell time, {name}: {dry.duration_s / 60:.1f} min ({dry.motion_s / 60:.1f} min in motion, "
              f"{args.dwell_s:g} s at each of {dry.n_targets} targets, 20 % speed)")
    gravity = GravityModel.from_spec(cr.robot, nominal)
    for seed in (int(s) for s in args.seeds.split(",")):
        twin = planted_twin(nominal, PlantedErrors(compliance_mm=args.compliance_mm), seed, gravity=gravity)
        rng = np.random.default_rng(100 + seed)
        _, p_true = twin.pose(q_task)
        row = []
        for name, q, cl in (("grid", q_grid, c_grid), ("optimal", q_opt, np.arange(len(q_opt)))):
            model, _ = Fitter("R1", nominal, measure(twin, q, rng, cl)).fit("pi")
            e = np.linalg.norm(model.fk(q_task)[1] - p_true, axis=1)
            row.append(f"{name} ({len(q)} poses) {e.mean():.3f}/{e.max():.3f}")
        print(f"seed {seed}: pi on the task, mean/max [mm]: " + "; ".join(row), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
