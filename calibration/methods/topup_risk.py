"""Whether top-up poses help at all: the expected task error of the global fit itself, its misfit included.

:func:`calibration.methods.topup.choose` ranks candidates by the posterior variance of a Bayesian model that learns
every error it has a term for; under it a measured pose can never hurt. The fit the product runs does not: pi (and
the global part of every recommended model) fits global parameters only, so the configuration-dependent error
``f(q)`` at the poses it is fitted on goes into those parameters. Where the added poses lie near the task, the
absorbed ``f`` is the task's own and the fit gains; where they lie far from it (the halves-swapped split of issue 33:
task poses 1.08 rad from the nearest candidate on average), the fit bends its parameters to another region's error
and can lose on the task, as adding every far candidate did on 0620 after and 0725.

This module computes that loss in closed form. With the parametric rows ``J`` (unit prior on the scaled parameters,
``param_sd_mm`` per parameter), ``f = Phi w`` the Nystroem Gaussian process of :class:`~calibration.methods.topup
.Features` (``gp_scale_mm`` per coordinate, ``length_rad``), pose weights ``W`` (1 per training pose, the fits'
``add_weight`` per added pose) and noise ``s2``, the fit is ``delta_hat = H^-1 J^T W y`` with
``H = J^T W J + s2 I``, and its position error at a task pose ``t`` has the expected square::

    r_t = s2^2 |A_t|^2  +  |A_t B - Phi_t|^2  +  s2 tr(A_t N A_t^T),   A_t = J_t H^-1,
    B = J^T W Phi,  N = J^T W^2 J

(parameters the data leaves to the prior; the misfit: ``f`` absorbed from the data minus ``f`` at the task; noise).
Adding a far pose lowers the first term and can raise the second: the criterion
(mean + ``tail_weight`` x the mean of the worst ``tail``, as in the design) of :func:`fit_risk` along the design's
order says how many of its poses to keep (:meth:`FitRisk.useful`, possibly none: the selection then declines).

The three scales are not set by hand: :func:`fold_log_likelihoods` scores them on a training recording's held-out
folds (errors of pi refitted without clusters at random, without the q1/q4-q6 steps, without the q2 and q3 edges),
and :data:`RISK_PRIOR` holds the choice of the 7 R1 days' folds together (their log-likelihoods added:
``scripts/benchmarks/bench_topup.py --risk-scales``). What those folds can and cannot tell: each day alone chooses
very different scales (parameter prior 0.03-1 mm-equivalent, misfit 0.02-0.5 mm over 0.25-1 rad), since every fold
lies within a few degrees of the poses fitted, while the loss this model is for happens about 1 rad away. Under
the pooled choice no pick of the top-up protocol on the 7 days is declined; under each day's own choice the
halves-swapped picks of 0516, 0627 after, 0725 and 0801 would be (issue 33's notes give the figures).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from calibration.data.recording import DEFAULT_ADD_WEIGHT
from calibration.errors import ModelError
from calibration.methods.topup import Features, TopupPrior, farthest_points

#: The risk model's defaults: parameter prior, misfit level and length of the largest likelihood of the 7 R1 days'
#: held-out training folds together (module docstring); no test recording was read for them.
RISK_PRIOR = TopupPrior(param_sd_mm=0.3, gp_scale_mm=0.05, length_rad=0.25)
#: The grids :func:`held_out_risk_scales` searches.
RISK_PARAM_GRID_MM = (0.03, 0.1, 0.3, 1.0)
RISK_LEVEL_GRID_MM = (0.0, 0.02, 0.05, 0.1, 0.15, 0.2, 0.3, 0.5)
RISK_LENGTH_GRID_RAD = (0.25, 0.5, 1.0, 2.0)
RISK_RESIDUAL_GRID_MM = (0.02, 0.03, 0.05, 0.08, 0.1, 0.12, 0.15, 0.2, 0.3)


@dataclass(frozen=True)
class FitRisk:
    """What :func:`fit_risk` returns.

    Attributes:
        risk_mm2: expected squared position error of the global fit at each task pose read, after the first k added
            poses, shape (K + 1, T) (row 0: TRAIN alone).
        criterion_mm2: mean + tail_weight x worst-tail mean of each row, shape (K + 1,).
    """

    risk_mm2: np.ndarray
    criterion_mm2: np.ndarray

    def useful(self, k: int | None = None) -> int:
        """How many of the first ``k`` added poses (default all) to keep: all k when the fit is predicted to do
        better on the task with them than with TRAIN alone, else the count of the least predicted error (0: decline).

        Only the sign of the whole set's predicted gain decides whether all are kept: the model is built to tell
        a set that helps from one that harms (poses far from the task, its misfit), not to rank prefixes whose
        predicted errors differ by a few micrometres (the real fits are damped and weighted, and the recommended
        models add a local part that uses poses near the task, which this global-only model does not credit)."""
        return useful_count(self.criterion_mm2, len(self.criterion_mm2) - 1 if k is None else k)

    @property
    def rms_mm(self) -> np.ndarray:
        """RMS over the task of the predicted error after each k, shape (K + 1,)."""
        return np.asarray(np.sqrt(self.risk_mm2.mean(axis=1)), dtype=float)


def useful_count(criterion_mm2: np.ndarray | list[float], k: int) -> int:
    """:meth:`FitRisk.useful` of the criterion along a design's order (entry 0: TRAIN alone), for its first k poses."""
    crit = np.asarray(criterion_mm2, dtype=float)
    if isinstance(k, bool) or not 0 <= int(k) < len(crit):
        raise ModelError(f"top-up risk: k must be in 0..{len(crit) - 1}, got {k!r}")
    crit = crit[: int(k) + 1]
    return int(k) if crit[-1] < crit[0] else int(np.argmin(crit))


