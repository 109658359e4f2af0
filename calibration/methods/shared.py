"""The fits every method of one training recording shares, each made once: the parameterisation, the observability
analyses, the global geometric fit, the physics-informed fit, the CDC references and their local cluster fits (with the
local prior chosen on held-out clusters). :class:`SharedFits` holds the training recording and these fits;
:class:`calibration.methods.fitter.Fitter` is the facade that fits methods on them."""

from __future__ import annotations

import logging
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from calibration.data.recording import Recording, standalone_mask
from calibration.errors import DataError, ModelError
from calibration.identification import GeometricProblem
from calibration.identification.observability import Observability, analyse, base_free_prior, filter_weights
from calibration.interpolation import make_interpolator
from calibration.interpolation.support import AnchorSupport
from calibration.kinematics.arrays import FloatArray
from calibration.kinematics.parameterisation import MinimalParameterisation
from calibration.kinematics.poe import PoeModel
from calibration.method_names import CDC_REFERENCES
from calibration.methods import heldout as robust
from calibration.methods import workspace
from calibration.methods.cdc import LocalFits, build_cdc, cluster_anchors, fit_local
from calibration.methods.options import FitOptions
from calibration.models.cdc import CDC_INPUTS
from calibration.models.pi import PhysicsInformedModel
from calibration.physics.extended import ExtendedKinematics
from calibration.physics.gravity import GravityModel
from calibration.workers import ForkPool

log = logging.getLogger("cellcal.calibration")

#: Clusters a CDC method needs: its interpolator over (q2, q3) needs 3 anchors, and its strengths are chosen on
#: clusters held out in turn (5 folds), so 4 leave 3 on every fold.
MIN_CDC_CLUSTERS = 4


@dataclass
class SharedCache:
    """What a fitter made once and keeps: the shared fits, the choices made on held-out clusters, the fold refits
    and the worker jobs under way (each None or empty until made).

    Attributes:
        clustered: the training poses in clusters (:attr:`SharedFits.clustered`).
        par, observability, pi_observability: the parameterisation and the observability analyses of the geometric
            and physics-informed parameters.
        x_global: the global geometric fit (nls1's parameters); pi: the global physics-informed fit.
        geometric_reference: kinematics and parameters of the paper's CDC reference (the geometric fit).
        local: local cluster fits per CDC reference, at its local prior; local_by_prior: per (reference, prior).
        local_prior_cv: how each reference's local prior was chosen (grid, held-out figures, chosen).
        local_prior_scores: each reference's (grid, held-out scores, workspace ratios) behind that choice.
        workspace_probes: joint configurations over the limits for the workspace check [rad], shape (P, n).
        seconds: wall time of each shared fit step [s] ("global", "pi", "local pi", "local geometric").
        fitted: methods fitted; worker_seconds: fit time [s] of methods fitted in worker processes, until collected.
        nls0_damping: nls0's chosen Tikhonov cutoff; strengths: each CDC method's chosen interpolator strength.
        diagnosis_job: ``diagnosed``'s worker pool and its future, until collected.
        pool: the worker pool of the network and fold jobs; prefetched: futures of final networks per method;
        fold_jobs: futures of fold refits per (method, fold).
        folds: (held-out mask, fitter on the other clusters) per fold.
        held_out_errors: per method, every training pose's held-out position error [mm];
        fold_errors, fold_seconds: per (method, fold), the refit's errors on the fold [mm] and its time [s].
    """

    clustered: Recording | None = None
    par: MinimalParameterisation | None = None
    observability: Observability | None = None
    pi_observability: Observability | None = None
    x_global: np.ndarray | None = None
    pi: PhysicsInformedModel | None = None
    geometric_reference: tuple[ExtendedKinematics, np.ndarray] | None = None
    local: dict[str, LocalFits] = field(default_factory=dict)
    local_by_prior: dict[tuple[str, float], LocalFits] = field(default_factory=dict)
    local_prior_cv: dict[str, dict[str, Any]] = field(default_factory=dict)
    local_prior_scores: dict[str, tuple[Any, ...]] = field(default_factory=dict)
    workspace_probes: np.ndarray | None = None
    seconds: dict[str, float] = field(default_factory=dict)
    fitted: set[str] = field(default_factory=set)
    worker_seconds: dict[str, float] = field(default_factory=dict)
    nls0_damping: float | None = None
    strengths: dict[str, dict[str, Any]] = field(default_factory=dict)
    diagnosis_job: tuple[ForkPool, Future[Any]] | None = None
    pool: ForkPool | None = None
    prefetched: dict[str, Future[Any]] = field(default_factory=dict)
    fold_jobs: dict[tuple[str, int], Future[Any]] = field(default_factory=dict)
    folds: list[tuple[np.ndarray, Any]] | None = None
    held_out_errors: dict[str, np.ndarray] = field(default_factory=dict)
    fold_errors: dict[tuple[str, int], np.ndarray] = field(default_factory=dict)
    fold_seconds: dict[tuple[str, int], float] = field(default_factory=dict)

    def is_empty(self) -> bool:
        """Nothing made yet (a fresh fitter, whose options may still change)."""
        return all(not v if isinstance(v, (dict, set)) else v is None for v in vars(self).values())


