"""The method ``diagnosed``: what :func:`calibration.diagnosis.diagnose` finds on the training data alone (effects
chosen on set-aside training clusters), refitted on all of it; run ahead in a forked worker of its own when a
prefetch asks for it (:func:`start_diagnosis`)."""

from __future__ import annotations

import multiprocessing as mp
import time
from dataclasses import replace

from calibration import workers
from calibration.diagnosis import DiagnoseOptions, diagnose
from calibration.methods import heldout as robust
from calibration.methods.folds import HeldOutRefits
from calibration.methods.registry import register
from calibration.models import KinematicModel


@register("diagnosed")
def fit_diagnosed(fitter: HeldOutRefits, method: str) -> KinematicModel:
    job, fitter._cache.diagnosis_job = fitter._cache.diagnosis_job, None
    if job is not None:  # started by prefetch in its own worker process: the same bits as here
        pool, future = job
        try:
            model: KinematicModel
            model, seconds = future.result()  # the worker's own error, or BrokenProcessPool if it died
        except BaseException:  # an interrupt here must not wait for the rest of the diagnosis
            pool.terminate()
            raise
        pool.shutdown(cancel=False)
        fitter._cache.worker_seconds["diagnosed"] = seconds
        return model
    return run_diagnosis(fitter)


def run_diagnosis(fitter: HeldOutRefits) -> KinematicModel:
    """``diagnosed``'s model, fitted here."""
    opts = DiagnoseOptions(a=fitter.options.a, tolerance=fitter.options.tolerance,
                           cluster_size=fitter.options.cluster_size)
    found = diagnose(fitter.robot, fitter.nominal, fitter.train, gravity=fitter.gravity,
                     joint_limits=fitter.joint_limits, options=opts)
    return replace(found.model, method="diagnosed", info={**found.model.info, "verdict": found.verdict})


def start_diagnosis(fitter: HeldOutRefits) -> None:
    """Start ``diagnosed``'s fit in a forked worker process of its own (collected by :func:`fit_diagnosed`); a
    no-op when it is fitted or started, without ``fork`` or with one usable core."""
    if (fitter._cache.diagnosis_job is not None or "diagnosed" in fitter._cache.fitted
            or workers.default_workers(robust.N_FOLDS) < 2 or "fork" not in mp.get_all_start_methods()):
        return
    pool = workers.ForkPool(1, fitter)  # the worker forks during the submit, with this Fitter as it is then
    fitter._cache.diagnosis_job = pool, pool.submit(_diagnosis_job)


def _diagnosis_job(fitter: HeldOutRefits) -> tuple[KinematicModel, float]:
    """Worker job of :func:`start_diagnosis`: ``diagnosed``'s model and its fit time [s]."""
    start = time.perf_counter()
    model = run_diagnosis(fitter)
    return model, time.perf_counter() - start

