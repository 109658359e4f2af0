"""The constant-parameter methods: ``nominal``, ``base`` (3 base-position parameters), ``cpa`` (circular point
analysis, needs single-joint sweeps), ``nls0`` (NLS on the clusters nearest q = 0, damped toward nominal) and ``nls1``
(one NLS over all training data), each registered under its name."""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import replace
from typing import Any, cast

import numpy as np

from calibration.data.recording import standalone_mask
from calibration.errors import ModelError
from calibration.evaluation.metrics import errors
from calibration.identification import GeometricProblem
from calibration.identification.cpa import identify_cpa, split_sweeps
from calibration.identification.observability import Observability, analyse, filter_weights
from calibration.methods import heldout as robust
from calibration.methods.cdc import cluster_anchors
from calibration.methods.folds import HeldOutRefits
from calibration.methods.registry import register
from calibration.models import ConstantModel

log = logging.getLogger("cellcal.calibration")

#: nls0 is flagged when its worst error on the training clusters it does not use exceeds nls1's (held out from
#: them) by this factor: the issue-10 bound on a method's test max against nls1's, applied to training clusters.
NLS0_HELDOUT_MAX_RATIO = 1.5


def _constant(fitter: HeldOutRefits, method: str, x: np.ndarray, n_params: int, **info: Any) -> ConstantModel:
    return ConstantModel(fitter.robot, method, fitter.par.model(x), n_params, dict(info))


@register("nominal")
def fit_nominal(fitter: HeldOutRefits, method: str) -> ConstantModel:
    return ConstantModel(fitter.robot, "nominal", fitter.nominal, 0, {})


@register("base")
def fit_base(fitter: HeldOutRefits, method: str) -> ConstantModel:
    R, p = fitter.nominal.fk(fitter.train.q)
    shift = np.mean(fitter.train.p - p, axis=0)  # the least-squares optimum: orientation does not change
    P = fitter.nominal.P.copy()
    P[:, 0] += shift
    return ConstantModel(fitter.robot, "base", fitter.nominal.with_geometry(fitter.nominal.H, P), 3,
                         {"base_shift_mm": shift.tolist()})


@register("cpa")
def fit_cpa(fitter: HeldOutRefits, method: str) -> ConstantModel:
    if fitter.cpa_data is None:
        raise ModelError("cpa needs single-joint sweep data (a recording with one cluster id per sweep); "
                         "none was given")
    x, circles = identify_cpa(fitter.par, split_sweeps(fitter.cpa_data))
    if fitter.par.fit_tool:
        # Circles give axes and points on them, not where along the last axes the tool sits: the flange
        # shift is fitted on the sweep positions with the axes held.
        g = 4 * fitter.par.n_joints
        basis = np.zeros((fitter.par.size, 3))
        basis[g:] = np.eye(3)
        d = fitter.cpa_data
        x = GeometricProblem(fitter.par, d.q, d.R, d.p, a=0.0, basis=basis, x_ref=x).solve().x[0]
    return _constant(fitter, "cpa", x, fitter.par.size, circle_rms_mm=[c.rms_mm for c in circles])


@register("nls0")
def fit_nls0(fitter: HeldOutRefits, method: str) -> ConstantModel:
    """The paper's NLS on the ``nls0_clusters`` clusters nearest q = 0, damped toward nominal.

    The paper fits these clusters by plain least squares. Their poses sit in one corner of the workspace, so
    directions they see only weakly are fitted to noise and the model extrapolates far worse than nominal
    (3.8 mm max on a shared test recording where nominal reaches 2.3). The one change: a Tikhonov filter toward nominal at a
    relative cutoff (:func:`~calibration.identification.observability.filter_weights`; directions well above
    it are fitted as before, those below it stay near nominal), its cutoff chosen from ``nls0_damping_grid``
    on the training clusters nls0 does not use (held out by construction; one-standard-error rule toward the
    stronger damping). A fold refit takes the cutoff of the fit on every cluster.

    The model carries ``info["heldout"]``: its RMS on those clusters against nls1's held out from its own
    fit (:meth:`held_out_errors`), and ``info["warning"]`` when its worst error there exceeds nls1's by
    :data:`NLS0_HELDOUT_MAX_RATIO`.

    Raises:
        ModelError: the recording has fewer than 2 clusters beyond the ones nls0 fits (nothing to check on).
    """
    groups, anchors = cluster_anchors(fitter.train, fitter.options.cluster_size)
    in_cluster = np.bincount(groups[~standalone_mask(fitter.train)], minlength=len(anchors)) > 0
    distance = np.where(in_cluster, np.linalg.norm(anchors, axis=1), np.inf)  # stand-alone poses: no cluster
    nearest = np.argsort(distance)[: min(fitter.options.nls0_clusters, int(in_cluster.sum()))]
    used = np.isin(groups, nearest)
    sub = fitter.train.subset(used)
    obs = analyse(fitter.par, sub.q, a=fitter.options.a, tolerance=fitter.options.tolerance)
    fits: dict[float, tuple[Observability, np.ndarray]] = {}

    def at(cutoff: float) -> tuple[Observability, np.ndarray]:
        if cutoff not in fits:
            o = replace(obs, tolerance=cutoff, rank=int(np.sum(obs.singular_values >= cutoff *
                                                               obs.singular_values[0])))
            res = GeometricProblem(fitter.par, sub.q, sub.R, sub.p, a=fitter.options.a,
                                   prior_weight=filter_weights(o)).solve()
            if not res.converged.all():
                log.warning("nls0 fit stopped after %d iterations without converging (%s)", res.iterations,
                            res.reason[0].value)
            fits[cutoff] = o, res.x[0]
        return fits[cutoff]

    info: dict[str, Any] = {"clusters": nearest.tolist()}
    if fitter.warm is not None:  # a fold refit is not checked: the fit on every cluster was
        cutoff = nls0_damping(fitter.warm)
    else:
        cutoff, info["damping"], info["heldout"] = _nls0_held_out(fitter, at, used, groups)
        if "warning" in info["heldout"]:
            info["warning"] = info["heldout"].pop("warning")
    o, x = at(cutoff)
    fitter._cache.nls0_damping = cutoff
    # the parameters it carries, as every kind counts them (cpa, pi, the CDC methods); the ones the data could
    # not see are named in hidden_directions (a rank here made nls1 "11 parameters" beside pi's full 77)
    return _constant(fitter, "nls0", x, fitter.par.size, **info, hidden_directions=o.unobservable())


