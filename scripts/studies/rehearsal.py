"""The real-cell rehearsal end to end, as separate OS processes, with its figures.

Starts ``fake-controller``, ``fake-motive`` (its twins in a hidden mocap world frame) and ``mocap-bridge`` on a
private copy of ``cell_config/rehearsal.yaml``, then runs, as a user would, ``cellcal register`` for R1 and R2 and
``cellcal collect`` of a small plan for each arm (no ``--sim``). Afterwards it plays the truth: it compares the
registrations with the hidden frames, R2's base from the data with the true one and with ``cell.yaml``, and every
recorded sample with the twin's pose in the base frame.

    python scripts/studies/rehearsal.py [--json FILE] [--seed 5] [--pure] [--targets 14]

``--pure`` gives the twins no kinematic error (only the hidden frames), so the registration can recover the world
frame exactly; by default the twins carry the simulated cell's planted joint-origin errors, axis tilts and gravity
compliance, part of which any frame registration absorbs (the base frame and joint 1's geometry are not separable).
"""

from __future__ import annotations

import argparse
import json
import sqlite3
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from app.collection.rehearsal import Rehearsal, run_cellcal, small_plan, write_rehearsal_cell  # noqa: E402
from calibration.data.recording import read_recording  # noqa: E402
from calibration.frames.registration import transform_difference  # noqa: E402
from calibration.physics import PlantedErrors  # noqa: E402
from cell_config import load_cell  # noqa: E402
from drivers.sim.rehearsal import hidden_frames, rehearsal_truths  # noqa: E402

PURE = ("--origin-std-mm", "0", "--tilt-std-deg", "0", "--compliance-mm", "0")


def _run(cell: Path, *args: str) -> dict:
    t0 = time.monotonic()
    done = run_cellcal(cell, *args, timeout_s=600)
    if done.returncode != 0:
        raise SystemExit(f"cellcal {' '.join(args)} failed:\n{done.stdout}\n{done.stderr}")
    return {"seconds": round(time.monotonic() - t0, 2), "stdout": done.stdout}


def register(cell_path: Path, work: Path) -> dict:
    out = {}
    for robot in ("R1", "R2"):
        run = _run(cell_path, "register", "--robot", robot, "--yes", "--speed", "1", "--no-progress", "--json",
                   str(work / f"reg_{robot}.json"))
        out[robot] = {**json.loads((work / f"reg_{robot}.json").read_text()), "seconds": run["seconds"]}
    return out


def collect(cell_path: Path, work: Path, n: int) -> dict:
    out = {}
    for robot in ("R1", "R2"):
        plan = small_plan(cell_path, robot, work / f"{robot}_plan.json", n)
        run = _run(cell_path, "collect", "--robot", robot, "--plan", str(plan), "--session", str(work / robot),
                   "--yes", "--speed", "1", "--no-progress", "--json", str(work / f"collect_{robot}.json"))
        _run(cell_path, "export", "--session", str(work / robot), "--out", str(work / f"{robot}.csv"))
        out[robot] = {**json.loads((work / f"collect_{robot}.json").read_text()), "wall_seconds": run["seconds"]}
    return out


def truth_check(cell_path: Path, work: Path, seed: int, pure: bool, regs: dict, cols: dict) -> dict:
    """What only the fake knows, against what cellcal found and recorded."""
    cell = load_cell(cell_path)
    hidden = hidden_frames(cell, seed)
    truths = rehearsal_truths(cell, seed, PlantedErrors(0.0, 0.0, 0.0)) if pure else rehearsal_truths(cell, seed)
    out: dict = {}
    for robot in ("R1", "R2"):
        d_mm, d_deg = transform_difference(cell.registration[robot].T_world_base, hidden[robot].T_world_base)
        spec = cell.robot(robot).robot
        rec = read_recording(work / f"{robot}.csv", spec.lower_rad, spec.upper_rad)
        R, p = truths[robot].pose(rec.q)
        p_true = p + np.einsum("nij,j->ni", R, hidden[robot].T_tool_marker[:3, 3])
        _, p_nom = cell.robot(robot).model().fk(rec.q)
        with sqlite3.connect(work / robot / "session.sqlite") as con:
            idx = [r[0] for r in con.execute("SELECT target_index FROM samples WHERE status = 'ok'")]
        out[robot] = {
            "world_base_vs_hidden_mm": d_mm, "world_base_vs_hidden_deg": d_deg,
            "registration_rms_mm": regs[robot]["rms_mm"], "registration_rms_deg": regs[robot]["rms_deg"],
            "registration_sigma_world_base": regs[robot]["sigma_world_base"],
            "registration_seconds": regs[robot]["seconds"],
            "targets": cols[robot]["targets"], "measured": cols[robot]["measured"],
            "distinct_targets": len(set(idx)), "duplicates": len(idx) - len(set(idx)),
            "mocap_frames_received": cols[robot]["mocap_frames_received"],
            "collect_seconds": cols[robot]["wall_seconds"],
            "samples_vs_truth_max_mm": float(np.max(np.linalg.norm(rec.p - p_true, axis=1))),
            "recording_nominal_mean_mm": float(np.mean(np.linalg.norm(rec.p - p_nom, axis=1))),
            "twin_nominal_mean_mm": float(np.mean(np.linalg.norm(p_true - p_nom, axis=1))),
        }
    T_true = np.linalg.inv(hidden["R1"].T_world_base) @ hidden["R2"].T_world_base
    T_found = np.linalg.inv(cell.registration["R1"].T_world_base) @ cell.registration["R2"].T_world_base
    T_yaml = cell.robot("R2").T_cell_base
    out["R2_base_in_R1"] = {"found_vs_cell_yaml": transform_difference(T_found, T_yaml),
                            "true_vs_cell_yaml": transform_difference(T_true, T_yaml),
                            "found_vs_true": transform_difference(T_found, T_true)}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", help="write the figures as JSON")
    ap.add_argument("--seed", type=int, default=5, help="the fake Motive's seed (hidden frames, twins)")
    ap.add_argument("--pure", action="store_true", help="twins without kinematic error")
    ap.add_argument("--targets", type=int, default=14, help="targets per arm in the collection")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="cellcal-rehearsal-") as tmp:
        work = Path(tmp)
        cell_path = write_rehearsal_cell(work)
        with Rehearsal(cell_path, *(PURE if args.pure else ()), seed=args.seed) as r:
            regs = register(cell_path, work)
            cols = collect(cell_path, work, args.targets)
            figures = truth_check(cell_path, work, args.seed, args.pure, regs, cols)
        figures["twin"] = "pure frames" if args.pure else "planted kinematic errors (simulated cell's)"
        figures["bridge_output"] = r.bridge.output.strip().splitlines()[-1]
    print(json.dumps(figures, indent=2))
    if args.json:
        Path(args.json).write_text(json.dumps(figures, indent=2))


if __name__ == "__main__":
    main()
