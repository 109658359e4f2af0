"""The analysis commands: ``fit``, ``predict``, ``evaluate``, ``rebase``, ``export-urdf``, ``compare`` and
``diagnose`` (their parsers are built by :mod:`app.cli.commands`)."""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING, Any

from app.cli.common import (
    add_topup_options,
    cell_spec,
    command_line,
    epoch_bar,
    model_and_robot,
    show_progress,
    sigma_residual,
    tolerance_from_args,
    write_json,
)
from calibration.errors import CellCalError, DataError

if TYPE_CHECKING:
    from app.workflows.fit import TrainingInputs


def _warn(line: str) -> None:
    """A workflow's warning line, on stderr."""
    print(line, file=sys.stderr)


def _training(args: argparse.Namespace) -> TrainingInputs:
    """``--robot``/``--train``/``--add``/``--add-weight``/``--cpa``/``--a`` as the fit workflow's training inputs."""
    from app.workflows.fit import TrainingInputs

    return TrainingInputs(args.robot, tuple(args.train), args.cpa, tuple(args.add), args.add_weight, args.a,
                          epoch_bar(args))


def cmd_fit(args: argparse.Namespace) -> int:
    """Run :func:`app.workflows.fit.fit_model` (warnings on stderr), print its line, write JSON."""
    from app.workflows.fit import FitInputs, fit_model

    inputs = FitInputs(_training(args), args.method, args.out)  # --method cpa without --cpa: refused here
    result = fit_model(cell_spec(args), inputs, _warn)
    print(result.line())
    write_json(args.json, result.to_json())
    return 0


def cmd_predict(args: argparse.Namespace) -> int:
    from calibration.data.recording import read_joints, write_table
    from calibration.kinematics import so3
    from calibration.models.guard import extrapolation

    _check_sigma_options(args)
    model, robot = _model_arg(args)
    q = read_joints(args.joints, *((robot.robot.lower_rad, robot.robot.upper_rad) if robot else ()))
    given = _given_recording(args, robot)
    outside = model.out_of_range(q)
    if outside.any():
        print(f"warning: {int(outside.sum())} of {len(q)} configurations lie outside the (q2, q3) region the "
              f"{model.method} model interpolates its parameters over (its anchors' hull); its parameters there are "
              "extrapolated", file=sys.stderr)
    ex = extrapolation(model, q)
    _warn_extrapolation(model, ex)
    R, p = model.fk(q)
    quat = so3.R_to_quat(R)
    residual, source = sigma_residual(args, robot, given) if given is not None else (0.0, "")
    sigma = _predicted_sigma(robot, given, q, residual)
    write_table(args.out, {"x": p[:, 0], "y": p[:, 1], "z": p[:, 2], "qw": quat[:, 0], "qx": quat[:, 1],
                           "qy": quat[:, 2], "qz": quat[:, 3], **({} if sigma is None else {"sigma_mm": sigma})})
    print(f"{len(q)} pose{'' if len(q) == 1 else 's'} -> {args.out}")
    write_json(args.json, {"robot": model.robot, "method": model.method, "poses": len(q),
                           "outside_fitted_region": int(outside.sum()), "out": str(args.out),
                           "extrapolation": ex, "counts_explained": _counts_explained(predict=True),
                           **({} if given is None else {"sigma_residual_mm": residual, "sigma_residual_from": source})})
    return 0


def _counts_explained(*, predict: bool = False) -> dict[str, str]:
    """What each pose count of the command's JSON counts, keyed by where the count sits (``extrapolation.KEY``);
    predict's ``outside_fitted_region`` is the extrapolation's ``outside_model_region``."""
    from calibration.models.guard import COUNTS_EXPLAINED as explained

    out = {f"extrapolation.{key}": text for key, text in explained.items()}
    if predict:
        out = {"outside_fitted_region": "the same count as extrapolation.outside_model_region: "
                                        + explained["outside_model_region"], **out}
    return out