def nls0_damping(fitter: HeldOutRefits) -> float:
    """The Tikhonov cutoff of ``nls0`` (FitOptions.nls0_damping, or the one chosen on held-out clusters)."""
    if fitter.options.nls0_damping is not None:
        return fitter.options.nls0_damping
    if fitter._cache.nls0_damping is None:
        fitter.fit("nls0")
    return cast(float, fitter._cache.nls0_damping)  # set by the nls0 fit just run


def _nls0_held_out(fitter: HeldOutRefits, at: Callable[[float], tuple[Observability, np.ndarray]], used: np.ndarray,
                   groups: np.ndarray) -> tuple[float, dict[str, Any], dict[str, Any]]:
    """nls0's cutoff (FitOptions.nls0_damping, else the one of ``nls0_damping_grid`` best on the training
    clusters it does not use: ``~used``, a mask over the training poses, ``groups`` their cluster index), how
    it was chosen, and the held-out figures of that fit against nls1's on those clusters (with a warning)."""

    rest = ~used
    groups = np.unique(groups[rest], return_inverse=True)[1]
    if groups.size == 0 or groups.max() < 1:
        raise ModelError(f"nls0 needs at least 2 training clusters beyond the {fitter.options.nls0_clusters} it "
                         f"fits, to choose its damping and check it on them; the recording has "
                         f"{len(np.unique(fitter.train.clusters(fitter.options.cluster_size)))}. Use nls1, or a training "
                         "recording with more clusters")
    held = fitter.train.subset(rest)
    nominal_mm = errors(fit_nominal(fitter, "nominal"), held).position_mm
    if fitter.options.nls0_damping is not None:
        cutoff = fitter.options.nls0_damping
        damping: dict[str, Any] = {"chosen": cutoff, "grid": None}
    else:
        grid = tuple(fitter.options.nls0_damping_grid)
        scores = [robust.HeldOut.of_errors(errors(_constant(fitter, "nls0", at(c)[1], 0), held).position_mm,
                                           nominal_mm, groups) for c in grid]
        cutoff = grid[robust.one_se_choice(grid, scores)]
        damping = {"chosen": cutoff, "grid": list(grid), "heldout_rms_mm": [round(s.rms_mm, 4) for s in scores],
                   "se_mm": [round(s.se_rms_mm, 4) for s in scores]}
    nls1_mm = cast(np.ndarray, fitter.held_out_errors("nls1"))[rest]  # None for diagnosed only
    h = robust.HeldOut.of_errors(errors(_constant(fitter, "nls0", at(cutoff)[1], 0), held).position_mm,
                                 nls1_mm, groups)
    heldout: dict[str, Any] = {
        "clusters": int(groups.max()) + 1, "rms_mm": round(h.rms_mm, 4), "max_mm": round(h.max_mm, 4),
        "nls1_rms_mm": round(h.reference_rms_mm, 4), "nls1_max_mm": round(h.reference_max_mm, 4),
        "nominal_rms_mm": round(float(np.sqrt(np.mean(nominal_mm ** 2))), 4)}
    log.info("nls0 damping %g (%s) on the %d training clusters it does not use: %s", cutoff, damping,
             heldout["clusters"], heldout)
    if h.max_mm > NLS0_HELDOUT_MAX_RATIO * h.reference_max_mm:
        heldout["warning"] = (
            f"nls0 extrapolates from the {fitter.options.nls0_clusters} clusters nearest q = 0: on the other "
            f"{heldout['clusters']} training clusters its position error reaches {h.max_mm:.3f} mm (RMS "
            f"{h.rms_mm:.3f}) against {h.reference_max_mm:.3f} mm (RMS {h.reference_rms_mm:.3f}) for nls1 held "
            f"out from them (x{h.max_mm / max(h.reference_max_mm, 1e-12):.2f} on the max), even damped toward "
            f"nominal at cutoff {cutoff:g}. Prefer nls1 or pi.")
    return cutoff, damping, heldout


@register("nls1")
def fit_nls1(fitter: HeldOutRefits, method: str) -> ConstantModel:
    obs = fitter.observability()
    return _constant(fitter, "nls1", fitter.global_fit(), fitter.par.size, hidden_directions=obs.unobservable(),
                          warning=obs.summary())

