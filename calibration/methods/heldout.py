"""Robustness checks of configuration-dependent (CDC) fits on the training recording alone.

Two checks, both blind to any test recording:

- **Held-out clusters.** The anchors are split into folds of whole clusters (the 7-pose groups); for each
  fold the interpolator is refitted on the other clusters' local parameters and the CDC model predicts the
  held-out clusters' poses. The figure is the position RMS over all held-out poses [mm], next to the same
  figure for the constant reference (the global fit the local fits are pulled toward). It chooses the
  strengths of :mod:`calibration.methods.fitter` (local prior, ridge, smoothing, weight decay) and flags an
  interpolator that does worse than the constant fit on clusters it has not seen.
- **Corrections over the workspace.** The CDC model's position correction over the reference at probe
  configurations spread over the joint limits (wrist and base joints anywhere, (q2, q3) at the anchors, so the
  interpolation itself stays in range) should be about as large as on the training poses: local fits that
  absorb directions a 7-pose cluster cannot see show up as corrections several times larger there. The
  figure is the ratio of the 99th percentiles [-].
- **Range at probe configurations.** The interpolated geometric parameters at a grid of (q2, q3) spread over
  the anchors' box widened by ``margin`` must stay near the range the local fits span: the excess beyond
  [min, max] per parameter, in units of that parameter's range, is reported (0 = inside).
"""

from __future__ import annotations

import multiprocessing as mp
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass
from typing import Any

import numpy as np

from calibration.data.recording import Recording
from calibration.errors import ModelError
from calibration.interpolation.base import Interpolator
from calibration.kinematics.arrays import FloatArray
from calibration.physics.extended import ExtendedKinematics
from calibration.workers import ForkPool

#: Default number of held-out folds (whole clusters).
N_FOLDS = 5
#: Folds the neural kinds' (nn, ae) check fits and scores, of N_FOLDS: each is a network training of a second
#: or two. On the 8 R1 training recordings (no test recording read) the held-out / reference ratio over the
#: first 2 folds stayed within 0.03 of the 5-fold figure (5-fold ratios 0.71-0.97 for both kinds, so the flag
#: at 1.25 is the same everywhere; ``python scripts/studies/heldout_folds.py``), for 2 trainings instead of 5. Since
#: issue 14 these folds are the recommendation's full refits (:meth:`calibration.methods.fitter.Fitter.held_out_errors`,
#: against the constant reference refitted alike), not interpolator-only refits: no training for the check alone;
#: on the 8 R1 training recordings the ratios moved by at most 0.03 and no flag changed (``scripts/studies/recommend_days.py``).
NEURAL_EVALUATED_FOLDS = 2
#: A CDC fit whose held-out RMS exceeds the reference's by this factor is flagged.
HELDOUT_RATIO_LIMIT = 1.25


@dataclass(frozen=True)
class HeldOut:
    """Held-out-cluster figures of one fit.

    Attributes:
        rms_mm: position RMS over the held-out poses of the CDC model [mm].
        reference_rms_mm: same for the constant reference.
        max_mm: worst held-out position error of the CDC model [mm].
        reference_max_mm: same for the reference.
        se_rms_mm: standard error of rms_mm over clusters [mm] (delta method on the per-cluster mean squares).
        cluster_ms_mm2: mean squared held-out position error of each held-out cluster [mm^2], in cluster order
            (sorted labels), for paired comparisons of fits scored on the same folds (:func:`paired_se_mm`).
    """

    rms_mm: float
    reference_rms_mm: float
    max_mm: float
    reference_max_mm: float
    se_rms_mm: float
    cluster_ms_mm2: tuple[float, ...] = ()

    @property
    def ratio(self) -> float:
        return self.rms_mm / max(self.reference_rms_mm, 1e-12)

    @classmethod
    def of_errors(cls, err: np.ndarray, ref: np.ndarray, groups: np.ndarray) -> HeldOut:
        """The figures of held-out position errors ``err`` [mm] (N,) against the reference's ``ref`` (N,) on the
        same poses, ``groups`` their cluster labels (N,) (any integers) for the standard error over clusters."""
        err, ref = np.asarray(err, dtype=float), np.asarray(ref, dtype=float)
        groups = np.unique(groups, return_inverse=True)[1]
        per_cluster = np.bincount(groups, err ** 2) / np.bincount(groups)
        rms = float(np.sqrt(np.mean(err ** 2)))
        se = float(per_cluster.std(ddof=1) / np.sqrt(len(per_cluster)) / (2.0 * max(rms, 1e-12)))
        return cls(rms, float(np.sqrt(np.mean(ref ** 2))), float(err.max()), float(ref.max()), se,
                   tuple(float(v) for v in per_cluster))