def _warn_extrapolation(model: Any, ex: dict[str, Any]) -> None:
    """One stderr line when poses leave the model's training joint range, one when they leave the range of a context
    entry its effects read (time, temperature, payload; see :mod:`calibration.models.guard`)."""
    from calibration.models.guard import GUARD_ACTED_MM

    if ex["outside_training_range"]:
        print(f"warning: {ex['outside_training_range']} of {ex['poses']} poses lie outside the joint range of the "
              f"{model.method} model's training data (by up to {ex['max_excess_deg']:.1f} deg); "
              + (f"the guard held its effects fitted in narrowly seen joints at the edge of that range there "
                 f"(moving the position by up to {ex['guard_shift_mm_max']:.3f} mm)" if ex.get("guard_acted") else
                 "the guard did not change its prediction there"), file=sys.stderr)
    beyond = {k: c for k, c in ex["outside_context_range"].items() if c["poses"]}
    if beyond:
        shift = ex["guard_shift_context_mm_max"]
        print(f"warning: poses lie beyond the {model.method} model's training data in "
              + ", ".join(f"{k} ({c['poses']} of {ex['poses']} poses, by up to {c['max_excess']:.3g} {c['unit']}; "
                          f"trained on {c['range'][0]:.6g} to {c['range'][1]:.6g} {c['unit']})"
                          for k, c in beyond.items())
              + "; " + (f"the guard held its effects whose shape was fitted over too short a span of them at the edge "
                        f"of that range (moving the position by up to {shift:.3f} mm)" if shift > GUARD_ACTED_MM else
                        "the guard did not change its prediction there (its effects go on as their formulas say)"),
              file=sys.stderr)


def _model_arg(args: argparse.Namespace) -> tuple[Any, Any]:
    """``--model``, checked to be ``--robot``'s (or, without it, the recorded robot's: its geometry against the
    robot YAML), and its robot's cell entry (:func:`app.cli.common.model_and_robot`).

    Joints are then checked against the limits when they are known (the recording spec calls a joint outside them
    an error); a model of a robot the cell does not describe gets ``None`` and no limit check.
    """
    return model_and_robot(args, args.model)


def _predicted_cov(robot: Any, given: Any, q: Any, residual_mm: float) -> Any:
    """The top-up design's predicted position error covariance [mm^2] (Q, 3, 3)
    (:func:`calibration.methods.topup.predicted_position_cov`) at each configuration q, given the poses the model was fitted
    on (:func:`_given_recording`) and the residual (:func:`app.cli.common.sigma_residual`); None without them."""
    if given is None:
        return None
    from calibration.methods.topup import predicted_position_cov

    return predicted_position_cov(robot.model(), given.q, q, residual_mm=residual_mm)


def _sigma_of(cov: Any) -> Any:
    import numpy as np

    return np.sqrt(np.trace(cov, axis1=1, axis2=2))


def _outside_given(given: Any, q: Any) -> Any:
    """Poses of q (N, 6) with a joint beyond the range of ``given``'s poses by more than the extrapolation count's
    tolerance (:data:`calibration.models.guard.OUTSIDE_TOLERANCE_DEG`), shape (N,)."""
    import numpy as np

    from calibration.models.guard import OUTSIDE_TOLERANCE_DEG

    tol = np.radians(OUTSIDE_TOLERANCE_DEG)
    lo, hi = given.q.min(axis=0), given.q.max(axis=0)
    return np.any((q < lo - tol) | (q > hi + tol), axis=1)


def _training_recording(model: Any) -> str:
    """The training recording the model's provenance names (a Welding_Motoman folder for its two files), or
    ``TRAIN.csv`` when it names none or several."""
    from pathlib import Path

    from app.reports.provenance import PROVENANCE_KEY

    trained = [i["path"] for i in (model.info.get(PROVENANCE_KEY) or {}).get("inputs", []) if i.get("role") == "train"]
    folders = {str(Path(t).parent) for t in trained}  # a Welding_Motoman recording is a folder of two files
    return trained[0] if len(trained) == 1 else folders.pop() if len(folders) == 1 else "TRAIN.csv"


