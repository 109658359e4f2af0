"""How many worker processes an expensive check may fork: the usable cores, capped by the caller's number of jobs
(:func:`default_workers`), and none inside a worker or where ``fork`` is not available (:func:`usable_workers`).
The pool those checks fork is :class:`ForkPool`. Imports nothing of the package, so every layer can ask."""

from __future__ import annotations

import multiprocessing as mp
import os
from collections.abc import Callable
from concurrent.futures import Future, ProcessPoolExecutor
from typing import Any


def default_workers(n_jobs: int) -> int:
    """Worker processes for an expensive held-out check: the usable cores, at most ``n_jobs``."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        cores = os.cpu_count() or 1
    return max(1, min(cores, n_jobs))


def usable_workers(limit: int = 2) -> int:
    """Worker processes for the check: the usable cores (at most ``limit``), none inside a worker process or
    without the ``fork`` start method."""
    if mp.parent_process() is not None or "fork" not in mp.get_all_start_methods():
        return 1
    return default_workers(limit)


class _Forked:
    """What a :class:`ForkPool` worker runs its jobs on: set by the pool's initializer inside the forked worker only
    (the parent never writes it), so a job is pickled as a name and its arguments, never with the state."""

    state: Any = None


def _adopt(state: Any) -> None:
    """Initializer of a :class:`ForkPool` worker, run in the worker right after it forks: keep the pool's state."""
    _Forked.state = state


def _run(job: Callable[..., Any], *args: Any) -> Any:
    """A :class:`ForkPool` job in its worker: ``job(state, *args)``."""
    return job(_Forked.state, *args)


class ForkPool:
    """Worker processes forked from this one, each running its jobs on ``state`` as it was when they forked (shared
    by the fork, not pickled: a fitter, a check holding lambdas and recordings).

    The workers fork at the first :meth:`submit` (every one of them: the ``fork`` start method launches the whole
    pool at once), so ``state`` is what it is then. :meth:`terminate` stops them now without reaching into the
    executor: the pool records the processes that appeared during its first submit.

    Args:
        n_workers: processes to fork.
        state: what every job receives as its first argument.
    """

    def __init__(self, n_workers: int, state: Any) -> None:
        self._executor = ProcessPoolExecutor(n_workers, mp_context=mp.get_context("fork"), initializer=_adopt,
                                             initargs=(state,))
        self._workers: list[mp.process.BaseProcess] | None = None

    def submit(self, job: Callable[..., Any], *args: Any) -> Future[Any]:
        """``job(state, *args)`` in a worker, a future (``job`` a module-level function: it is pickled by name)."""
        if self._workers is not None:
            return self._executor.submit(_run, job, *args)
        before = set(mp.active_children())
        try:
            return self._executor.submit(_run, job, *args)
        finally:
            self._workers = [p for p in mp.active_children() if p not in before]

    def shutdown(self, cancel: bool = True) -> None:
        """Drop the jobs not started (unless ``cancel`` is False) and wait for the workers to exit."""
        self._executor.shutdown(wait=True, cancel_futures=cancel)

    def terminate(self) -> None:
        """Stop the workers now, their jobs dropped; then the executor's own shutdown finds them dead, cancels what
        is queued and reaps them (joining them here raced its manager thread)."""
        for proc in self._workers or ():
            proc.terminate()
        self.shutdown()