def cluster_folds(n_clusters: int, n_folds: int = N_FOLDS, seed: int = 0) -> np.ndarray:
    """Fold (0..n_folds-1) of each cluster: a seeded shuffle dealt round-robin, shape (K,)."""
    order = np.random.default_rng(seed).permutation(n_clusters)
    folds = np.empty(n_clusters, dtype=int)
    folds[order] = np.arange(n_clusters) % n_folds
    return folds


def position_errors(kin: ExtendedKinematics, theta: np.ndarray, rec: Recording) -> np.ndarray:
    """Position error norm per sample [mm] of parameters theta (N, size) or (size,) on rec."""
    theta = np.broadcast_to(theta, (len(rec), kin.size))
    _, p = kin.pose(rec.q, np.ascontiguousarray(theta))
    err_mm: FloatArray = np.linalg.norm(rec.p - p, axis=1)
    return err_mm


def _fit_fold(check: HeldOutCheck, f: int) -> np.ndarray:
    """Worker job of :class:`HeldOutCheck`: its fold f (the check shared by the fork, without pickling its
    ``make``, which is usually a lambda)."""
    return check.fold_prediction(f)


class HeldOutCheck:
    """Held-out-cluster error of the interpolator ``make()`` over the local fits, started on construction.

    With ``workers > 1`` (and the ``fork`` start method, i.e. Linux) the folds are fitted in that many forked
    worker processes, so the caller can fit the final model meanwhile and :meth:`result` collects them; the
    figures are the same bits as with ``workers=1`` (every fold is the same deterministic fit, only elsewhere).
    Worth it for the neural kinds, whose 5 fold trainings cost seconds; the cheap kinds stay in-process.

    Args:
        make: a new unfitted interpolator.
        kin, theta_ref: the CDC kinematics and its reference parameters.
        anchors: (K, d) interpolation inputs of the anchors; x_local (K, g) their local geometric parameters.
        groups: cluster index (0..K-1) of each sample of rec.
        rec: the training recording.
        inputs: joint indices the interpolator reads.
        clamp: clip predictions to the training folds' per-parameter range (as the fitted model does).
        n_folds, seed: the folds of :func:`cluster_folds`.
        workers: processes fitting the folds (1: in this process, when the result is asked for).
        reference_mm: the reference's position errors on ``rec`` when the caller already has them.
        n_evaluated: folds fitted and scored, the first ones of the seeded deal (default all): each fit still
            leaves out 1/n_folds of the clusters, so the figures estimate the same held-out error on fewer
            clusters (both RMS figures over the same held-out poses). Fewer trainings for the neural kinds
            (:data:`NEURAL_EVALUATED_FOLDS`).
    """

    def __init__(self, make: Callable[[], Interpolator], kin: ExtendedKinematics, theta_ref: np.ndarray,
                 anchors: np.ndarray, x_local: np.ndarray, groups: np.ndarray, rec: Recording,
                 inputs: tuple[int, ...], clamp: bool = True, n_folds: int = N_FOLDS, seed: int = 0,
                 workers: int = 1, n_evaluated: int | None = None, reference_mm: np.ndarray | None = None) -> None:
        self._reference_mm = reference_mm
        self._kin, self._theta_ref, self._x_local, self._groups, self._rec = kin, theta_ref, x_local, groups, rec
        self._clamp, self._n_total = clamp, n_folds
        self._n_folds = n_folds if n_evaluated is None else int(n_evaluated)
        if not 1 <= self._n_folds <= n_folds:
            raise ModelError(f"n_evaluated must be 1..{n_folds}, got {n_evaluated!r}")
        self._folds = cluster_folds(len(anchors), n_folds, seed)
        self._idx = [np.flatnonzero((self._folds == f)[groups]) for f in range(self._n_folds)]
        queries = [rec.q[idx][:, list(inputs)] for idx in self._idx]
        self._make, self._anchors, self._queries = make, anchors, queries
        self._pool: ForkPool | None = None
        self._pending: list[Future[Any]] = []
        if workers > 1 and "fork" in mp.get_all_start_methods():
            self._pool = ForkPool(min(workers, self._n_folds), self)  # the workers fork during the first submit
            self._pending = [self._pool.submit(_fit_fold, f) for f in range(self._n_folds)]

    @property
    def n_evaluated(self) -> int:
        """Folds fitted and scored."""
        return self._n_folds

    def fold_prediction(self, f: int) -> np.ndarray:
        """Fold f in this process: the interpolator fitted on the other folds' clusters, at fold f's held-out
        queries, shape (n_f, g)."""
        train = self._folds != f
        return self._make().fit(self._anchors[train], self._x_local[train]).predict(self._queries[f])

    def _predictions(self) -> list[np.ndarray]:
        if self._pool is None:
            return [self.fold_prediction(f) for f in range(self._n_folds)]
        try:
            return [f.result() for f in self._pending]  # a worker that died raises BrokenProcessPool
        finally:
            self.cancel()

    def cancel(self) -> None:
        """Drop the folds not started and wait for the workers to exit (the caller failed before asking for the
        result, or has it)."""
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None

    def result(self) -> HeldOut:
        """The figures (waits for the workers)."""
        return self.figures(self._predictions())

    def figures(self, predictions: list[np.ndarray], n_evaluated: int | None = None) -> HeldOut:
        """The figures from the folds' predictions, over the first ``n_evaluated`` folds (default all)."""
        kin, rec, x_local = self._kin, self._rec, self._x_local
        n = len(predictions) if n_evaluated is None else n_evaluated
        g = x_local.shape[1]
        err = np.empty(len(rec))
        for f, (idx, x) in enumerate(zip(self._idx[:n], predictions[:n])):
            if self._clamp:
                train = self._folds != f
                x = np.clip(x, x_local[train].min(axis=0), x_local[train].max(axis=0))
            theta = np.array(np.broadcast_to(self._theta_ref, (len(idx), kin.size)))
            theta[:, :g] = x
            err[idx] = position_errors(kin, theta, rec.subset(idx))
        ref = position_errors(kin, self._theta_ref, rec) if self._reference_mm is None else self._reference_mm
        if n < self._n_total:  # only some clusters held out: both figures over their poses
            rows = np.concatenate(self._idx[:n])
            err, ref, groups = err[rows], ref[rows], self._groups[rows]
        else:
            groups = self._groups
        return HeldOut.of_errors(err, ref, groups)