def _evaluate_why(args: argparse.Namespace, model: Any) -> str:
    """The report's why for ``evaluate``: the model judged is the one given, nothing was chosen among others; what
    it is (method, parameter count, training recording when its provenance names one) and the test used."""
    trained = _training_recording(model)
    on = "" if trained == "TRAIN.csv" else f", fitted on {trained}"
    return (f"evaluate chooses no model: it judges the one given, {args.model} ({model.method}, {model.n_parameters} "
            f"parameters{on}), on {args.test}, a recording it was not fitted on; the test is the tolerance on the "
            "largest position and orientation errors there.")


def cmd_evaluate(args: argparse.Namespace) -> int:
    from app.workflows.compare import check_test_frames
    from app.workflows.inputs import read_recording_for
    from calibration.evaluation.metrics import error_stats, errors

    tolerance = tolerance_from_args(args)
    from calibration.models.guard import extrapolation

    _check_sigma_options(args)
    model, robot = _model_arg(args)
    test = read_recording_for(args.test, robot)
    given = _given_recording(args, robot)
    frames = check_test_frames(model, test, "recording, against the data the model was fitted on,",
                               f"the model {args.model}", _warn)  # another arm's recording: refused before any output
    ex = extrapolation(model, test.q, test.context())
    _warn_extrapolation(model, ex)
    result = {"robot": model.robot, "method": model.method, "samples": len(test),
              "test": error_stats(errors(model, test)), "extrapolation": ex}
    pos, ori = result["test"]["position_mm"], result["test"]["orientation_deg"]
    print(f"{model.method} on {len(test)} samples: position mean {pos['mean']:.3f} std {pos['std']:.3f} "
          f"max {pos['max']:.3f} mm; orientation mean {ori['mean']:.3f} max {ori['max']:.3f} deg")
    residual, source = sigma_residual(args, robot, given) if given is not None else (0.0, "")
    cov = _predicted_cov(robot, given, test.q, residual)
    sigma_map = None
    if cov is not None:
        import numpy as np

        from app.reports.sections import SigmaMap
        from calibration.methods.topup import gaussian_share_over

        sigma = _sigma_of(cov)
        e = errors(model, test).position_mm
        over = float(np.mean(e > 2 * sigma))
        reference = gaussian_share_over(cov)
        sigma_map = SigmaMap(sigma, _outside_given(given, test.q), reference,
                             "sigma predicted from the poses the model was fitted on, --given"
                             + (" and --add" if args.add else ""))
        result["predicted_sigma"] = {
            "mean_mm": float(sigma.mean()), "max_mm": float(sigma.max()), "share_over_2_sigma": over,
            "share_over_1_sigma": float(np.mean(e > sigma)), "gaussian_share_over_2_sigma": reference,
            "outside_given_range": int(sigma_map.outside.sum()), "residual_mm": residual, "residual_from": source,
            "sigma": "RMS of the position error norm the top-up design's error model predicts given --given/--add",
            "gaussian": "share of poses a Gaussian error of each pose's predicted covariance puts beyond 2 sigma "
                        "(0.74 % isotropic, 4.55 % along one axis)"}
        print(f"predicted position sigma mean {sigma.mean():.3f} max {sigma.max():.3f} mm; {100 * over:.1f} % of the "
              f"poses err by more than 2 sigma (a Gaussian error of the predicted covariances: {100 * reference:.1f} %)")
    result["frames"] = frames
    result["counts_explained"] = _counts_explained()
    write_json(args.json, result)
    if args.report:
        from pathlib import Path

        from app.reports.sections import write_evaluation_report

        page = write_evaluation_report(f"Evaluation of {Path(args.model).name} on {Path(args.test).name}",
                                       command_line(args),  # the full paths: in the command and the inputs table
                                       {model.method: model}, test, args.report, tolerance,
                                       [("model", args.model), ("test", args.test)], "the test recording",
                                       next_steps=_evaluate_next_steps(args, model, ex),
                                       why=[_evaluate_why(args, model)], sigma=sigma_map)
        print(f"report: {page}")
    return 0


