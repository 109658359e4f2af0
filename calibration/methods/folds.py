"""Held-out refits: every method refitted without each fold of whole training clusters (the recommendation's
held-out errors and the neural kinds' check), in this process or in forked workers
(:class:`calibration.workers.ForkPool`).

:class:`HeldOutRefits` adds them to the shared fits; a fold's refit is a fresh fitter of the same class on the other
clusters, warm-started from this one, so it reaches the methods through the same dispatch (:meth:`HeldOutRefits.fit`,
the facade's registry lookup)."""

from __future__ import annotations

import multiprocessing as mp
import time
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from calibration import workers
from calibration.evaluation.metrics import errors
from calibration.method_names import CDC_METHODS, NEURAL_METHODS, cdc_method
from calibration.methods import heldout as robust
from calibration.methods.cdc import cluster_anchors
from calibration.methods.shared import SharedCache, SharedFits
from calibration.models import KinematicModel


@dataclass
class HeldOutRefits(SharedFits, ABC):
    """The shared fits, with every method's fold refits (cached) and the worker pool that may run them."""

    @abstractmethod
    def fit(self, method: str) -> tuple[KinematicModel, float]:
        """Fit one method: the model and its fit time [s] (:meth:`calibration.methods.fitter.Fitter.fit`)."""

    def held_out_errors(self, method: str) -> np.ndarray | None:
        """Position error [mm] of every training pose as predicted by ``method`` fitted without that pose's
        cluster: k-fold over whole clusters (:func:`robust.cluster_folds`, the folds of the CDC checks), shape (N,).

        ``nominal`` and ``cpa`` never see the training poses: their training errors are held-out errors. Every
        other method is refitted on each fold's other clusters by a :attr:`warm` Fitter (global fits started
        from, and the local prior and Fourier ridge taken from, this one's fit on every cluster; so the method
        is fitted here first). None for ``diagnosed`` (a fold refit would rerun the whole diagnosis).
        """

        if method == "diagnosed":
            return None
        if method in ("nominal", "cpa"):
            return errors(self.fit(method)[0], self.train).position_mm
        if method not in self._cache.fitted:
            self.fit(method)  # chooses the strengths the fold refits reuse
        return self._fold_errors(method)

    def _fold_errors(self, method: str) -> np.ndarray:
        """:meth:`held_out_errors` of a method whose strengths are chosen (cached)."""
        cache = self._cache.held_out_errors
        if method not in cache:
            err = np.empty(len(self.train))
            for f, (held, _) in enumerate(self._fold_fitters()):
                err[held] = self._fold_error(method, f)
            cache[method] = err
        return cache[method]

    def _fold_error(self, method: str, fold: int) -> np.ndarray:
        """Position errors [mm] on fold ``fold``'s poses of ``method`` refitted without them (cached; collected
        from a worker when one refits it)."""
        cached = self._cache.fold_errors
        if (method, fold) not in cached:
            job = self._cache.fold_jobs.pop((method, fold), None)
            err, seconds = self._collect(job) if job is not None else _fold_error_of(self, method, fold)
            cached[method, fold] = err
            self._cache.fold_seconds[method, fold] = seconds
        return cached[method, fold]

    def fold_masks(self) -> list[np.ndarray]:
        """The poses (N,) each fold of :meth:`held_out_errors` holds out (whole clusters)."""
        return [held for held, _ in self._fold_fitters()]

    def _fold_fitters(self) -> list[tuple[np.ndarray, HeldOutRefits]]:
        """``(held-out mask, Fitter on the other clusters)`` per fold, shared by every method (cached)."""
        if self._cache.folds is None:
            self._require_clusters(2, "held-out figures (each fold refitted on the other clusters)")
            groups, anchors = cluster_anchors(self.train, self.options.cluster_size)
            folds = robust.cluster_folds(len(anchors), robust.N_FOLDS, self.options.seed)[groups]
            self._cache.folds = [(folds == f, replace(self, train=self.train.subset(folds != f), warm=self,
                                                      _cache=SharedCache())) for f in range(robust.N_FOLDS)]
        return self._cache.folds

    def prefetch_held_out_errors(self, methods: list[str] | tuple[str, ...]) -> None:
        """:meth:`held_out_errors` of the neural CDC methods among ``methods``, their fold refits (a network
        trained per method and fold, the bulk of a recommendation's cost) run in forked worker processes; the same
        bits as refitted here (every training is deterministic on one BLAS thread).

        The fold Fitters' shared fits (reference, local fits) are made here first, so no worker repeats them.
        A no-op without the ``fork`` start method or with one usable core.
        """
        cache = self._cache.held_out_errors
        neural = [m for m in methods if m in NEURAL_METHODS and m not in cache]
        if not neural or workers.default_workers(robust.N_FOLDS) < 2 or "fork" not in mp.get_all_start_methods():
            return
        for m in neural:
            if m not in self._cache.fitted:
                self.fit(m)  # chooses the strengths the fold refits reuse
        try:
            self._submit_folds([(m, f) for m in neural for f in range(robust.N_FOLDS)])
            for m in neural:
                self._fold_errors(m)  # a worker that died raises BrokenProcessPool
        except BaseException:
            self._shutdown_jobs()
            raise

    def _prepare_folds(self, jobs: list[tuple[str, int]]) -> None:
        """The shared fits (reference, local fits) of the fold refits ``(CDC method, fold)``, made here."""
        folds = self._fold_fitters()
        for reference, f in dict.fromkeys((cdc_method(m)[0], f) for m, f in jobs if m in CDC_METHODS):
            folds[f][1].reference(reference)
            folds[f][1].local_fits(reference)

    def _submit(self, job: Callable[..., Any], *args: Any) -> Any:
        """``job(*args)`` in this Fitter's worker pool (made on first use), a future. The workers fork at the first
        submit and run every later job with this Fitter as it was then (:class:`calibration.workers.ForkPool`)."""
        if self._cache.pool is None:
            self._cache.pool = workers.ForkPool(workers.default_workers(robust.N_FOLDS), self)
        return self._cache.pool.submit(job, *args)

    def _submit_folds(self, jobs: list[tuple[str, int]]) -> None:
        """Start the fold refits ``(method, fold)`` not yet made or started, in forked workers (in this process
        when there is one usable core or no ``fork``)."""
        cached, pending = self._cache.fold_errors, self._cache.fold_jobs
        jobs = [j for j in jobs if j not in cached and j not in pending]
        if not jobs or workers.default_workers(robust.N_FOLDS) < 2 or "fork" not in mp.get_all_start_methods():
            return
        if self._cache.pool is None:  # workers forked later see them
            self._prepare_folds(jobs)
        for m, f in jobs:
            pending[m, f] = self._submit(_fold_error_job, m, f)

    def _collect(self, future: Any) -> Any:
        """A worker job's result; the pool is shut once no job is pending."""
        try:
            return future.result()  # a worker that died raises BrokenProcessPool
        finally:
            if not self._cache.prefetched and not self._cache.fold_jobs:
                self._shutdown_jobs()

    def _shutdown_jobs(self) -> None:
        """Drop the jobs not started and wait for the workers to exit."""
        pool, self._cache.pool = self._cache.pool, None
        if pool is not None:
            pool.shutdown()
        self._cache.fold_jobs, self._cache.prefetched = {}, {}  # new ones: a caller may hold the old

    def abort_jobs(self) -> None:
        """Stop every worker process now (the network pool and ``diagnosed``'s), its results dropped: after a
        failure or an interrupt in the parent, which must not wait for a fit nobody will collect."""
        job, self._cache.diagnosis_job = self._cache.diagnosis_job, None
        for pool in (job[0] if job else None, self._cache.pool):
            if pool is not None:
                pool.terminate()
        self._shutdown_jobs()  # drops the network jobs' bookkeeping (their workers are gone already)


def _fold_error_of(fitter: HeldOutRefits, method: str, fold: int) -> tuple[np.ndarray, float]:
    """``method`` refitted without fold ``fold``'s clusters of ``fitter``: its position errors [mm] on them and the
    refit's time [s]."""

    start = time.perf_counter()
    held, sub = fitter._fold_fitters()[fold]
    err = errors(sub.fit(method)[0], fitter.train.subset(held)).position_mm
    return err, time.perf_counter() - start


def _fold_error_job(fitter: HeldOutRefits, method: str, fold: int) -> tuple[np.ndarray, float]:
    """Worker job of :meth:`HeldOutRefits._submit_folds`: :func:`_fold_error_of` on the Fitter that forked it."""
    return _fold_error_of(fitter, method, fold)


