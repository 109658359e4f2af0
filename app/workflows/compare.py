"""The paper's comparison (Table IV): fit every method on a training set, evaluate on a test set."""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from app.workflows.fit import TrainingInputs, trained_fitter
from app.workflows.inputs import load_model_for, read_recording_for
from calibration.data.recording import Recording
from calibration.diagnosis.shifts import one_sided_shift
from calibration.errors import ModelError
from calibration.evaluation.comparison import Comparison, comparison_warnings
from calibration.evaluation.metrics import (
    joint_correlation,
    paired_tests,
    parameter_spread,
)
from calibration.frames.check import check_test
from calibration.frames.policy import refuse_another_arms, refuse_unexplained
from calibration.method_names import CDC_METHODS, METHODS, NEURAL_METHODS, cdc_method
from calibration.methods.cdc import cluster_anchors
from calibration.methods.fitter import Fitter
from calibration.methods.recommend import Recommendation, off_reference, recommend
from calibration.models import KinematicModel
from calibration.models.guard import extrapolation

log = logging.getLogger("cellcal.app")


def parse_methods(text: str) -> list[str]:
    """``all`` or a comma-separated list of methods, validated."""
    if text == "all":
        return list(METHODS)
    chosen = [m.strip() for m in text.split(",") if m.strip()]
    unknown = [m for m in chosen if m not in METHODS]
    if unknown or not chosen:
        raise ModelError(f"unknown method {unknown[0] if unknown else text!r}; valid: all, {', '.join(METHODS)}")
    return chosen


def run_comparison(fitter: Fitter, test: Recording, methods: list[str] | tuple[str, ...],
                   progress: bool = False, files: dict[str, KinematicModel] | None = None) -> Comparison:
    """Fit each method and evaluate it; a method whose data is missing (CPA sweeps) is skipped with a reason.

    ``files`` adds saved models (a diagnose result, a model fitted elsewhere) as rows of their own, evaluated
    on the same data; their fit time is the one recorded in the file, if any.

    Raises:
        ModelError: a saved model is for another robot.
    """
    out = Comparison(fitter.robot)
    for name, model in (files or {}).items():
        if model.robot != fitter.robot:
            raise ModelError(f"model {name} is for robot {model.robot!r}, not {fitter.robot!r}")
    try:
        return _run_comparison(fitter, test, methods, progress, files or {}, out)
    except BaseException:
        fitter.abort_jobs()  # a failed or interrupted compare does not wait for workers nobody will collect
        raise


def _run_comparison(fitter: Fitter, test: Recording, methods: list[str] | tuple[str, ...], progress: bool,
                    files: dict[str, KinematicModel], out: Comparison) -> Comparison:
    from tqdm import tqdm

    # The neural fits train in worker processes while the other methods are fitted here, and are collected last;
    # the rows keep the order asked for.
    fitter.prefetch(methods, held_out=True)  # the recommendation's network refits too
    order = [m for m in methods if m not in NEURAL_METHODS] + [m for m in methods if m in NEURAL_METHODS]
    bar = tqdm(order, desc=f"{fitter.robot} fit", unit="method", disable=not progress)
    for method in bar:
        bar.set_postfix_str(method)
        if method == "cpa" and fitter.cpa_data is None:
            out.skipped[method] = "no single-joint sweep data given (--cpa DATA)"
            continue
        model, seconds = fitter.fit(method)
        log.info("%s fitted in %.3f s", method, seconds)
        out.add(method, model, seconds, fitter.train, test)
    if not out.models:  # the recommendation's "no method has held-out errors" did not say why
        raise ModelError("no method to compare: " + "; ".join(f"{m} skipped: {why}" for m, why in out.skipped.items()))
    tables: tuple[dict[str, Any], ...] = (out.models, out.fit_seconds, out.train_errors, out.test_errors)
    for rows in tables:
        fitted = dict(rows)
        rows.clear()
        rows.update({m: fitted[m] for m in methods if m in fitted})
    for name, model in files.items():
        out.add(name, model, model.info.get("fit_seconds"), fitter.train, test)
    out.analysis = _analysis(fitter, test, out)
    recommendation = _recommend(fitter, out, files)
    out.recommended = recommendation.method
    out.analysis["recommendation"] = recommendation.to_json()
    return out


def recommendation_line(cmp: Comparison) -> str:
    """One line naming the recommended method and why (for the CLI)."""
    rec = cmp.analysis["recommendation"]
    c, b = rec["candidates"][rec["method"]], rec["candidates"][rec["best"]]
    best = rec["method"] == rec["best"]
    why = (f"the best on clusters held out from training ({c['heldout_rms_mm']:.3f} mm RMS)" if best
           else f"{c['heldout_rms_mm']:.3f} mm RMS on clusters held out from training, tied with the best, "
                f"{rec['best']} ({b['heldout_rms_mm']:.3f} mm, {b['n_parameters']} parameters; p = "
                f"{c['p_worse_than_best']:.2f})")
    return f"recommended: {rec['method']} ({c['n_parameters']} parameters): {why}"