def held_out(make: Callable[[], Interpolator], kin: ExtendedKinematics, theta_ref: np.ndarray,
             anchors: np.ndarray, x_local: np.ndarray, groups: np.ndarray, rec: Recording,
             inputs: tuple[int, ...], clamp: bool = True, n_folds: int = N_FOLDS, seed: int = 0,
             workers: int = 1, n_evaluated: int | None = None, reference_mm: np.ndarray | None = None) -> HeldOut:
    """Held-out-cluster error of the interpolator ``make()`` over the local fits (see :class:`HeldOutCheck`).

    ``reference_mm`` is ``position_errors(kin, theta_ref, rec)`` when the caller already has it (it does not depend
    on the interpolator, so a choice among strengths computes it once).
    """
    return HeldOutCheck(make, kin, theta_ref, anchors, x_local, groups, rec, inputs, clamp, n_folds, seed,
                        workers, n_evaluated, reference_mm).result()


def one_se_choice(strengths: tuple[float, ...], scores: list[HeldOut]) -> int:
    """Index of the strongest regularisation whose held-out RMS is within one standard error of the best
    (the one-standard-error rule: among fits the data cannot tell apart, the most regularised)."""
    best = int(np.argmin([s.rms_mm for s in scores]))
    limit = scores[best].rms_mm + scores[best].se_rms_mm
    ok = [i for i, s in enumerate(scores) if s.rms_mm <= limit]
    return max(ok, key=lambda i: strengths[i])


