"""Every identification method of the paper behind one entry point.

Constant-parameter methods: ``nominal``, ``base`` (3 base-position parameters), ``cpa`` (circular point
analysis, needs single-joint sweeps), ``nls0`` (NLS on the clusters nearest q = 0), ``nls1`` (one NLS over
all training data). Configuration-dependent (CDC) methods interpolate local cluster fits over (q2, q3) with one
of the interpolators ``nearest``, ``linear``, ``cubic``, ``rbf``, ``fbf13``, ``fbf7``, ``nn``, ``ae``, in two
constructions (:data:`CDC_REFERENCES`):

- the paper's, under the interpolator's bare name (``fbf13``): local minimal POE fits of the geometry alone,
  pulled toward the purely geometric global fit (``nls1``'s geometry; no tool rotation, compliance or
  deflection);
- built on ``pi``, prefixed ``pi+`` (``pi+fbf13``): the local fits vary the geometric block of the
  physics-informed model, its other terms held at the global ``pi`` fit.

Beyond the paper, ``pi`` is the physics-informed model (geometry + tool rotation + gravity compliance + smooth
structural deflection, see :mod:`calibration.physics.extended`), and ``diagnosed`` is what
:func:`calibration.diagnosis.diagnose` finds on the training data alone (effects chosen on set-aside training
clusters), refitted on all of it.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import cast

import numpy as np

from calibration import workers
from calibration.arm import Arm
from calibration.data.recording import Recording
from calibration.errors import DataError, ModelError
from calibration.kinematics.poe import pose_error
from calibration.method_names import CDC_METHODS, METHODS, REFERENCE_FITS, cdc_method
from calibration.methods import cdc_fit, constant, diagnosed, pi  # noqa: F401  (each registers its methods)
from calibration.methods import heldout as robust
from calibration.methods.folds import HeldOutRefits
from calibration.methods.options import FitOptions
from calibration.methods.recommend import off_reference
from calibration.methods.registry import fit_function
from calibration.methods.shared import SharedCache
from calibration.models import KinematicModel
from calibration.models.guard import REGION_KEY, Region

log = logging.getLogger("cellcal.calibration")


@dataclass
class Fitter(HeldOutRefits):
    """Fits methods on one training recording, sharing the global and local fits between methods
    (:class:`calibration.methods.shared.SharedFits`, its fields) and refitting them on held-out folds
    (:class:`calibration.methods.folds.HeldOutRefits`). A method is a function registered under its name
    (:mod:`calibration.methods.registry`) by its family's module."""

    @classmethod
    def for_arm(cls, arm: Arm, train: Recording, cpa: Recording | None = None,
                options: FitOptions | None = None) -> Fitter:
        """A Fitter for one arm: its nominal model, link masses (the mass-free joint compliance, with a warning, when
        it has none) and joint limits, on the training recording less its gross measurement errors
        (:meth:`without_gross_rows`, unless ``options.reject_gross_rows`` is off; ``fitter.gross`` names them).

        Args:
            arm: the arm (:meth:`cell_config.loader.CellRobot.arm`).
            train: the training recording.
            cpa: the CPA sweeps recording, or None.
            options: the fit options (default options when None).
        """
        try:
            gravity = arm.gravity()
        except ModelError as e:
            log.warning("%s: joint compliance takes the mass-free form: %s", arm.name, e)
            gravity = None
        fitter = cls(arm.name, arm.nominal, train, options or FitOptions(), cpa, gravity, arm.joint_limits_rad)
        return fitter.without_gross_rows() if fitter.options.reject_gross_rows else fitter

    def without_gross_rows(self) -> Fitter:
        """This fitter on its training recording less its gross measurement errors (:func:`robust.gross_rows`,
        scored under the geometric fit ``nls1``, refitted without them); ``gross`` says which were set aside. With
        none set aside it is this fitter, still fresh: the scoring fits are made apart (the frames-first fit changes a
        fresh fitter's options, :func:`calibration.frames.check.base_free`), one geometric fit more."""
        train = self.train

        def errors(keep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            fitter = replace(self, train=train if keep.all() else train.subset(keep), _cache=SharedCache())
            R, p = fitter.par.model(fitter.global_fit()).fk(train.q)
            return pose_error(train.R, train.p, R, p)

        gross = robust.gross_rows(errors, len(train), train.source)
        if gross.rows or gross.too_many:
            log.info("%s", gross.message())  # the app warns (app.cli.common.fitter_from_args); models carry it
        if gross.rows:
            keep = np.ones(len(train), dtype=bool)
            keep[list(gross.rows)] = False
            fitter = replace(self, train=_with_clusters(train, self.options.cluster_size).subset(keep), _cache=SharedCache())
        else:
            fitter = self
        fitter.gross = gross
        return fitter

    def fit(self, method: str) -> tuple[KinematicModel, float]:
        """Fit one method. Returns the model and its fit time [s], shared global/local fits included."""
        if method not in METHODS:
            raise ModelError(f"unknown method {method!r}; valid: {', '.join(METHODS)}")
        shared = self._prepare_shared(method)
        start = time.perf_counter()
        model = fit_function(method)(self, method)
        # A prefetched fit ran in worker processes: its time is what its jobs took there, as if run here.
        seconds = self._cache.worker_seconds.pop(method, time.perf_counter() - start) + shared
        self._cache.fitted.add(method)
        model.info.setdefault("fit_seconds", seconds)
        model.info.setdefault("train_samples", len(self.train))
        if self.gross is not None and (self.gross.rows or self.gross.too_many):
            model.info.setdefault("gross_rows", self.gross.to_json())
        region = Region.of(self.train.q, context=self.train.context())  # the extrapolation guard's region
        model.info.setdefault(REGION_KEY, region.to_dict())
        return model, seconds

    def _prepare_shared(self, method: str) -> float:
        """Run (once) the shared fits ``method`` builds on; returns their wall time [s], charged to each user."""
        needs: tuple[str, ...] = {"nls1": ("global",), "pi": ("pi",)}.get(method, ())
        if method in CDC_METHODS:
            reference = cdc_method(method)[0]
            needs = ("pi", "local pi") if reference == "pi" else ("global", "local geometric")
        steps: dict[str, Callable[[], object]] = {
            "global": self.global_fit, "pi": self.physics_informed,
            "local pi": lambda: self.local_fits("pi"), "local geometric": lambda: self.local_fits("geometric")}
        seconds = self._cache.seconds
        for step in needs:
            if step not in seconds:
                start = time.perf_counter()
                steps[step]()
                seconds[step] = time.perf_counter() - start
        return sum(seconds[step] for step in needs)

    def nls0_damping(self) -> float:
        """The Tikhonov cutoff of ``nls0`` (:func:`calibration.methods.constant.nls0_damping`)."""
        return constant.nls0_damping(self)

    def prefetch(self, methods: list[str] | tuple[str, ...], held_out: bool = False) -> None:
        """Start the network trainings of the neural CDC fits among ``methods`` (each final network, and the fold
        refits of its check) in forked worker processes, so that the methods fitted here in the meantime overlap
        them; :meth:`fit` collects them (the same bits as fitted here: every training is deterministic on one BLAS
        thread). With ``held_out`` the fold refits of :meth:`held_out_errors` too, for the methods whose held-out
        errors a recommendation reads (those on the reference :func:`calibration.methods.recommend.off_reference` keeps).

        ``diagnosed`` among ``methods`` runs in a worker process of its own, forked first: it shares no fit with
        the others, so it overlaps the shared fits made here before the network workers fork.

        A no-op without the ``fork`` start method or with one usable core. The shared fits run here first.
        """
        if "diagnosed" in methods:
            diagnosed.start_diagnosis(self)
        prefetched = self._cache.prefetched
        neural = [m for m in ("ae", "pi+ae", "nn", "pi+nn") if m in methods and m not in prefetched
                  and m not in self._cache.fitted]
        if not neural or workers.default_workers(robust.N_FOLDS) < 2 or "fork" not in mp.get_all_start_methods():
            return
        for m in neural:  # the shared fits of each reference, once, before the workers fork
            self._prepare_shared(m)
        jobs = {m: cdc_fit.cdc_options(self, m) for m in neural}
        folds = [(m, f) for m in neural for f in range(robust.NEURAL_EVALUATED_FOLDS)]
        if held_out:

            unread = off_reference({m: (ref, cast(np.ndarray, self.held_out_errors(ref)))  # a reference: never None
                                    for m in methods if m in CDC_METHODS
                                    for ref in [REFERENCE_FITS[cdc_method(m)[0]]]})
            folds += [(m, f) for m in neural if m not in unread
                      for f in range(robust.NEURAL_EVALUATED_FOLDS, robust.N_FOLDS)]
        self._prepare_folds(folds)  # the fold refits' shared fits too, before the fork
        for m, options in jobs.items():  # the longest (ae's final training) first
            prefetched[m] = self._submit(cdc_fit.prefetch_final, m, options)
        self._submit_folds(folds)


def _with_clusters(rec: Recording, size: int) -> Recording:
    """``rec`` with its cluster ids as a column, so a subset keeps them (consecutive groups of ``size`` rows are no
    longer clusters once a row is gone); as it is when it has neither a column nor whole clusters."""
    if "cluster" in rec.extra:
        return rec
    try:
        cluster = rec.clusters(size)
    except DataError:
        return rec
    return Recording(rec.q, rec.p, rec.quat, {**rec.extra, "cluster": cluster.astype(float)}, rec.source)