def recommend_fitted(fitter: Fitter, models: dict[str, KinematicModel]) -> Recommendation:
    """The model to use among methods ``fitter`` fitted (:mod:`calibration.methods.recommend`): its training data only,
    no test recording enters."""
    constant_fit = {"geometric": "nls1", "pi": "pi"}  # the constant fit each CDC reference is
    references = {m: constant_fit[cdc_method(m)[0]] for m in models if m in CDC_METHODS}
    cdc_references = {m: (ref, _reference_errors(fitter, ref)) for m, ref in references.items()}
    # the CDC methods on the losing reference are no candidates whatever their own held-out errors: not refitted
    unread = off_reference(cdc_references)
    neural = [m for m in models if m in NEURAL_METHODS and m not in unread]
    for m in models:  # the cheap ones first: they fill the fold fits' caches the network refits start from
        if m not in neural and m not in unread:
            fitter.held_out_errors(m)
    fitter.prefetch_held_out_errors(neural)  # the costly network refits, on every usable core
    held_out = {m: None if m in unread else fitter.held_out_errors(m) for m in models}  # cached by the Fitter
    groups, _ = cluster_anchors(fitter.train, fitter.options.cluster_size)
    return recommend(held_out, {m: model.n_parameters for m, model in models.items()}, groups,
                     cdc_references=cdc_references)


def _reference_errors(fitter: Fitter, ref: str) -> np.ndarray:
    """The held-out errors of a CDC method's reference (a constant fit: ``nls1`` or ``pi``, which always has them)."""
    e = fitter.held_out_errors(ref)
    if e is None:
        raise ModelError(f"the CDC reference {ref} has no held-out errors")
    return e


def _recommend(fitter: Fitter, cmp: Comparison, files: dict[str, KinematicModel]) -> Recommendation:
    rec = recommend_fitted(fitter, {m: model for m, model in cmp.models.items() if m not in files})
    return replace(rec, not_candidates={**rec.not_candidates, **{
        name: "a saved model: not fitted here, so no held-out figure" for name in files}})


def _analysis(fitter: Fitter, test: Recording, cmp: Comparison) -> dict[str, Any]:
    """Paper tables II and V, paired tests against the nominal and Fourier models, observability, Fourier spectrum."""
    analysis: dict[str, Any] = {}
    if "nominal" in cmp.models:
        nominal_test = cmp.test_errors["nominal"].position_mm
        analysis["nominal_error_joint_correlation_test"] = joint_correlation(nominal_test, test.q)
        analysis["nominal_error_joint_correlation_train"] = joint_correlation(
            cmp.train_errors["nominal"].position_mm, fitter.train.q)
        analysis["paired_tests_vs_nominal"] = {
            m: paired_tests(e.position_mm, nominal_test) for m, e in cmp.test_errors.items() if m != "nominal"}
    if "fbf13" in cmp.models:
        fourier_test = cmp.test_errors["fbf13"].position_mm
        analysis["paired_tests_vs_fbf13"] = {
            m: paired_tests(e.position_mm, fourier_test) for m, e in cmp.test_errors.items() if m != "fbf13"}
    if "pi" in cmp.models:  # measurement jumps in the training recording, against its most accurate smooth fit

        _, p = cmp.models["pi"].fk(fitter.train.q)
        analysis["measurement_shift"] = one_sided_shift(fitter.train.p - p).to_json()
    obs = fitter.observability()
    analysis["observability"] = {"condition_number": obs.condition_number, "rank": obs.rank,
                                 "parameters": len(obs.singular_values),
                                 "relative_singular_values": (obs.singular_values / obs.singular_values[0]).tolist(),
                                 "hidden_directions": obs.unobservable(), "warning": obs.summary()}
    references = {cdc_method(m)[0] for m in cmp.models if m in CDC_METHODS}
    if references:
        # Table V is the paper's: the local fits of its construction when one of its methods ran, else pi's
        reference = "geometric" if "geometric" in references else "pi"
        local = fitter.local_fits(reference)
        analysis["local_reference"] = reference
        analysis["local_parameter_spread"] = parameter_spread(local.x, fitter.par.names())
        analysis["local_fit_seconds"] = local.seconds
        analysis["local_fit_rms_mm"] = {"mean": float(np.mean(local.rms_mm)), "max": float(np.max(local.rms_mm))}
    interp = cmp.models["fbf13"].interpolation() if "fbf13" in cmp.models else None
    if interp is not None:  # any kind answers: a frames-first fit wraps fbf13 in a rebased model
        analysis["fourier_singular_values"] = np.asarray(interp.singular_values()).tolist()
    return analysis