def paired_se_mm(a: HeldOut, b: HeldOut) -> float:
    """Standard error [mm] of ``a.rms_mm - b.rms_mm`` over clusters, for two fits scored on the same held-out
    clusters (same folds): the delta method on the per-cluster differences of ``ms / (2 rms)``. Much smaller than
    either fit's own standard error when the clusters that are hard for one are hard for the other."""
    ma, mb = np.asarray(a.cluster_ms_mm2), np.asarray(b.cluster_ms_mm2)
    if ma.shape != mb.shape or ma.size < 2:
        raise ModelError(f"paired standard error needs both fits' per-cluster errors on the same clusters, got "
                         f"{ma.size} and {mb.size}")
    d = ma / (2.0 * max(a.rms_mm, 1e-12)) - mb / (2.0 * max(b.rms_mm, 1e-12))
    return float(d.std(ddof=1) / np.sqrt(d.size))


def paired_one_se_choice(strengths: tuple[float, ...], scores: list[HeldOut], k: float = 1.0) -> int:
    """Index of the strongest regularisation whose held-out RMS exceeds the best's by at most ``k`` times the
    standard error of that difference (:func:`paired_se_mm`): the one-standard-error rule (``k`` = 1) with the paired
    standard error, for fits scored on the same folds (where each fit's own standard error mostly measures how the
    clusters differ, which every fit shares). A larger ``k`` leaves the stronger regularisation only for a weaker one
    the held-out clusters find better by more than ``k`` paired standard errors."""
    best = int(np.argmin([s.rms_mm for s in scores]))
    ok = [i for i, s in enumerate(scores)
          if i == best or s.rms_mm - scores[best].rms_mm <= k * paired_se_mm(s, scores[best])]
    return max(ok, key=lambda i: strengths[i])


#: Rules choosing a strength from held-out scores, by the name :class:`calibration.methods.options.FitOptions` takes.
CHOICE_RULES: dict[str, Callable[[tuple[float, ...], list[HeldOut]], int]] = {
    "one_se": one_se_choice,
    "paired_one_se": paired_one_se_choice,
    "paired_two_se": lambda strengths, scores: paired_one_se_choice(strengths, scores, 2.0),
    "paired_three_se": lambda strengths, scores: paired_one_se_choice(strengths, scores, 3.0)}


# -- gross measurement errors (issue 30) ----------------------------------------------------------------------------

#: A training row is a gross error when its error under the first fit exceeds the median by this many robust
#: standard deviations (1.4826 MAD), in position or in orientation. On the 8 R1 training recordings (training data
#: only; the geometric fit nls1) the largest such score of any row is 7.2 in position and 5.3 in orientation, so 15 is
#: twice the largest clean tail and rejects no row there; a marker swap of 50 mm scores about 500.
GROSS_SCORE = 15.0
#: ... and exceeds these absolute errors: on data with almost no noise (a simulation) the scale is tiny and a row a
#: model leaves 0.2 mm off is no gross error.
GROSS_MIN_MM = 1.0
GROSS_MIN_DEG = 1.0
#: At most this share of the rows is rejected: more rows beyond the bound is a model that does not fit the arm, not a
#: few bad measurements, and none is rejected (the warning says so).
GROSS_MAX_SHARE = 0.05


