"""The configuration-dependent (CDC) methods, every name of :data:`calibration.method_names.CDC_METHODS`
registered with one function: the interpolator over the local cluster fits (:mod:`calibration.methods.cdc`), its
strength chosen on held-out training clusters, and the checks its model carries (held-out clusters, probe range,
corrections over the workspace)."""

from __future__ import annotations

import logging
import time
from typing import Any

import numpy as np

from calibration.errors import ModelError
from calibration.interpolation import make_interpolator
from calibration.method_names import CDC_METHODS, NEURAL_METHODS, REFERENCE_FITS, cdc_method
from calibration.methods import heldout as robust
from calibration.methods import workspace
from calibration.methods.cdc import build_cdc, cluster_anchors
from calibration.methods.folds import HeldOutRefits
from calibration.methods.registry import register
from calibration.models import KinematicModel
from calibration.models.cdc import CDC_INPUTS, CdcModel

log = logging.getLogger("cellcal.calibration")


def cdc_options(fitter: HeldOutRefits, method: str) -> dict[str, Any]:
    kind = cdc_method(method)[1]
    options: dict[str, Any] = {}
    if kind == "fbf7":
        options["rank"] = fitter.options.fbf7_rank
    if method == "pi+ae":
        options["hidden"] = tuple(fitter.options.pi_ae_hidden)
    if kind in ("nn", "ae"):
        options["random_state"] = fitter.options.seed
        options["progress"] = fitter.options.epoch_progress
    if kind in ("fbf13", "fbf7"):
        options["ridge"] = _choose_strength(fitter, method, options, "ridge", fitter.options.fourier_ridge_grid)
    return options


def build_model(fitter: HeldOutRefits, method: str, options: dict[str, Any]) -> CdcModel:
    reference, kind = cdc_method(method)
    return build_cdc(fitter.robot, method, fitter.reference(reference)[0], fitter.local_fits(reference),
                     interpolator=kind, **options)


@register(*CDC_METHODS)
def fit_cdc(fitter: HeldOutRefits, method: str) -> KinematicModel:
    options = cdc_options(fitter, method)
    if fitter.warm is not None:  # a fold refit is not checked: the fit on every cluster was
        return build_model(fitter, method, options)
    if method not in NEURAL_METHODS:
        check = _held_out_check(fitter, method, options)
        model = build_model(fitter, method, options)
        h = check.result()
    else:
        final = fitter._cache.prefetched.pop(method, None)
        if final is not None:  # final network (and the check's fold refits) trained in worker processes
            model, final_s = fitter._collect(final)
        else:
            # The check's fold refits are network trainings: started in worker processes first, they run
            # while the final network trains here (the same bits as in-process)
            fitter._submit_folds([(method, f) for f in range(robust.NEURAL_EVALUATED_FOLDS)])
            try:
                start = time.perf_counter()
                model = build_model(fitter, method, options)
                final_s = time.perf_counter() - start
                for f in range(robust.NEURAL_EVALUATED_FOLDS):
                    fitter._fold_error(method, f)  # collected here, so a worker failure shuts the pool
            except BaseException:
                fitter._shutdown_jobs()
                raise
        for f in range(robust.NEURAL_EVALUATED_FOLDS):
            fitter._fold_error(method, f)
        fitter._cache.worker_seconds[method] = final_s + sum(
            fitter._cache.fold_seconds[method, f] for f in range(robust.NEURAL_EVALUATED_FOLDS))
        h = _neural_check(fitter, method)
    model.info.update(_cdc_checks(fitter, method, model, h))
    return model


def _held_out_check(fitter: HeldOutRefits, method: str, options: dict[str, Any]) -> robust.HeldOutCheck:

    reference, kind = cdc_method(method)
    (kin, theta), local = fitter.reference(reference), fitter.local_fits(reference)
    groups, _ = cluster_anchors(fitter.clustered, fitter.options.cluster_size)
    return robust.HeldOutCheck(lambda: make_interpolator(kind, **options), kin, theta,
                               local.anchors, local.x, groups, fitter.clustered, CDC_INPUTS, seed=fitter.options.seed)


def _neural_check(fitter: HeldOutRefits, method: str) -> robust.HeldOut:
    """The neural kinds' held-out check: the method and its constant reference (``nls1`` / ``pi``) refitted
    without each of the first :data:`robust.NEURAL_EVALUATED_FOLDS` folds (the recommendation's own fold refits,
    :meth:`held_out_errors`), on those folds' poses."""
    reference = REFERENCE_FITS[cdc_method(method)[0]]
    groups, _ = cluster_anchors(fitter.train, fitter.options.cluster_size)
    folds = fitter._fold_fitters()[: robust.NEURAL_EVALUATED_FOLDS]
    rows = np.concatenate([np.flatnonzero(held) for held, _ in folds])
    return robust.HeldOut.of_errors(
        np.concatenate([fitter._fold_error(method, f) for f in range(len(folds))]),
        np.concatenate([fitter._fold_error(reference, f) for f in range(len(folds))]), groups[rows])


