"""How many worker processes an expensive check may fork: the usable cores, capped by the caller's number of jobs
(:func:`default_workers`), and none inside a worker or where ``fork`` is not available (:func:`usable_workers`).
Imports nothing of the package, so every layer can ask."""

from __future__ import annotations

import multiprocessing as mp
import os


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
