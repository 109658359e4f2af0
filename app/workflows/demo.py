"""The main job on the simulated cell: collect both arms over Zenoh, fit every method, evaluate, report.

Steps, all on the packaged cell description with no hardware:

1. :class:`~app.collection.runtime.sim.SimCell`: both arms simulated with their own planted geometric errors and a
   gravity-like joint compliance, the mocap simulated and carried over real Zenoh sessions on loopback.
2. For each arm in turn (the other one parked and read live for the collision checks): a guided collection
   session over the anchor grid (10 deg steps by default, the paper's 5 deg / 248 anchors with ``full``),
   single-joint CPA sweeps and random validation poses.
3. The session exported to recordings (training = anchors + perturbations, CPA sweeps, test = validation).
4. Every method fitted per arm (:func:`~app.workflows.compare.run_comparison`), models saved, test-set statistics.
5. ``report.html`` (tables and plots), ``summary.json``, the recordings (CSV) and the models (YAML).

Output folder layout::

    DIR/report.html  DIR/summary.json
    DIR/R1/{train,cpa,test}.csv  DIR/R1/models/<method>.yaml  DIR/R1/report.md  DIR/R1/*.png
    DIR/R1/session/session.sqlite   (and the same for R2)
"""

from __future__ import annotations

import json
import logging
import math
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from app.collection.collect import DEMO_COLLECT, CollectConfig, SessionResult, collect_arm, export
from app.collection.plans.session import PlanSpec, session_plan
from app.collection.runtime.sim import SimCell, SimCellOptions
from app.collection.safety import CellSafety
from app.progress import EpochBar
from app.reports.provenance import provenance, with_provenance
from app.reports.sections import write_demo_report
from app.workflows.compare import run_comparison
from calibration.data.files import atomic_write_text
from calibration.data.recording import Recording, read_recording
from calibration.errors import ConfigError, DataError
from calibration.method_names import METHODS
from calibration.methods.fitter import Fitter
from calibration.methods.options import FitOptions
from calibration.models import ConstantModel, save_model
from cell_config.loader import CellSpec

log = logging.getLogger("cellcal.app")

#: Methods the demo fits: every method (the neural ones take ~3 s each on the reduced grid).
DEMO_METHODS = METHODS


@dataclass(frozen=True)
class DemoConfig:
    """What the demo runs.

    Attributes:
        full: the paper's 248-anchor design (5 deg steps) instead of the reduced 10 deg grid.
        anchor_step_deg: the anchor grid's q2/q3 step [deg]; None: 5 with ``full``, else 10 (a coarser grid makes
            a short demo, e.g. for tests).
        seed: seed of the planted errors, the mocap noise and the validation poses.
        n_validation: validation poses per arm (the test set).
        robots: the arms to calibrate, in order.
        methods: methods to fit; None picks DEMO_METHODS.
        sim: the simulated cell (its seed is replaced by ``seed``).
        collect: collection settings.
        progress: show progress bars.
        tolerance: the acceptance :class:`~app.reports.acceptance.Tolerance` (None: 1 mm and 1 deg).
        report_dir: where ``report.html`` goes (None: the output folder).
    """

    full: bool = False
    anchor_step_deg: float | None = None
    seed: int = 0
    n_validation: int = 50
    robots: tuple[str, ...] = ("R1", "R2")
    methods: tuple[str, ...] | None = None
    sim: SimCellOptions = field(default_factory=SimCellOptions)
    collect: CollectConfig = DEMO_COLLECT
    progress: bool = True
    tolerance: Any = None
    report_dir: Path | None = None

    def chosen_methods(self) -> tuple[tuple[str, ...], dict[str, str]]:
        """(methods to fit, method -> reason for each one left out)."""
        methods = DEMO_METHODS if self.methods is None else tuple(self.methods)
        return methods, {m: "not requested" for m in DEMO_METHODS if m not in methods}

    def plan_spec(self) -> PlanSpec:
        step = self.anchor_step_deg or (5.0 if self.full else 10.0)
        return PlanSpec(q2_step_deg=step, q3_step_deg=step, cpa=True, n_validation=self.n_validation, seed=self.seed)


@dataclass(frozen=True)
class DemoResult:
    """What the demo produced.

    Attributes:
        out_dir: the output folder.
        report: ``report.html``.
        summary: the content of ``summary.json``.
        seconds: wall time of the whole run [s].
    """

    out_dir: Path
    report: Path
    summary: dict[str, Any]
    seconds: float


@dataclass(frozen=True)
class Recordings:
    """One arm's recordings: files and the loaded training, CPA and test sets."""

    train_csv: Path
    cpa_csv: Path | None
    test_csv: Path
    train: Recording
    cpa: Recording | None
    test: Recording


