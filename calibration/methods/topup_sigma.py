"""The predicted sigma's residual level, chosen on the training recording itself: what ``predict``, ``evaluate`` and
``select`` use with ``--given``.

:func:`calibration.methods.topup.predicted_position_cov` adds a residual per coordinate to the parametric part's
posterior: the configuration-dependent error a global model never learns. Its level differs from day to day
(0.08-0.15 mm on the 7 R1 days with a test), so a fixed one is over- or under-confident. Here it is chosen as
``scripts/benchmarks/bench_topup.py`` chose it (issue 33): pi is refitted without each of 8 folds of the given
recording (the 5 folds of whole clusters the recommendation holds out, the poses stepping q1/q4-q6 away from their
anchor, the clusters at either edge of q2 and of q3: :mod:`calibration.data.folds`), and the level is the maximum
likelihood one of those refits' errors at the held-out poses
(:func:`calibration.methods.topup.held_out_sigma_scales`). Only the given recording is read; it costs 8 pi refits.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from calibration.data.folds import EDGE_JOINTS, edge_mask, step_mask
from calibration.evaluation.metrics import errors
from calibration.methods.folds import HeldOutRefits
from calibration.methods.shared import SharedCache
from calibration.methods.topup import SigmaScales, held_out_sigma_scales

#: The global model whose held-out errors set the level (the recommended models' global part).
SIGMA_METHOD = "pi"


def sigma_fold_masks(fitter: HeldOutRefits) -> list[np.ndarray]:
    """The poses (N,) each fold of the module docstring holds out, in that order: the held-out cluster folds of
    ``fitter``, then the q1/q4-q6 steps and the q2 and q3 edges (each when it holds out some poses, not all)."""
    train = fitter.train
    extra = [step_mask(train)] + [edge_mask(train, j) for j in EDGE_JOINTS]
    return fitter.fold_masks() + [m for m in extra if m.any() and not m.all()]


def held_out_folds(fitter: HeldOutRefits) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """``(masks, errors)``: per fold of :func:`sigma_fold_masks`, the poses (N,) it holds out and the position errors
    [mm] of :data:`SIGMA_METHOD` refitted without them at those poses.

    Raises:
        ModelError: the recording has fewer than 2 clusters to hold out.
    """
    train = fitter.train
    e = np.asarray(fitter.held_out_errors(SIGMA_METHOD))
    masks = sigma_fold_masks(fitter)
    n_clusters = len(fitter.fold_masks())
    errs = [e[m] for m in masks[:n_clusters]]
    for m in masks[n_clusters:]:
        model, _ = replace(fitter, train=train.subset(~m), warm=fitter, _cache=SharedCache()).fit(SIGMA_METHOD)
        errs.append(errors(model, train.subset(m)).position_mm)
    return masks, errs


def held_out_residual(fitter: HeldOutRefits) -> SigmaScales:
    """The predicted sigma's scales chosen on ``fitter``'s training recording (module docstring): the residual per
    coordinate [mm] of the largest likelihood, the parameter prior the fixed one."""
    masks, errs = held_out_folds(fitter)
    return held_out_sigma_scales(fitter.nominal, fitter.train.q, masks, errs)

