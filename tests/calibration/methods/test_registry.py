"""The methods' dispatch table: every method name a model file may carry is fitted by exactly one registered family
function, a name cannot be claimed twice, and the Fitter fits by looking the name up (no per-method code in it)."""

import pytest

from calibration.method_names import METHODS
from calibration.methods import registry
from calibration.methods.fitter import Fitter
from calibration.models import ConstantModel
from tests.conftest import cluster_design, measure


def test_every_method_name_is_registered_and_nothing_else():
    assert sorted(registry.registered()) == sorted(METHODS)


def test_a_name_registered_twice_is_refused_naming_both_functions():
    with pytest.raises(ValueError, match=r"'nls1' is registered twice: calibration.methods.constant.fit_nls1 and"):
        registry.register("nls1")(lambda fitter, method: None)
    assert registry.fit_function("nls1").__module__ == "calibration.methods.constant"


def test_the_fitter_fits_what_the_registry_holds_for_the_name(monkeypatch, r1_nominal, synthetic_arm):
    """Fitter.fit calls the registered function with itself and the name (so a new method is one module and one
    @register), and still adds what every model carries (fit time, training size, region)."""
    q, cluster = cluster_design(step_deg=30.0)
    train = measure(synthetic_arm[2].fk, q, 0.02, 0.01, 1, cluster)
    seen = []

    def fit(fitter, method):
        seen.append((fitter, method))
        return ConstantModel("R1", method, r1_nominal, 0, {"by": "the registry"})

    monkeypatch.setitem(registry._TABLE, "base", fit)
    fitter = Fitter("R1", r1_nominal, train)
    model, seconds = fitter.fit("base")
    assert seen == [(fitter, "base")] and model.info["by"] == "the registry"
    assert {"fit_seconds", "train_samples"} <= set(model.info) and model.info["train_samples"] == len(train)


def _pid_and_state(state, tag):
    import os

    return os.getpid(), (state["n"], state["fit"](1)), tag


def _sleep(state, seconds):
    import time

    time.sleep(seconds)


def test_a_fork_pool_runs_its_jobs_on_its_state_and_terminate_stops_them_now():
    """ForkPool hands the state it was made with to every job (shared by the fork, not pickled: a lambda inside is
    fine) and terminate ends a running job at once, with no worker left behind."""
    import multiprocessing
    import os
    import time

    from calibration.workers import ForkPool

    if "fork" not in multiprocessing.get_all_start_methods():
        pytest.skip("no fork start method")
    state = {"fit": lambda x: x + 1, "n": 7}  # a lambda cannot be pickled: the state must come by the fork
    pool = ForkPool(2, state)
    try:
        pid, got, tag = pool.submit(_pid_and_state, "a").result()
    except Exception:
        pool.terminate()
        raise
    assert pid != os.getpid() and tag == "a" and got == (7, 2)
    running = pool.submit(_sleep, 60.0)
    time.sleep(0.2)
    start = time.perf_counter()
    pool.terminate()
    assert time.perf_counter() - start < 5.0 and running.done()
    assert multiprocessing.active_children() == []


def test_the_shared_fits_are_made_once_into_the_typed_cache_and_a_fold_starts_fresh(r1_nominal, synthetic_arm):
    q, cluster = cluster_design(step_deg=30.0)
    fitter = Fitter("R1", r1_nominal, measure(synthetic_arm[2].fk, q, 0.02, 0.01, 1, cluster))
    assert fitter._cache.is_empty()
    fitter.fit("nls1")
    x = fitter._cache.x_global
    assert x is not None and fitter._cache.fitted == {"nls1"} and set(fitter._cache.seconds) == {"global"}
    fitter.fit("nls1")
    assert fitter._cache.x_global is x and not fitter._cache.is_empty()
    for _, sub in fitter._fold_fitters():
        assert sub._cache.is_empty() and sub._cache is not fitter._cache and sub.warm is fitter