#: Share of an isotropic 3-D Gaussian error whose norm exceeds twice its RMS norm: P(chi2_3 > 12).
GAUSSIAN_OVER_2_SIGMA = 0.0074


#: Fewer clusters than this in a rebase's data get a warning: the issue-10 design rebases on 3 spread clusters (21
#: poses), and the frames fitted to one cluster absorb the arm's local error (a new user saw 0.638 -> 0.018 mm).
REBASE_MIN_CLUSTERS = 3


def cmd_rebase(args: argparse.Namespace) -> int:
    import math

    import numpy as np

    from app.workflows.inputs import read_recording_for
    from calibration.data.recording import DEFAULT_CLUSTER_SIZE
    from calibration.frames.rebase import rebase, rebase_auto, workspace_configurations
    from calibration.frames.rebase_design import REBASE_OFFSETS
    from calibration.models import save_model

    _check_rebase_tolerance(args.tolerance)
    model, robot = model_and_robot(args, args.model, needs_robot=True)
    data = read_recording_for(args.data, robot)
    if args.offsets:
        rebased, result = rebase(model, data, tolerance=args.tolerance, offsets=REBASE_OFFSETS)
        choice = "frames+offsets"
    elif args.translation_only or args.all_directions:
        rebased, result = rebase(model, data, tolerance=args.tolerance, rotations=args.all_directions)
        choice = "translations" if args.translation_only else "frames"
    else:
        workspace = workspace_configurations(robot.robot.lower_rad, robot.robot.upper_rad)
        rebased, result, choice = rebase_auto(model, data, tolerance=args.tolerance, q_workspace=workspace)
    if not result.converged:
        raise CellCalError(f"rebase of {args.model} on {args.data} did not converge ({result.reason.value}); "
                           "nothing written")
    from calibration.frames.policy import refuse_unexplained

    refuse_unexplained(data.source, robot.name, f"the rebased model {args.model}", result.mean_before_mm,
                       result.mean_after_mm)  # the rebase is the frame fit: another arm's data stays far off
    from app.reports.provenance import provenance, with_provenance

    save_model(with_provenance(rebased, provenance([("model", args.model), ("data", args.data)])), args.out)
    print(result.summary())
    try:
        n_clusters = len(np.unique(data.clusters()))
        where = f"{n_clusters} cluster(s)"
    except DataError:  # no cluster column and not whole clusters: judged by the pose count
        n_clusters = result.n_samples // DEFAULT_CLUSTER_SIZE
        where = "no clusters"
    if n_clusters < REBASE_MIN_CLUSTERS:
        print(f"warning: {args.data} holds {result.n_samples} poses in {where}: the error after the "
              f"rebase is measured on the poses it was fitted to, and poses this close together cannot tell a frame "
              f"change from the arm's own error there. Rebase on {REBASE_MIN_CLUSTERS} or more clusters spread over "
              f"the workspace (cellcal plan --design optimal --budget 21 --for rebase, or cellcal select --for "
              f"rebase --budget 3 on a grid recording), or check the model on other poses (cellcal evaluate).",
              file=sys.stderr)
    print(f"rebased {model.method} model -> {args.out}")
    write_json(args.json, {"robot": robot.name, "model": str(args.model), "data": str(args.data),
                           "samples": result.n_samples, "directions": choice, "fitted_directions": result.fitted,
                           "held": list(result.held),
                           "position_mean_mm": {"before": result.mean_before_mm, "after": result.mean_after_mm},
                           "objective_rms": {"before": result.objective_before, "after": result.objective_after},
                           "shrink": result.shrink,
                           "T_base_correction": result.T_base_correction.tolist(),
                           "T_tool_correction": result.T_tool_correction.tolist(),
                           "joint_offsets_deg": [math.degrees(v) for v in result.joint_offsets], "out": str(args.out)})
    return 0