def _rows(feats: Features, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Parametric rows (N, 6, m) and the misfit's position rows (N, 3, G) of the feature map."""
    F = feats.rows(q)
    return F[:, :, : feats.m], F[:, :3, feats.m:]


def _task_risk(J_t: np.ndarray, P_t: np.ndarray, H: np.ndarray, B: np.ndarray, N: np.ndarray,
               s2: float) -> np.ndarray:
    """``r_t`` of the module docstring for task rows J_t (T, 3, m), P_t (T, 3, G), shape (T,)."""
    A = J_t @ np.linalg.inv(H)  # (T, 3, m)
    E = A @ B - P_t
    r = s2 ** 2 * np.sum(A * A, axis=(1, 2)) + np.sum(E * E, axis=(1, 2)) + s2 * np.sum((A @ N) * A, axis=(1, 2))
    return np.asarray(r, dtype=float)


def _tail_mean(v: np.ndarray, tail: float) -> float:
    n = max(1, int(np.ceil(tail * len(v))))
    return float(np.mean(np.sort(v)[-n:]))


def fit_risk(nominal: object, q_given: np.ndarray, q_added: np.ndarray, q_task: np.ndarray,
             prior: TopupPrior = RISK_PRIOR, add_weight: float = DEFAULT_ADD_WEIGHT,
             theta: np.ndarray | None = None) -> FitRisk:
    """The global fit's expected task error after each prefix of ``q_added`` (module docstring).

    Args:
        nominal: the robot's nominal model.
        q_given: the training poses [rad], shape (N, 6), each of weight 1.
        q_added: the poses to add, in order [rad], shape (K, 6), each of weight ``add_weight``.
        q_task: the task's configurations [rad], shape (T, 6) (at most ``prior.max_task`` read, evenly spaced).
        prior: the risk model's scales (:data:`RISK_PRIOR`, or :func:`held_out_risk_scales`'s choice).
        add_weight: weight of each added pose in the fit (``fit --add-weight``).

    Raises:
        ModelError: no task configuration, or a weight that is not positive.
    """
    q_given = np.asarray(q_given, dtype=float).reshape(-1, 6)
    q_added = np.asarray(q_added, dtype=float).reshape(-1, 6)
    q_task = np.asarray(q_task, dtype=float).reshape(-1, 6)
    if not len(q_task):
        raise ModelError("top-up risk: the task has no configuration")
    if not (np.isfinite(add_weight) and add_weight > 0):
        raise ModelError(f"top-up risk: the added poses' weight must be positive, got {add_weight!r}")
    if len(q_task) > prior.max_task:
        q_task = q_task[np.unique(np.linspace(0, len(q_task) - 1, prior.max_task).round().astype(int))]
    known = np.concatenate([q_given, q_added, q_task])
    feats = Features(nominal, prior, known[farthest_points(known, prior.n_inducing)], theta)
    s2 = prior.noise_mm ** 2
    J_g, P_g = _rows(feats, q_given)
    J_a, P_a = _rows(feats, q_added)
    J_t = _rows(feats, q_task)[0][:, :3]
    P_t = _rows(feats, q_task)[1]
    JJ = np.einsum("nim,nik->mk", J_g, J_g)
    H, N = JJ + s2 * np.eye(feats.m), JJ.copy()
    B = np.einsum("nim,nig->mg", J_g[:, :3], P_g)
    risks = [_task_risk(J_t, P_t, H, B, N, s2)]
    for j in range(len(q_added)):
        jj = J_a[j].T @ J_a[j]
        H, N = H + add_weight * jj, N + add_weight ** 2 * jj
        B = B + add_weight * J_a[j, :3].T @ P_a[j]
        risks.append(_task_risk(J_t, P_t, H, B, N, s2))
    r = np.asarray(risks)
    crit = np.array([row.mean() + prior.tail_weight * _tail_mean(row, prior.tail) for row in r])
    return FitRisk(r, crit)


@dataclass(frozen=True)
class RiskScales:
    """The risk model's scales chosen on held-out training folds (:func:`held_out_risk_scales`).

    Attributes:
        prior: :data:`RISK_PRIOR` with the chosen ``param_sd_mm``, ``gp_scale_mm`` and ``length_rad``.
        residual_mm: white error per coordinate the folds' errors hold beyond the model (noise included) [mm].
        held_out_poses: held-out predictions the choice read.
        log_likelihood: of the fold errors under the choice.
    """

    prior: TopupPrior
    residual_mm: float
    held_out_poses: int
    log_likelihood: float

    def to_json(self) -> dict[str, float | int]:
        return {"param_sd_mm": self.prior.param_sd_mm, "gp_scale_mm": self.prior.gp_scale_mm,
                "length_rad": self.prior.length_rad, "residual_mm": self.residual_mm,
                "held_out_poses": self.held_out_poses, "log_likelihood": self.log_likelihood}


def _fold_terms(J: np.ndarray, P: np.ndarray, mask: np.ndarray, sd: float, s2: float
                ) -> tuple[np.ndarray, np.ndarray]:
    """For one fold (poses ``mask`` held out, the rest fitted at weight 1) and a unit misfit level: the expected
    squared error at each held-out pose without the misfit term (prior + noise), and the misfit term, shapes (h,)."""
    Jg, Pg = J[~mask] * sd, P[~mask]
    JJ = np.einsum("nim,nik->mk", Jg, Jg)
    H = JJ + s2 * np.eye(JJ.shape[0])
    B = np.einsum("nim,nig->mg", Jg[:, :3], Pg)
    A = (J[mask][:, :3] * sd) @ np.linalg.inv(H)
    base = s2 ** 2 * np.sum(A * A, axis=(1, 2)) + s2 * np.sum((A @ JJ) * A, axis=(1, 2))
    E = A @ B - P[mask]
    return base, np.sum(E * E, axis=(1, 2))


def fold_log_likelihoods(nominal: object, q: np.ndarray, held_out: list[np.ndarray], error_mm: list[np.ndarray],
                         prior: TopupPrior = RISK_PRIOR, theta: np.ndarray | None = None
                         ) -> dict[tuple[float, float, float, float], float]:
    """Log-likelihood of the held-out errors of the global fit refitted without each fold (a Gaussian 3-D error of
    each pose's predicted RMS norm, ``r_t + 3 residual^2``) for every (param_sd_mm, gp_scale_mm, length_rad,
    residual_mm) of :data:`RISK_PARAM_GRID_MM` x :data:`RISK_LEVEL_GRID_MM` x :data:`RISK_LENGTH_GRID_RAD` x
    :data:`RISK_RESIDUAL_GRID_MM`. Only training poses and their errors are read; tables of several recordings add.

    Args:
        q: the training poses [rad], shape (N, 6).
        held_out: per fold, the poses (N,) held out of the refit.
        error_mm: per fold, the refit model's position error [mm] at the held-out poses, shape (held,).

    Raises:
        ModelError: no fold, or a fold's errors not one per held-out pose.
    """
    q = np.asarray(q, dtype=float).reshape(-1, 6)
    if not held_out or len(held_out) != len(error_mm):
        raise ModelError(f"held-out risk scales: need one error array per fold, got {len(held_out)} folds and "
                         f"{len(error_mm)} error arrays")
    masks = [np.asarray(m, dtype=bool) for m in held_out]
    errs = [np.asarray(e, dtype=float) for e in error_mm]
    for m, e in zip(masks, errs):
        if m.shape != (len(q),) or e.shape != (int(m.sum()),):
            raise ModelError(f"held-out risk scales: a fold holds out {int(m.sum())} of {len(q)} poses but has "
                             f"{e.size} errors")
    e2 = np.concatenate(errs) ** 2
    s2 = prior.noise_mm ** 2
    table = {}
    for length in RISK_LENGTH_GRID_RAD:
        unit = replace(prior, param_sd_mm=1.0, gp_scale_mm=1.0, length_rad=length)
        feats = Features(nominal, unit, q[farthest_points(q, prior.n_inducing)], theta)
        J, P = _rows(feats, q)
        for sd in RISK_PARAM_GRID_MM:
            terms = [_fold_terms(J, P, m, sd, s2) for m in masks]
            base = np.concatenate([t[0] for t in terms])
            mis = np.concatenate([t[1] for t in terms])
            for level in RISK_LEVEL_GRID_MM:
                for res in RISK_RESIDUAL_GRID_MM:
                    s3 = (base + level ** 2 * mis + 3 * res ** 2) / 3
                    table[(sd, level, length, res)] = float(np.sum(-1.5 * np.log(s3) - 0.5 * e2 / s3))
    return table


def best_scales(table: dict[tuple[float, float, float, float], float], held_out_poses: int,
                prior: TopupPrior = RISK_PRIOR) -> RiskScales:
    """The scales of the largest log-likelihood in ``table`` (:func:`fold_log_likelihoods`, or a sum of them)."""
    if not table:
        raise ModelError("held-out risk scales: empty grid")
    (sd, level, length, res), ll = max(table.items(), key=lambda kv: kv[1])
    return RiskScales(replace(prior, param_sd_mm=sd, gp_scale_mm=level, length_rad=length), res, held_out_poses, ll)


def held_out_risk_scales(nominal: object, q: np.ndarray, held_out: list[np.ndarray], error_mm: list[np.ndarray],
                         prior: TopupPrior = RISK_PRIOR, theta: np.ndarray | None = None) -> RiskScales:
    """The risk model's parameter prior, misfit level and length (and a white residual) of the largest likelihood of
    one training recording's held-out errors (:func:`fold_log_likelihoods`, whose arguments these are)."""
    table = fold_log_likelihoods(nominal, q, held_out, error_mm, prior, theta)
    return best_scales(table, int(sum(np.asarray(m, dtype=bool).sum() for m in held_out)), prior)