def _choose_strength(fitter: HeldOutRefits, method: str, options: dict[str, Any], name: str,
                     grid: tuple[float, ...]) -> float:
    """Option ``name`` of CDC ``method``'s interpolator from ``grid``, on held-out training clusters (1-SE rule);
    a fold refit takes the :attr:`warm` Fitter's choice."""

    if fitter.warm is not None:
        if method not in fitter.warm._cache.strengths:
            fitter.warm.fit(method)
        strength: float = fitter.warm._cache.strengths[method][name]
        return strength
    ref_name, kind = cdc_method(method)
    (kin, theta), local = fitter.reference(ref_name), fitter.local_fits(ref_name)
    groups, _ = cluster_anchors(fitter.clustered, fitter.options.cluster_size)
    scores: list[robust.HeldOut | None] = []
    reference = robust.position_errors(kin, theta, fitter.clustered)
    for v in grid:
        try:
            scores.append(robust.held_out(lambda: make_interpolator(kind, **{**options, name: v}),
                                          kin, theta, local.anchors, local.x, groups, fitter.clustered,
                                          CDC_INPUTS, seed=fitter.options.seed, reference_mm=reference))
        except ModelError as e:  # e.g. ridge 0 with fewer than 13 anchors in a fold: that strength is out
            log.info("%s %s=%g cannot be fitted on the held-out folds: %s", method, name, v, e)
            scores.append(None)
    usable = [i for i, s in enumerate(scores) if s is not None]
    usable_scores = [s for s in scores if s is not None]
    if not usable:
        raise ModelError(f"{method}: no {name} of {list(grid)} can be fitted on the held-out folds of "
                         f"{len(local.anchors)} clusters")
    chosen = grid[usable[robust.one_se_choice(tuple(grid[i] for i in usable), usable_scores)]]
    fitter._cache.strengths[method] = {
        name: chosen, "grid": list(grid),
        "heldout_rms_mm": [None if s is None else round(s.rms_mm, 4) for s in scores]}
    return chosen


def _cdc_checks(fitter: HeldOutRefits, method: str, model: Any, h: robust.HeldOut) -> dict[str, Any]:
    """Held-out-cluster (``h``) and probe-range checks of a CDC fit (training data only); a warning when
    one fails."""
    reference = cdc_method(method)[0]
    local = fitter.local_fits(reference)
    probes = workspace.probe_grid(local.anchors)
    excess = workspace.range_excess(model.interpolator.predict(probes), local.x, 0.01 * fitter.par.scale())
    ratio, probe_mm, train_mm = workspace.workspace_ratio(model.fk, fitter._reference_fk(reference), fitter.train.q,
                                                       fitter._workspace_probes())
    info: dict[str, Any] = {
        "heldout": {"rms_mm": round(h.rms_mm, 4), "max_mm": round(h.max_mm, 4),
                    "reference_rms_mm": round(h.reference_rms_mm, 4),
                    "reference_max_mm": round(h.reference_max_mm, 4)},
        "probe_range_excess": {"max": round(float(excess.max()), 3),
                               "share_over_limit": round(float(np.mean(excess > workspace.RANGE_EXCESS_LIMIT)), 3)},
        "workspace_correction": {"ratio": round(ratio, 2), "probe_p99_mm": round(probe_mm, 4),
                                 "train_p99_mm": round(train_mm, 4)},
        "reference": reference,
        "local_prior": fitter._cache.local_prior_cv.get(reference, {"chosen": fitter.options.local_prior}),
    }
    if method in fitter._cache.strengths:
        info["strength"] = fitter._cache.strengths[method]
    problems = []
    if h.ratio > robust.HELDOUT_RATIO_LIMIT:
        problems.append(f"on training clusters held out from it, its position RMS is {h.rms_mm:.3f} mm (max "
                        f"{h.max_mm:.3f}) against {h.reference_rms_mm:.3f} mm (max {h.reference_max_mm:.3f}) "
                        f"for the constant {reference} reference fit (x{h.ratio:.2f})")
    if ratio > workspace.WORKSPACE_RATIO_LIMIT:
        problems.append(f"its correction over the constant reference reaches {probe_mm:.3f} mm (99th "
                        f"percentile) at configurations spread over the joint limits against {train_mm:.3f} mm "
                        f"on the training poses (x{ratio:.1f}): the local fits carry directions the clusters "
                        f"cannot see")
    if not info["local_prior"].get("within_workspace_limit", True):
        problems.append(f"no local prior of {info['local_prior']['grid']} kept its correction over the workspace "
                        f"within {workspace.WORKSPACE_RATIO_LIMIT:g} times that on the training poses (ratios "
                        f"{info['local_prior']['workspace_ratio']}), so the strongest was taken: the local fits "
                        f"are held near the {reference} reference and the method gives about what it gives")
    if excess.max() > workspace.RANGE_EXCESS_LIMIT:
        problems.append(f"at {np.mean(excess > workspace.RANGE_EXCESS_LIMIT):.0%} of {len(probes)} probe "
                        f"configurations within 10 deg of the anchors' (q2, q3) box its raw parameters leave "
                        f"the local fits' range by up to {excess.max():.1f} times that range (clipped to it)")
    if problems:
        info["warning"] = f"{method} may be unstable: " + "; ".join(problems) + \
            ". Prefer the pi method (--method pi), or train on more clusters (a denser plan)."
    return info


def prefetch_final(fitter: HeldOutRefits, method: str, options: dict[str, Any]) -> tuple[CdcModel, float]:
    """Worker job of :meth:`Fitter.prefetch`: the final model and its fit time [s]."""
    start = time.perf_counter()
    model = build_model(fitter, method, options)
    return model, time.perf_counter() - start