def _check_rebase_tolerance(tolerance: float) -> None:
    """Refuse a ``rebase --tolerance`` that is not a fraction in (0, 1) (a direction is fitted when its singular
    value is at least this fraction of the largest): at 0 or below no direction is held however poorly the poses
    see it; at 1 only the best seen one is fitted; above 1, at inf or NaN (which compares false with every
    singular value) none is, and the rebase returned the model unchanged without a word.

    Raises:
        CellCalError: naming the option and the value.
    """
    import math

    if not (math.isfinite(tolerance) and 0.0 < tolerance < 1.0):
        raise CellCalError(f"--tolerance must be a fraction in (0, 1) of the largest singular value, got {tolerance:g}")


def cmd_export_urdf(args: argparse.Namespace) -> int:
    from calibration.data.files import atomic_write_text
    from calibration.models.urdf import (
        BASE_LINK,
        ROS_JOINTS,
        TOOL_LINK,
        JointLimits,
        UrdfLayout,
        write_urdf,
        xacro_text,
    )

    if args.macro is not None:  # before any work: the name is called as <xacro:NAME .../>, an XML name
        import re

        if not args.xacro:
            raise CellCalError(f"--macro {args.macro!r} names the xacro macro; give --xacro FILE too")
        if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_.-]*", args.macro):
            raise CellCalError(f"--macro {args.macro!r}: not a macro name; expected a letter or _ then letters, "
                               "digits, _ . - (it is called as <xacro:NAME prefix=.../>)")
    model, robot = model_and_robot(args, args.model, needs_robot=True)
    geometry = model.urdf_geometry()
    spec = robot.robot
    limits = JointLimits(spec.lower_rad, spec.upper_rad, spec.max_speed_rad_s, spec.max_torque_Nm)
    layout = UrdfLayout(spec.base_height_mm, args.meshes)
    xacro = None
    if args.xacro:  # built before anything is written: a refused model or mesh URI leaves neither file
        xacro = xacro_text(geometry, limits, args.macro or f"cellcal_{spec.name.lower()}", str(args.model), layout)
    write_urdf(args.out, geometry, limits, robot.name, str(args.model), layout)
    if xacro is not None:
        atomic_write_text(args.xacro, xacro)
    label = model.method if model.kind == model.method else f"{model.kind} {model.method}"  # not "pi pi model"
    print(f"{label} model of {robot.name}: exported {geometry.exported} -> {args.out}")
    if args.xacro:
        print(f"  xacro macro {args.macro or f'cellcal_{spec.name.lower()}'} (prefix parameter) -> {args.xacro}")
    for item in geometry.lost:
        print(f"  lost: {item}")
    if not geometry.lost:
        print("  lost: nothing (the model is one constant geometry)")
    write_json(args.json, {"robot": robot.name, "model": str(args.model), "kind": model.kind, "method": model.method,
                           "exported": geometry.exported, "lost": list(geometry.lost), "out": str(args.out),
                           "xacro": args.xacro, "base_link": BASE_LINK, "robot_frame_link": "base",
                           "base_height_mm": spec.base_height_mm, "tool_link": TOOL_LINK,
                           "joints": list(ROS_JOINTS[:geometry.arm.n_joints])})
    return 0


def cmd_compare(args: argparse.Namespace) -> int:
    """Run :func:`app.workflows.compare.compare` (warnings on stderr), print the table, write JSON and the report."""
    from app.reports.sections import comparison_table, shows_paper, write_report
    from app.workflows.compare import CompareInputs, compare, parse_methods, recommendation_line

    methods = parse_methods(args.methods)
    tolerance = tolerance_from_args(args)
    result = compare(cell_spec(args), CompareInputs(_training(args), args.test, tuple(methods), tuple(args.model),
                                                    show_progress(args)), _warn)
    cmp, test = result.comparison, result.test
    with_paper = shows_paper(args.robot, test)  # the paper's figures only beside a test recording of its own cell
    print(comparison_table(cmp, with_paper=with_paper))
    print(recommendation_line(cmp))
    write_json(args.json, cmp.to_json())
    if args.report:
        inputs = [*(("train", t) for t in args.train), ("cpa", args.cpa), ("test", args.test)] + [("model", f) for f in args.model]
        written = write_report(cmp, test, args.report, with_paper, tolerance, inputs, command_line(args))
        print(f"report: {written[-1]}")
    return 0