@dataclass(frozen=True)
class CompareInputs:
    """What ``cellcal compare`` was asked.

    Attributes:
        training: the training data (:class:`~app.workflows.fit.TrainingInputs`).
        test: the test recording every method is evaluated on.
        methods: the methods to fit (:func:`parse_methods`).
        model_files: saved models compared beside them, each a row of its own (``--model``).
        progress: show a progress bar over the fits.
    """

    training: TrainingInputs
    test: str
    methods: tuple[str, ...]
    model_files: tuple[str, ...] = ()
    progress: bool = False


@dataclass(frozen=True)
class CompareResult:
    """A comparison and the recording it was tested on.

    Attributes:
        comparison: the :class:`~calibration.evaluation.comparison.Comparison` (its ``analysis`` holds the training
            and test frame checks, the gross rows and, with several training recordings, the days).
        test: the test recording.
    """

    comparison: Comparison
    test: Recording


def compare(cell: Any, inputs: CompareInputs, warn: Callable[[str], None]) -> CompareResult:
    """Fit every method on the training data and evaluate each, with the saved models, on the test recording.

    The test recording is checked to be the arm's before any fit; the training recordings are checked as ``fit``
    checks them (:func:`~app.workflows.fit.trained_fitter`); after the fits, the recommended model (else pi, else
    nls1) checks the test recording's frames (:func:`check_test_frames`). Warnings go to ``warn``, one line each,
    the comparison's own last.

    Raises:
        CellCalError: bad input (a model file or recording that is not the arm's, unreadable data).
    """
    robot = cell.robot(inputs.training.robot)
    files = {f"{Path(f).stem} (file)": load_model_for(f, robot) for f in inputs.model_files}
    test = read_recording_for(inputs.test, robot)
    refuse_another_arms(robot.arm(), test, "test recording")  # before any fit: another arm's test would waste them all
    trained = trained_fitter(cell, inputs.training, warn)  # the training recordings are checked the same way
    cmp = run_comparison(trained.fitter, test, list(inputs.methods), progress=inputs.progress, files=files)
    check = trained.frame_check
    cmp.analysis["frames"] = {"training": None if check is None else check.to_json()}
    cmp.analysis["gross_rows"] = trained.gross_rows()
    if trained.days is not None:
        cmp.analysis["days"] = trained.days.to_json()
    checked = next((m for m in (cmp.recommended, "pi", "nls1") if m in cmp.models), None)
    if checked is not None:
        cmp.analysis["frames"]["test"] = {"model": checked, **check_test_frames(
            cmp.models[checked], test, f"test recording, against the {checked} fit of the training recording,",
            f"the {checked} fit of the training recording", warn)}
    for text in comparison_warnings(cmp):
        warn(f"warning: {text}")
    return CompareResult(cmp, test)


def check_test_frames(model: KinematicModel, test: Recording, subject: str, against: str,
                      warn: Callable[[str], None]) -> dict[str, Any]:
    """:func:`calibration.frames.check.check_test` of ``model`` on ``test``, its message told as a warning; JSON.

    Raises:
        DataError: even the rigid frame fit leaves ``test`` far off ``model`` (another arm's recording).
    """
    check = check_test(model, test, subject)
    refuse_unexplained(test.source, model.robot, against, check.mean_mm, check.left_mm)
    out = check.to_json()
    if check.found:
        caveat = _extrapolation_caveat(model, test)
        warn(f"warning: {check.message()} No kinematic model can remove that; the errors reported are without the "
             f"frame fit.{caveat}")
        out["caveat"] = caveat.strip() or None
    return out


#: Share of a test recording's poses outside the model's training joint range beyond which a frame found on it
#: may be the model's extrapolation instead (a rigid fit absorbs part of any smooth error over those poses).
EXTRAPOLATED_SHARE = 0.5


def _extrapolation_caveat(model: KinematicModel, test: Recording) -> str:
    """A sentence for a frame found on a test recording whose poses mostly lie outside the model's training joint
    range; empty otherwise (or when the model records no training region)."""
    ex = extrapolation(model, test.q)
    outside = ex["outside_training_range"]
    if not outside or outside <= EXTRAPOLATED_SHARE * ex["poses"]:
        return ""
    return (f" But {outside} of its {ex['poses']} poses lie outside the joint range the model was trained on (by up "
            f"to {ex['max_excess_deg']:.1f} deg), and a rigid frame fit also absorbs part of a model's error there: "
            "this may be the model's extrapolation rather than a frame. A frame error shows on poses inside that "
            "range too; measure a few there to tell.")