@dataclass
class SharedFits:
    """One training recording and the fits the methods share, each made once (see the module).

    ``gravity`` (link masses) and ``joint_limits`` serve ``diagnosed``: without masses its joint compliance
    takes the mass-free form; without limits the training poses stand in for the workspace.

    ``warm``: fits on a superset of this one's training data (the whole recording, when this one fits the
    clusters outside a held-out fold): its global fits start this one's solver and its observability analyses
    (hidden directions, Tikhonov damping) are reused, so a fold refit takes a few iterations.
    """

    robot: str
    nominal: PoeModel
    train: Recording
    options: FitOptions = field(default_factory=FitOptions)
    cpa_data: Recording | None = None
    gravity: GravityModel | None = None
    joint_limits: tuple[np.ndarray, np.ndarray] | None = None
    warm: Any = field(default=None, repr=False)
    _cache: SharedCache = field(default_factory=SharedCache, repr=False)
    gross: robust.GrossRows | None = field(default=None, repr=False)

    @property
    def clustered(self) -> Recording:
        """The training poses in clusters (stand-alone poses left out,
        :func:`calibration.data.recording.standalone_mask`):
        what the local (per-cluster) fits of the CDC methods, their held-out checks and nls0 read; the global fits
        (nls1, pi, geometric, diagnosed) and the held-out folds use every pose, a stand-alone pose as its own unit."""
        if self._cache.clustered is None:
            alone = standalone_mask(self.train)
            self._cache.clustered = self.train.subset(~alone) if alone.any() else self.train
        return self._cache.clustered

    @property
    def par(self) -> MinimalParameterisation:
        if self._cache.par is None:
            self._cache.par = MinimalParameterisation(self.nominal, self.options.fit_tool)
        return self._cache.par

    def observability(self) -> Observability:
        if self._cache.observability is None:
            self._cache.observability = self.warm.observability() if self.warm is not None else \
                analyse(self.par, self.train.q, a=self.options.a, tolerance=self.options.tolerance)
        return self._cache.observability

    def _pi_observability(self) -> Observability:
        if self._cache.pi_observability is None:
            self._cache.pi_observability = self.warm._pi_observability() if self.warm is not None else \
                analyse(ExtendedKinematics(self.par), self.train.q, a=self.options.a, tolerance=self.options.tolerance)
        return self._cache.pi_observability

    def _global(self, rec: Recording, obs: Observability, x0: np.ndarray | None = None) -> np.ndarray:
        problem = GeometricProblem(self.par, rec.q, rec.R, rec.p, a=self.options.a, basis=obs.basis)
        # x = basis z with basis = scale * V_r: a start x0 in that span is z0 = V_r^T (x0 / scale)
        res = problem.solve(None if x0 is None else (obs.V[:, : obs.rank].T @ (x0 / obs.scale))[None])
        if not res.converged.all():
            log.warning("global NLS stopped after %d iterations without converging (%s)", res.iterations,
                        res.reason[0].value)
        x: FloatArray = res.x[0]
        return x

    def global_fit(self) -> np.ndarray:
        if self._cache.x_global is None:
            x0 = None if self.warm is None else self.warm.global_fit()
            self._cache.x_global = self._global(self.train, self.observability(), x0)
        return self._cache.x_global

    def physics_informed(self) -> PhysicsInformedModel:
        """The global physics-informed fit (cached): method ``pi`` and the reference of the CDC local fits."""
        if self._cache.pi is None:
            kin = ExtendedKinematics(self.par)
            obs = self._pi_observability()
            z0 = None if self.warm is None else self.warm.physics_informed().theta[None]
            prior = filter_weights(obs)
            prior[kin.registration_mask(self.options.pi_registration_free)] = 0.0
            if self.options.pi_base_free:
                prior = base_free_prior(prior, kin.base_motion())
            res = GeometricProblem(kin, self.train.q, self.train.R, self.train.p, a=self.options.a,
                                   prior_weight=prior).solve(z0)
            if not res.converged.all():
                log.warning("physics-informed fit stopped after %d iterations without converging (%s)",
                            res.iterations, res.reason[0].value)
            self._cache.pi = PhysicsInformedModel(self.robot, "pi", kin, res.x[0], obs.rank,
                                                  {"hidden_directions": len(obs.singular_values) - obs.rank})
        return self._cache.pi

    def reference(self, reference: str = "pi") -> tuple[ExtendedKinematics, np.ndarray]:
        """Kinematics and global parameters the local fits of a CDC construction vary around (cached).

        ``pi``: the physics-informed fit. ``geometric`` (the paper's): the same layout with only the geometric
        block, at the global geometric fit (``nls1``'s), every other term zero.
        """
        if reference == "pi":
            pi = self.physics_informed()
            return pi.kinematics, pi.theta
        if reference != "geometric":
            raise ModelError(f"unknown CDC reference {reference!r}; valid: {', '.join(CDC_REFERENCES)}")
        if self._cache.geometric_reference is None:
            kin = ExtendedKinematics(self.par)
            theta = np.zeros(kin.size)
            theta[: self.par.size] = self.global_fit()
            self._cache.geometric_reference = (kin, theta)
        return self._cache.geometric_reference

    def _reference_fk(self, reference: str) -> Any:
        kin, theta = self.reference(reference)
        return lambda q: kin.pose(q, theta)

    def local_fits(self, reference: str = "pi") -> LocalFits:
        """The local cluster fits around ``reference`` at the local prior of FitOptions (or chosen, see there)."""
        cache = self._cache.local
        if reference not in cache:
            if self.warm is None:  # a fold refit's Fitter has fewer: its parent's count was checked
                self._require_clusters(MIN_CDC_CLUSTERS, "a CDC method (its interpolator over (q2, q3) needs 3 "
                                       "anchors on every fold of clusters held out in turn)")
                self._require_spread_anchors()
            prior = self.options.local_prior
            if prior is None and self.warm is not None:
                prior = self.warm.local_prior(reference)
            if prior is None:
                prior = self._choose_local_prior(reference)
            cache[reference] = self._local_at(prior, reference)
        return cache[reference]

    def local_prior(self, reference: str = "pi") -> float:
        """The local prior the local fits around ``reference`` use (FitOptions.local_prior or the chosen one)."""
        if self.options.local_prior is not None:
            return self.options.local_prior
        self.local_fits(reference)
        weight: float = self._cache.local_prior_cv[reference]["chosen"]
        return weight

    def _local_at(self, prior: float, reference: str) -> LocalFits:
        fits = self._cache.local_by_prior
        if (reference, prior) not in fits:
            kin, theta = self.reference(reference)
            fits[reference, prior] = fit_local(kin, self.train, theta, self.options.a, prior,
                                               self.options.cluster_size)
        return fits[reference, prior]

    def _choose_local_prior(self, reference: str) -> float:
        """The local prior of ``local_prior_grid`` chosen on held-out training clusters (see FitOptions)."""

        grid = tuple(self.options.local_prior_grid)
        kin, theta = self.reference(reference)
        groups, _ = cluster_anchors(self.clustered, self.options.cluster_size)
        scores, ratios = [], []
        for prior in grid:
            local = self._local_at(prior, reference)
            scores.append(robust.held_out(lambda: make_interpolator("linear"), kin, theta, local.anchors, local.x,
                                          groups, self.clustered, CDC_INPUTS, seed=self.options.seed))
            model = build_cdc(self.robot, "linear", kin, local)
            ratios.append(workspace.workspace_ratio(model.fk, self._reference_fk(reference), self.train.q,
                                                 self._workspace_probes())[0])
        ok = [i for i, r in enumerate(ratios) if r <= workspace.WORKSPACE_RATIO_LIMIT]
        if ok:
            rule = robust.CHOICE_RULES[self.options.local_prior_rule]
            chosen = grid[ok[rule(tuple(grid[i] for i in ok), [scores[i] for i in ok])]]
        else:
            chosen = max(grid)
        self._cache.local_prior_scores[reference] = (grid, scores, ratios)
        self._cache.local_prior_cv[reference] = {
            "chosen": chosen, "grid": list(grid), "heldout_rms_mm": [round(s.rms_mm, 4) for s in scores],
            "se_mm": [round(s.se_rms_mm, 4) for s in scores], "workspace_ratio": [round(r, 2) for r in ratios],
            "within_workspace_limit": bool(ok), "rule": self.options.local_prior_rule}
        log.info("local prior %g (%s reference) chosen on held-out clusters: %s", chosen, reference,
                 self._cache.local_prior_cv[reference])
        return chosen

    def _require_clusters(self, n: int, what: str) -> None:
        """Refuse a training recording of fewer than ``n`` clusters for ``what`` (one cluster made a fold refit on no
        poses at all: a traceback in compare, 'x: empty array of shape (0, 2)' from fit --method fbf13).

        Raises:
            DataError: naming the recording, the count and the need.
        """
        _, anchors = cluster_anchors(self.clustered, self.options.cluster_size)  # stand-alone poses are no cluster
        if len(anchors) < n:
            raise DataError(self.train.source, None, None,
                            f"{len(anchors)} cluster{'s' if len(anchors) != 1 else ''} of training poses; {what} "
                            f"need{'s' if what.startswith('a ') else ''} at least {n}")

    def _require_spread_anchors(self) -> None:
        """Refuse training clusters whose anchors span no area in a CDC method's inputs (q2, q3), on every cluster
        or on those a fold of clusters held out in turn leaves: its interpolator cannot triangulate them, and fit
        --method fbf13 said only 'anchors: the 3 anchors span no 2-dimensional volume', a fold's count, not the
        recording's, and no file.

        Raises:
            DataError: naming the recording, its cluster count and the fold.
        """

        _, anchor_q = cluster_anchors(self.clustered, self.options.cluster_size)
        x = anchor_q[:, list(CDC_INPUTS)]
        folds = robust.cluster_folds(len(x), robust.N_FOLDS, self.options.seed)
        names = "(" + ", ".join(f"q{i + 1}" for i in CDC_INPUTS) + ")"
        for fold in (None, *range(robust.N_FOLDS)):
            kept = x if fold is None else x[folds != fold]
            try:
                AnchorSupport(kept)
            except ModelError:
                which = ("" if fold is None else
                         f", without the {len(x) - len(kept)} held out in fold {fold + 1} of {robust.N_FOLDS},")
                raise DataError(self.train.source, None, None,
                                f"{len(x)} clusters of training poses whose anchors{which} span no area in {names} "
                                f"(all on a line?); a CDC method interpolates over {names} and needs anchors spread "
                                "over an area") from None

    def _workspace_probes(self) -> np.ndarray:
        if self._cache.workspace_probes is None:
            _, anchor_q = cluster_anchors(self.clustered, self.options.cluster_size)
            self._cache.workspace_probes = workspace.workspace_probes(
                anchor_q[:, list(CDC_INPUTS)], self.joint_limits, self.par.n_joints, CDC_INPUTS,
                seed=self.options.seed)
        return self._cache.workspace_probes