def cmd_diagnose(args: argparse.Namespace) -> int:
    from app.workflows.diagnose import run_diagnose
    from calibration.diagnosis import DiagnoseOptions

    result = run_diagnose(args.robot, args.train, added=args.add, add_weight=args.add_weight, heldout=args.test,
                          model=args.model, json_path=args.json,
                          report_dir=args.report, model_out=args.out, cell=args.cell,
                          options=DiagnoseOptions(compliance_form=args.compliance_form, weighting=args.weighting),
                          tolerance=tolerance_from_args(args), progress=show_progress(args),
                          command=command_line(args))
    if result.days is not None:
        print(result.days.summary())
    print(result.verdict)
    if result.extrapolation is not None:
        _warn_extrapolation(result.model, result.extrapolation)
    return 0


def _add_fit_inputs(p: argparse.ArgumentParser) -> None:
    p.add_argument("--robot", required=True, help="robot name in the cell (R1, R2)")
    p.add_argument("--train", required=True, action="append",
                   help="training recording CSV or Welding_Motoman folder; repeat it to fit several recordings "
                        "(days) as one arm with a pair of frames per recording")
    add_topup_options(p)
    p.add_argument("--cpa", help="single-joint sweep recording for circular point analysis")
    p.add_argument("--a", type=float, default=1641.0, help="orientation weight (default %(default)g: 1 mm ~ 1 deg)")


def _check_sigma_options(args: argparse.Namespace) -> None:
    """Refuse ``--add`` without ``--given`` before any output (the poses it names join the training recording)."""
    if args.add and args.given is None:
        raise CellCalError("--add names poses the model was fitted on beside --given TRAIN; give --given too")


def _given_recording(args: argparse.Namespace, robot: Any) -> Any:
    """``--given TRAIN`` with ``--add``'s poses (None without ``--given``), read before any warning or output so a
    bad file is the command's one line.

    Raises:
        CellCalError: ``--given`` for a model of a robot the cell does not describe (no nominal arm to take the
            Jacobian of), or a bad file (naming it).
    """
    if getattr(args, "given", None) is None:
        return None
    from app.workflows.inputs import read_given, read_recording_for
    from calibration.data.recording import with_added

    if robot is None:
        raise CellCalError("--given needs the model's robot in the cell (its nominal arm); give --robot or --cell")
    given = read_given(args.given, robot)
    return with_added(given, [read_recording_for(a, robot) for a in args.add]) if args.add else given


def _predicted_sigma(robot: Any, given: Any, q: Any, residual_mm: float) -> Any:
    """The predicted position sigma [mm] (RMS of the error norm, :func:`calibration.methods.topup.predicted_sigma`) at each
    configuration q, given the poses the model was fitted on; None without them."""
    cov = _predicted_cov(robot, given, q, residual_mm)
    return None if cov is None else _sigma_of(cov)


def _evaluate_next_steps(args: argparse.Namespace, model: Any, ex: dict[str, Any]) -> list[str]:
    """The report's next step when the test poses leave the model's training joint range: a top-up that covers them
    (``cellcal select``, the training recording named from the model's provenance); none otherwise (the verdict's
    default step then)."""
    if not ex["outside_training_range"]:
        return []
    given = _training_recording(model)
    return [f"{ex['outside_training_range']} of the {ex['poses']} poses lie outside the joint range the model was "
            f"trained on (by up to {ex['max_excess_deg']:.1f} deg): the model extrapolates there. Collect poses that "
            f"cover the task and refit: cellcal select --robot {model.robot} --data CANDIDATES.csv --given {given} "
            f"--task {args.test} --poses 21 --out topup.csv, measure them (cellcal collect), then cellcal fit with "
            f"--add topup.csv."]
