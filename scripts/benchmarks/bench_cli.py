"""Wall time of whole CLI commands, each run as a fresh subprocess (imports, data loading and compilation included).

The commands are the speed goals of issue 14 on the 0801 R1 recordings of ``../shared/data/welding_motoman``:

- ``compare``: ``compare --methods all`` (training PH_grad_data/test0801_R1, test kinematic_raw_data/test0801_R1);
- ``diagnose``: ``diagnose`` on the same training recording, default options;
- ``plan-dual``: ``plan-dual --path sweep:200`` with the compiled planner already in the cache;
- ``plan-dual-cold``: the same into an empty ``CELLCAL_CACHE`` (graph build included; gcc starts alongside the
  interpreted plan, which ends first and cancels it);
- ``make-test`` (only with ``--make-test``, it takes minutes): ``make test``, the README's test command, on the
  built ``.venv`` (the suite on every core).

Each command runs ``--repeat`` times (after one untimed warm-up run for ``plan-dual`` with
``--compile wait``, which fills the cache); the
figure is the median wall time. The 1-minute load average before each run is printed beside it, since a busy
machine stretches every figure, and so is the median CPU time of the command's process tree (user + system),
which a busy machine stretches much less (but which counts the parallel workers of ``compare`` in full).

Bytecode is cached, as a user's Python does after the first run: the repository's packages are compiled once
before timing and ``PYTHONDONTWRITEBYTECODE`` is dropped from the commands' environment (a machine that sets it,
as this one does, would otherwise compile every module of the repository in every run: ~0.3 s per command).

    python scripts/benchmarks/bench_cli.py [--json FILE] [--repeat N] [--only compare,diagnose] [--make-test]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
#: ``../shared/data/welding_motoman`` next to the checkout (or next to a folder holding worktrees).
DATA = next((d / "shared" / "data" / "welding_motoman" for d in ROOT.parents
             if (d / "shared" / "data" / "welding_motoman").exists()), ROOT.parent / "shared" / "data" / "welding_motoman")
GOALS_S = {"compare": 8.0, "diagnose": 5.0, "plan-dual": 3.0, "plan-dual-cold": 3.0, "make-test": 180.0}
NEEDS_DATA = ("compare", "diagnose")
#: The repository's packages, compiled to bytecode before timing.
PACKAGES = ("app", "calibration", "cell_config", "drivers")


def commands(data: Path, out: Path) -> dict[str, list[str]]:
    """The argument list of every benchmarked command."""
    train, test = data / "PH_grad_data" / "test0801_R1", data / "kinematic_raw_data" / "test0801_R1"
    cli = [sys.executable, "-m", "app.cli"]
    return {
        "compare": cli + ["compare", "--robot", "R1", "--train", str(train), "--test", str(test), "--methods", "all",
                          "--json", str(out / "compare.json")],
        "diagnose": cli + ["diagnose", "--robot", "R1", "--train", str(train), "--json", str(out / "diagnose.json")],
        "plan-dual": cli + ["plan-dual", "--path", "sweep:200", "--json", str(out / "plan_dual.json")],
        "plan-dual-cold": cli + ["plan-dual", "--path", "sweep:200", "--json", str(out / "plan_dual.json")],
        "make-test": ["make", "test"],
    }


def load_1min() -> float:
    return os.getloadavg()[0]


def children_cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def run_once(argv: list[str], env: dict[str, str]) -> tuple[float, float]:
    """Wall time and CPU time (user + system, the command's whole process tree) [s] of ``argv`` from the
    repository root; raises when it fails."""
    start, cpu = time.perf_counter(), children_cpu_s()
    proc = subprocess.run(argv, cwd=ROOT, env=env, capture_output=True, text=True)
    seconds, cpu = time.perf_counter() - start, children_cpu_s() - cpu
    if proc.returncode != 0:
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-3:]
        raise RuntimeError(f"{' '.join(argv[:4])} exited {proc.returncode}: " + " | ".join(tail))
    return seconds, cpu


def bench(name: str, argv: list[str], repeat: int, base_env: dict[str, str]) -> dict[str, Any]:
    runs, cpus, loads = [], [], []
    env = dict(base_env)
    if name == "plan-dual":
        run_once(argv + ["--compile", "wait"], env)  # fills the compile cache (a 200-waypoint plan ends first)
    for _ in range(repeat):
        with tempfile.TemporaryDirectory() as cache:
            if name == "plan-dual-cold":
                env["CELLCAL_CACHE"] = cache
            loads.append(load_1min())
            wall, cpu = run_once(argv, env)
            runs.append(wall)
            cpus.append(cpu)
    return {"median_s": round(statistics.median(runs), 3), "runs_s": [round(r, 3) for r in runs],
            "median_cpu_s": round(statistics.median(cpus), 3),
            "load_1min": [round(x, 2) for x in loads], "goal_s": GOALS_S[name],
            "command": " ".join(["python", *argv[1:]] if argv[0] == sys.executable else argv)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", type=Path, help="write the figures as JSON")
    ap.add_argument("--repeat", type=int, default=3, help="runs per command (median reported; default 3)")
    ap.add_argument("--only", help="comma-separated subset of: " + ", ".join(GOALS_S))
    ap.add_argument("--make-test", action="store_true", help="also time the whole test suite (minutes)")
    ap.add_argument("--data", type=Path, default=DATA, help="the welding_motoman data folder")
    args = ap.parse_args(argv)
    if args.repeat < 1:
        ap.error(f"--repeat must be >= 1, got {args.repeat}")
    names = [n for n in GOALS_S if n != "make-test" or args.make_test]
    if args.only:
        names = [n.strip() for n in args.only.split(",")]
        bad = [n for n in names if n not in GOALS_S]
        if bad:
            ap.error(f"--only: unknown command(s) {', '.join(bad)}; valid: {', '.join(GOALS_S)}")
    if any(n in NEEDS_DATA for n in names) and not args.data.is_dir():
        ap.error(f"--data: {args.data} is not a folder (compare and diagnose need the welding_motoman recordings)")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    compiled = subprocess.run([sys.executable, "-m", "compileall", "-q", *PACKAGES], cwd=ROOT, env=env,
                              capture_output=True, text=True)
    if compiled.returncode != 0:
        raise RuntimeError("compileall failed: " + (compiled.stdout + compiled.stderr).strip()[-300:])
    results: dict[str, Any] = {}
    with tempfile.TemporaryDirectory() as out:
        cmds = commands(args.data, Path(out))
        for name in names:
            r = results[name] = bench(name, cmds[name], args.repeat, env)
            print(f"{name:15s} median {r['median_s']:7.2f} s (goal {r['goal_s']:g} s), CPU {r['median_cpu_s']:.2f} s  runs "
                  f"{', '.join(f'{x:.2f}' for x in r['runs_s'])}  load {', '.join(f'{x:.2f}' for x in r['load_1min'])}",
                  flush=True)
    summary = {"cores": os.cpu_count(), "repeat": args.repeat, "bytecode_cached": True, "commands": results}
    if args.json:
        args.json.write_text(json.dumps(summary, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