def export_recordings(session_dir: Path, out_dir: Path, cell: CellSpec, robot: str) -> Recordings:
    """Export a session to ``train.csv`` (anchors + perturbations), ``cpa.csv`` and ``test.csv`` (validation).

    Raises:
        DataError: the session has no training or no validation sample.
    """

    spec = cell.robot(robot).robot
    train_csv, cpa_path, test_csv = out_dir / "train.csv", out_dir / "cpa.csv", out_dir / "test.csv"
    export(session_dir, train_csv, kinds=("anchor", "perturb"))
    cpa_csv: Path | None = cpa_path
    try:
        export(session_dir, cpa_path, kinds=("cpa",))
    except DataError:
        cpa_csv = None
    export(session_dir, test_csv, kinds=("validation",))

    def read(p: Path) -> Recording:
        return read_recording(p, spec.lower_rad, spec.upper_rad)

    return Recordings(train_csv, cpa_csv, test_csv, read(train_csv), read(cpa_csv) if cpa_csv else None,
                      read(test_csv))


def fit_and_compare(cell: CellSpec, robot: str, rec: Recordings, methods: tuple[str, ...], model_dir: Path,
                    progress: bool = True) -> Any:
    """Fit ``methods`` on the training set, evaluate them on the test set, save every model as YAML."""

    epochs = EpochBar(f"{robot} nn/ae training") if progress else None
    fitter = Fitter.for_arm(cell.robot(robot).arm(), rec.train, rec.cpa, FitOptions(epoch_progress=epochs))
    cmp = run_comparison(fitter, rec.test, methods, progress)
    model_dir.mkdir(parents=True, exist_ok=True)
    record = provenance([("train", rec.train_csv), ("cpa", rec.cpa_csv)])
    for m, model in cmp.models.items():
        save_model(with_provenance(model, record), model_dir / f"{m}.yaml")
    return cmp


def robot_summary(session: SessionResult, rec: Recordings, cmp: Any, left_out: dict[str, str]) -> dict[str, Any]:
    """One arm's entry of ``summary.json`` (test statistics in the ``compare`` JSON shape)."""
    full = cmp.to_json()
    methods = {m: {"test": v["test"], "fit_seconds": v["fit_seconds"], "n_parameters": v["n_parameters"]}
               for m, v in full["methods"].items()}
    skipped = dict(full["skipped"])
    skipped.update(left_out)
    return {"samples": session.n_ok, "targets": session.n_targets, "skipped_targets": session.n_skipped,
            "train_samples": len(rec.train), "cpa_samples": 0 if rec.cpa is None else len(rec.cpa),
            "test_samples": len(rec.test), "collect_seconds": session.elapsed_s, "methods": methods,
            "skipped_methods": skipped, "recommended": full["recommended"],
            "observability_warning": full["analysis"].get("observability", {}).get("warning") or ""}


#: The files a demo run writes at the top of its output folder.
TOP_FILES = ("report.html", "summary.json")


def _demo_folder(d: Path) -> bool:
    """Whether the robot folder ``d`` is a demo run's: it holds the demo's ``plan.json`` or ``session/``."""
    return d.is_dir() and ((d / "plan.json").exists() or (d / "session").is_dir())


def clear_previous(out: Path, robots: tuple[str, ...]) -> None:
    """Remove what an earlier demo run wrote into ``out`` (its robot folders, report and summary), nothing else.

    A robot folder counts as the demo's when it holds the demo's ``plan.json`` or ``session/``.
    """
    import shutil

    for robot in robots:
        d = out / robot
        if _demo_folder(d):
            log.info("removing the previous demo run's %s", d)
            shutil.rmtree(d)
    for name in TOP_FILES:
        (out / name).unlink(missing_ok=True)


def left_behind(out: Path, robots: tuple[str, ...]) -> list[str]:
    """What a demo run (finished or stopped part-way) has in ``out``, relative to it, folders with a trailing ``/``:
    each demo robot folder's entries, then the report and summary. These are what :func:`clear_previous` removes."""
    left = [f"{robot}/{e.name}{'/' if e.is_dir() else ''}" for robot in robots if _demo_folder(out / robot)
            for e in sorted((out / robot).iterdir())]
    return left + [name for name in TOP_FILES if (out / name).exists()]


def stop_note(out: Path, robots: tuple[str, ...]) -> str:
    """The stop line's note for a demo stopped (Ctrl-C) part-way: what it left in ``out`` and what a re-run does
    with it. Nothing is deleted on a stop (a user's data is never removed silently); a re-run replaces it."""
    left = left_behind(out, robots)
    if not left:
        return f" (nothing left in {out})"
    return (f" (left in {out}: {', '.join(left)}; nothing was deleted: a re-run of cellcal demo --out {out} "
            "removes these and starts over)")


