"""``cellcal compensate-job``: a Yaskawa job compensated with calibrated models, every other line kept."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path

from app.cli.common import cell_spec, positive_float, write_json
from app.jobs.compensate import load_job_models


def _output_path(text: str, flag: str) -> Path:
    """``text`` as a file to write: refused when empty, a directory, or under an existing non-directory."""
    from calibration.errors import DataError

    path = Path(text)
    if not text or path.is_dir():
        raise DataError(text, None, None, f"{flag} must be a file path, not a directory or empty")
    parent = next((p for p in path.absolute().parents if p.exists()), None)
    if parent is not None and not parent.is_dir():
        raise DataError(text, None, None, f"{flag} lies under {parent}, which is not a directory")
    return path


def cmd_compensate_job(args: argparse.Namespace) -> int:
    from app.jobs import JobCompensator, read_job, write_job
    from calibration.data.files import atomic_write_bytes
    from calibration.errors import DataError

    out = _output_path(args.out, "--out")  # --out equal to --job: refused by app.cli.common.check_output_args
    if args.json is not None:
        _output_path(args.json, "--json")
    cell = cell_spec(args)
    models = load_job_models(args.model, cell)
    job = read_job(args.job)
    comp = JobCompensator(cell, models, max_joint_change_deg=args.max_joint_change_deg,
                          near_orientation_deg=args.near_orientation_deg).compensate(job)
    data = write_job(job, comp.replacements)
    summary = {"job": str(args.job), "out": str(out), **comp.to_json()}
    writers: tuple[tuple[str | Path, Callable[[], object]], ...] = (
        (args.json, lambda: write_json(args.json, summary)), (out, lambda: atomic_write_bytes(out, data)))
    for path, write in writers:
        try:
            write()
        except OSError as e:
            raise DataError(path, None, None, f"cannot write ({e.__class__.__name__}: {e.strerror or e})") from e
    robots = ", ".join(f"{r}: {m}" for r, m in comp.models.items())
    print(f"{len(comp.points)} positions compensated ({robots}), residual <= {summary['max_residual_mm']:.1e} mm "
          f"under the model, {summary['max_written_residual_mm']:.1e} mm as written, joints moved by up to "
          f"{summary['max_joint_change_deg']:.3f} deg -> {out}")
    near = [p for p in comp.points if p.near_singularity]
    if near:
        print(f"{len(near)} of them at the wrist singularity (q5 ~ 0): position reached, orientation left up to "
              f"{max(p.residual_deg for p in near):.3f} deg off rather than swinging joints 4 and 6 ("
              + ", ".join(p.name for p in near[:5]) + (", ..." if len(near) > 5 else "") + ")")
    return 0


def add_job_parsers(add: Callable[..., argparse.ArgumentParser]) -> None:
    p = add("compensate-job", cmd_compensate_job,
            "rewrite a Yaskawa INFORM job (.JBI) so the calibrated arms reach the poses the nominal ones would")
    p.add_argument("--model", action="append", required=True, metavar="[ROBOT=]FILE",
                   help="calibrated model file; ROBOT=FILE to name the robot (default: the robot it was fitted for); "
                        "repeat for a second robot (RB1 is the cell's first robot R1, RB2 its second R2)")
    p.add_argument("--job", required=True, help="input job file (.JBI): PULSE, ROBOT or BASE C positions")
    p.add_argument("--out", required=True, help="compensated job file to write (never the input)")
    p.add_argument("--max-joint-change-deg", type=positive_float, default=5.0,
                   help="refuse a point whose compensation moves any joint by more than this [deg] (default 5; "
                        "near the wrist singularity the solution nearest the programmed joints is taken, see "
                        "--near-orientation-deg)")
    p.add_argument("--near-orientation-deg", type=positive_float, default=0.5,
                   help="near the wrist singularity (q5 ~ 0), where reaching the last part of the orientation swings "
                        "joints 4 and 6 against each other, reach the position exactly and leave at most this "
                        "orientation error [deg] instead (default 0.5); the JSON marks such points "
                        "(near_singularity)")
    p.add_argument("--json", help="write per position: line, group, before/after values, joint change [deg], "
                                  "residual [mm, deg] as JSON")