@dataclass(frozen=True)
class GrossRows:
    """The training rows set aside as gross measurement errors (a marker swap, a wrong rigid body).

    Attributes:
        rows: their 0-based sample indices in the training recording.
        position_mm, orientation_deg: their errors under the fit without them [mm], [deg].
        bound_mm, bound_deg: the bounds they exceed [mm], [deg] (median + GROSS_SCORE robust SDs, at least the
            absolute minimums).
        n_samples: rows in the recording.
        source: the recording.
        beyond: rows beyond the bounds; when more than GROSS_MAX_SHARE of the rows, none is rejected (``rows`` empty).
    """

    rows: tuple[int, ...]
    position_mm: tuple[float, ...]
    orientation_deg: tuple[float, ...]
    bound_mm: float
    bound_deg: float
    n_samples: int
    source: str
    beyond: int = 0

    @property
    def too_many(self) -> bool:
        """More rows beyond the bounds than a few bad measurements: none was rejected."""
        return self.beyond > 0 and not self.rows

    def message(self) -> str:
        """One warning line naming the rows (1-based data rows, header not counted), or '' when nothing to say."""
        if self.too_many:
            return (f"{self.beyond} of {self.n_samples} training rows of {self.source} lie beyond the gross-error bound "
                    f"({self.bound_mm:.3g} mm / {self.bound_deg:.3g} deg), more than {GROSS_MAX_SHARE:.0%}: a model "
                    "that does not fit this arm rather than a few bad measurements, so none was rejected")
        if not self.rows:
            return ""
        shown = ", ".join(f"{i + 1} ({mm:.1f} mm, {deg:.2f} deg)" for i, mm, deg in
                          list(zip(self.rows, self.position_mm, self.orientation_deg))[:10])
        more = f" and {len(self.rows) - 10} more" if len(self.rows) > 10 else ""
        return (f"{len(self.rows)} of {self.n_samples} training rows of {self.source} rejected as gross measurement "
                f"errors (beyond {self.bound_mm:.3g} mm / {self.bound_deg:.3g} deg, {GROSS_SCORE:g} robust SDs above "
                f"the median error; data rows, 1-based): {shown}{more}. Check the markers of those poses")

    def to_json(self) -> dict[str, Any]:
        return {"rows": [i + 1 for i in self.rows], "position_mm": list(self.position_mm),
                "orientation_deg": list(self.orientation_deg), "bound_mm": self.bound_mm, "bound_deg": self.bound_deg,
                "n_samples": self.n_samples, "beyond_bound": self.beyond, "rejected": len(self.rows)}


def gross_bounds(position_mm: np.ndarray, orientation_deg: np.ndarray) -> tuple[float, float]:
    """The gross-error bounds of one fit's errors: median + GROSS_SCORE x 1.4826 MAD per channel, at least
    GROSS_MIN_MM / GROSS_MIN_DEG."""
    def bound(e: np.ndarray, floor: float) -> float:
        med = float(np.median(e))
        return max(med + GROSS_SCORE * 1.4826 * float(np.median(np.abs(e - med))), floor)

    return bound(position_mm, GROSS_MIN_MM), bound(orientation_deg, GROSS_MIN_DEG)


def gross_rows(errors: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]], n: int, source: str = "",
               rounds: int = 3) -> GrossRows:
    """Screen a training recording for gross errors: fit on the rows kept, score every row, repeat until the set is
    stable (at most ``rounds`` fits).

    Args:
        errors: ``errors(keep)`` fits on the rows of the boolean mask ``keep`` (n,) and returns every row's position
            [mm] and orientation [deg] error (n,) under that fit.
        n: rows in the recording.
        source: the recording (for the message).
    """
    keep = np.ones(n, dtype=bool)
    for _ in range(rounds):
        dp, dr = errors(keep)
        b_mm, b_deg = gross_bounds(dp[keep], dr[keep])
        beyond = (dp > b_mm) | (dr > b_deg)
        if beyond.sum() > GROSS_MAX_SHARE * n:
            return GrossRows((), (), (), b_mm, b_deg, n, source, int(beyond.sum()))
        if np.array_equal(~beyond, keep):
            break
        keep = ~beyond
    idx = np.flatnonzero(~keep)
    return GrossRows(tuple(int(i) for i in idx), tuple(float(v) for v in dp[idx]), tuple(float(v) for v in dr[idx]),
                     b_mm, b_deg, n, source, int(idx.size))
