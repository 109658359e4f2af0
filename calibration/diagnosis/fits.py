"""The joint fits of diagnose's held-out check, each made once, the independent ones side by side.

The check (:func:`calibration.diagnosis.core.confirm_on_heldout`) refits the model in use with sets of effects: the
kinds kept so far, each further kind on top of them, and both again in their most flexible form. Several of those
fits do not depend on each other's outcome, and the same set is asked for more than once (the flexible form that
tests a further kind is the one that may replace the kept kinds). :class:`JointFits` remembers every fit by the
effects it holds, and :meth:`JointFits.start` hands fits to forked worker processes before they are needed, so
that on two cores the fits of one step of the check run at the same time.

Every fit is the same deterministic computation wherever it runs (single-threaded BLAS, as the CLI and the tests
set), so the outcome is the same bits with or without workers; only the time changes.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Future

import numpy as np

from calibration.diagnosis.refit import JointFit
from calibration.physics.base import Effect
from calibration.workers import ForkPool

#: An effect template with its parameter basis, as diagnose's selection passes them.
Chosen = list[tuple[Effect, np.ndarray]]


def _fit_job(fit: Callable[[Chosen], JointFit], chosen: Chosen) -> JointFit:
    """Worker job: one joint fit with ``chosen`` (``fit`` shared by the fork, without pickling the model in use and
    the recording)."""
    return fit(chosen)


class JointFits:
    """Joint fits ``fit(chosen)``, each computed once per set of effect templates and their bases (by identity;
    the sets asked for are kept, so no identity is reused while this lives).

    Args:
        fit: the joint fit of the model in use with ``chosen`` on the fit data.
        workers: processes for fits started ahead (1: every fit in this process, when it is asked for).
    """

    def __init__(self, fit: Callable[[Chosen], JointFit], workers: int = 1) -> None:
        self._fit = fit
        self._done: dict[tuple[tuple[int, int], ...], tuple[Chosen, JointFit]] = {}
        self._pending: dict[tuple[tuple[int, int], ...], tuple[Chosen, Future[JointFit]]] = {}
        self._pool: ForkPool | None = None
        if workers > 1:
            self._pool = ForkPool(workers, fit)  # the workers fork on the first submit, each with ``fit``

    @staticmethod
    def _key(chosen: Chosen) -> tuple[tuple[int, int], ...]:
        return tuple((id(e), id(B)) for e, B in chosen)

    def start(self, *sets: Chosen) -> None:
        """Hand the fits of ``sets`` not made or started yet to the workers (a no-op without workers)."""
        if self._pool is None:
            return
        for chosen in sets:
            key = self._key(chosen)
            if key not in self._done and key not in self._pending:
                self._pending[key] = (list(chosen), self._pool.submit(_fit_job, list(chosen)))

    def get(self, chosen: Chosen) -> JointFit:
        """The fit with ``chosen``: remembered, collected from a worker, or made here."""
        key = self._key(chosen)
        if key not in self._done:
            if key in self._pending:
                kept, future = self._pending.pop(key)
                self._done[key] = (kept, future.result())  # a worker that died raises BrokenProcessPool
            else:
                self._done[key] = (list(chosen), self._fit(list(chosen)))
        return self._done[key][1]

    def close(self) -> None:
        """Drop the fits not started and wait for the workers to exit."""
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None
        self._pending.clear()

    def __enter__(self) -> JointFits:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