def run_demo(out_dir: str | Path, cell: CellSpec, config: DemoConfig = DemoConfig()) -> DemoResult:
    """Run the whole demo into ``out_dir`` (created; an earlier demo run there is replaced).

    Raises:
        ConfigError: unknown robot, or ``out_dir`` is a file.
        UnsafeTarget: a planned target is unsafe (nothing moves).
        SessionAborted: a collection session failed repeatedly.
    """

    t0 = time.monotonic()
    out = Path(out_dir)
    for robot in config.robots:
        cell.robot(robot)
    if out.exists() and not out.is_dir():
        raise ConfigError(out, "", "the demo output must be a folder")
    clear_previous(out, tuple(cell.robots))
    methods, left_out = config.chosen_methods()
    safety = CellSafety(cell)
    sim_config = replace(config.sim, seed=config.seed, deterministic=True)  # the same seed, the same numbers
    robots: dict[str, Any] = {}
    comparisons: dict[str, Any] = {}
    tests: dict[str, Any] = {}
    with SimCell(cell, sim_config, robots=tuple(cell.robots)) as sim:
        sessions: dict[str, SessionResult] = {}
        for robot in config.robots:
            parked = {n: d.read_joints().q for n, d in sim.others(robot).items()}
            plan = session_plan(robot, safety, parked, config.plan_spec(), sim.drivers[robot].read_joints().q)
            (out / robot).mkdir(parents=True, exist_ok=True)
            plan.save(out / robot / "plan.json")
            log.info("%s: %d targets (%s)", robot, len(plan), plan.params)
            sessions[robot] = collect_arm(sim, safety, robot, plan, out / robot / "session", config.collect,
                                          progress=config.progress, clock=sim.clock.now,
                                          model=ConstantModel(robot, "nominal", cell.robot(robot).model(), 0, {}),
                                          model_name=f"the nominal {robot}")  # -v: each target's residual
        frames = sim.frames_received
    for robot in config.robots:
        rec = export_recordings(out / robot / "session", out / robot, cell, robot)
        cmp = fit_and_compare(cell, robot, rec, methods, out / robot / "models", config.progress)
        comparisons[robot], tests[robot] = cmp, rec.test
        robots[robot] = robot_summary(sessions[robot], rec, cmp, left_out)
    seconds = time.monotonic() - t0
    summary = {"robots": robots, "mocap_frames_received": frames, "seconds": round(seconds, 3),
               "config": {"full": config.full, "seed": config.seed, "time_scale": sim_config.time_scale,
                          "mocap_rate_hz": sim_config.mocap_rate_hz, "anchor_step_deg": config.plan_spec().q2_step_deg,
                          "validation_poses": config.n_validation, "methods": list(methods)},
               "planted": {"origin_std_mm": sim_config.errors.offset_std_mm,
                           "tilt_std_deg": math.degrees(sim_config.errors.tilt_std_rad),
                           "compliance_rms_mm": sim_config.errors.compliance_mm, "mocap_noise_mm": sim_config.noise_pos_mm}}
    inputs = [(f"{robot} {kind}", path) for robot in config.robots for kind in ("train", "cpa", "test")
              if (path := out / robot / f"{kind}.csv").exists()]
    report = write_demo_report(out, comparisons, tests, summary, config.tolerance, config.report_dir, inputs)
    seconds = time.monotonic() - t0
    summary["seconds"] = round(seconds, 3)
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=1))
    return DemoResult(out, report, summary, seconds)


def summary_table(summary: dict[str, Any]) -> str:
    """Plain-text table: per robot and method, test position mean / max [mm] and orientation mean [deg]."""
    width = max([6] + [len(m) for r in summary["robots"].values() for m in r["methods"]])
    lines = [f"{'robot':<5} {'method':<{width}} {'pos mean mm':>11} {'pos max mm':>10} {'ori mean deg':>12}"]
    for robot, r in summary["robots"].items():
        for m, v in r["methods"].items():
            p, o = v["test"]["position_mm"], v["test"]["orientation_deg"]
            lines.append(f"{robot:<5} {m:<{width}} {p['mean']:>11.3f} {p['max']:>10.3f} {o['mean']:>12.4f}")
        by_reason: dict[str, list[str]] = {}
        for m, reason in r["skipped_methods"].items():
            by_reason.setdefault(reason, []).append(m)
        for reason, ms in by_reason.items():  # one line per reason, not one per method (20 "not requested")
            lines.append(f"{robot:<5} skipped ({reason}): {', '.join(ms)}" if len(ms) > 1
                         else f"{robot:<5} {ms[0]:<{width}} skipped: {reason}")
        lines.append(f"{robot:<5} recommended (chosen on clusters held out from training): {r['recommended']}")
    return "\n".join(lines)


__all__ = ["DEMO_COLLECT", "DEMO_METHODS", "DemoConfig", "DemoResult", "collect_arm", "export_recordings",
           "fit_and_compare", "run_demo", "summary_table"]
