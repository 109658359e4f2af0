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
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from calibration import workers
from calibration.data.recording import Recording, standalone_mask
from calibration.diagnosis import DiagnoseOptions, diagnose
from calibration.errors import DataError, ModelError
from calibration.evaluation.metrics import errors
from calibration.identification import GeometricProblem
from calibration.identification.cpa import identify_cpa, split_sweeps
from calibration.identification.observability import Observability, analyse, filter_weights
from calibration.interpolation import make_interpolator
from calibration.interpolation.support import AnchorSupport
from calibration.kinematics.parameterisation import MinimalParameterisation
from calibration.kinematics.poe import PoeModel, pose_error
from calibration.method_names import CDC_METHODS, CDC_REFERENCES, METHODS, NEURAL_METHODS, REFERENCE_FITS, cdc_method
from calibration.methods import heldout as robust
from calibration.methods import workspace
from calibration.methods.cdc import LocalFits, build_cdc, cluster_anchors, fit_local
from calibration.methods.options import FitOptions
from calibration.methods.pi import base_free_prior
from calibration.methods.recommend import off_reference
from calibration.models import ConstantModel, KinematicModel
from calibration.models.cdc import CDC_INPUTS, CdcModel
from calibration.models.guard import REGION_KEY, Region
from calibration.models.pi import PhysicsInformedModel
from calibration.physics.extended import ExtendedKinematics
from calibration.physics.gravity import GravityModel

log = logging.getLogger("cellcal.calibration")

#: nls0 is flagged when its worst error on the training clusters it does not use exceeds nls1's (held out from
#: them) by this factor: the issue-10 bound on a method's test max against nls1's, applied to training clusters.
NLS0_HELDOUT_MAX_RATIO = 1.5
#: Clusters a CDC method needs: its interpolator over (q2, q3) needs 3 anchors, and its strengths are chosen on
#: clusters held out in turn (5 folds), so 4 leave 3 on every fold.
MIN_CDC_CLUSTERS = 4


@dataclass
class Fitter:
    """Fits methods on one training recording, sharing the global and local fits between methods.

    ``gravity`` (link masses) and ``joint_limits`` serve ``diagnosed``: without masses its joint compliance
    takes the mass-free form; without limits the training poses stand in for the workspace.

    ``warm``: a Fitter on a superset of this one's training data (the whole recording, when this one fits the
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
    warm: Fitter | None = field(default=None, repr=False)
    _cache: dict[str, Any] = field(default_factory=dict, repr=False)
    gross: robust.GrossRows | None = field(default=None, repr=False)

    def without_gross_rows(self) -> Fitter:
        """This fitter on its training recording less its gross measurement errors (:func:`robust.gross_rows`,
        scored under the geometric fit ``nls1``, refitted without them); ``gross`` says which were set aside. With
        none set aside it is this fitter, still fresh: the scoring fits are made apart (the frames-first fit changes a
        fresh fitter's options, :func:`calibration.frames.check.base_free`), one geometric fit more."""
        train = self.train

        def errors(keep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            fitter = replace(self, train=train if keep.all() else train.subset(keep), _cache={})
            R, p = fitter.par.model(fitter.global_fit()).fk(train.q)
            return pose_error(train.R, train.p, R, p)

        gross = robust.gross_rows(errors, len(train), train.source)
        if gross.rows or gross.too_many:
            log.info("%s", gross.message())  # the app warns (app.cli.common.fitter_from_args); models carry it
        if gross.rows:
            keep = np.ones(len(train), dtype=bool)
            keep[list(gross.rows)] = False
            fitter = replace(self, train=_with_clusters(train, self.options.cluster_size).subset(keep), _cache={})
        else:
            fitter = self
        fitter.gross = gross
        return fitter

    @property
    def clustered(self) -> Recording:
        """The training poses in clusters (stand-alone poses left out, :func:`calibration.data.recording.standalone_mask`):
        what the local (per-cluster) fits of the CDC methods, their held-out checks and nls0 read; the global fits
        (nls1, pi, geometric, diagnosed) and the held-out folds use every pose, a stand-alone pose as its own unit."""
        if "clustered" not in self._cache:
            alone = standalone_mask(self.train)
            self._cache["clustered"] = self.train.subset(~alone) if alone.any() else self.train
        return self._cache["clustered"]

    @property
    def par(self) -> MinimalParameterisation:
        if "par" not in self._cache:
            self._cache["par"] = MinimalParameterisation(self.nominal, self.options.fit_tool)
        return self._cache["par"]

    def observability(self) -> Observability:
        if "obs" not in self._cache:
            self._cache["obs"] = self.warm.observability() if self.warm is not None else \
                analyse(self.par, self.train.q, a=self.options.a, tolerance=self.options.tolerance)
        return self._cache["obs"]

    def _pi_observability(self) -> Observability:
        if "pi_obs" not in self._cache:
            self._cache["pi_obs"] = self.warm._pi_observability() if self.warm is not None else \
                analyse(ExtendedKinematics(self.par), self.train.q, a=self.options.a, tolerance=self.options.tolerance)
        return self._cache["pi_obs"]

    def _global(self, rec: Recording, obs: Observability, x0: np.ndarray | None = None) -> np.ndarray:
        problem = GeometricProblem(self.par, rec.q, rec.R, rec.p, a=self.options.a, basis=obs.basis)
        # x = basis z with basis = scale * V_r: a start x0 in that span is z0 = V_r^T (x0 / scale)
        res = problem.solve(None if x0 is None else (obs.V[:, : obs.rank].T @ (x0 / obs.scale))[None])
        if not res.converged.all():
            log.warning("global NLS stopped after %d iterations without converging (%s)", res.iterations,
                        res.reason[0].value)
        return res.x[0]

    def global_fit(self) -> np.ndarray:
        if "x_global" not in self._cache:
            x0 = None if self.warm is None else self.warm.global_fit()
            self._cache["x_global"] = self._global(self.train, self.observability(), x0)
        return self._cache["x_global"]

    def physics_informed(self) -> PhysicsInformedModel:
        """The global physics-informed fit (cached): method ``pi`` and the reference of the CDC local fits."""
        if "pi" not in self._cache:
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
            self._cache["pi"] = PhysicsInformedModel(self.robot, "pi", kin, res.x[0], obs.rank,
                                                     {"hidden_directions": len(obs.singular_values) - obs.rank})
        return self._cache["pi"]

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
        if "geometric_reference" not in self._cache:
            kin = ExtendedKinematics(self.par)
            theta = np.zeros(kin.size)
            theta[: self.par.size] = self.global_fit()
            self._cache["geometric_reference"] = (kin, theta)
        return self._cache["geometric_reference"]

    def _reference_fk(self, reference: str) -> Any:
        kin, theta = self.reference(reference)
        return lambda q: kin.pose(q, theta)

    def local_fits(self, reference: str = "pi") -> LocalFits:
        """The local cluster fits around ``reference`` at the local prior of FitOptions (or chosen, see there)."""
        cache = self._cache.setdefault("local", {})
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
        return self._cache["local_prior_cv"][reference]["chosen"]

    def _local_at(self, prior: float, reference: str) -> LocalFits:
        fits = self._cache.setdefault("local_by_prior", {})
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
            chosen = grid[ok[robust.one_se_choice(tuple(grid[i] for i in ok), [scores[i] for i in ok])]]
        else:
            chosen = max(grid)
        self._cache.setdefault("local_prior_cv", {})[reference] = {
            "chosen": chosen, "grid": list(grid), "heldout_rms_mm": [round(s.rms_mm, 4) for s in scores],
            "se_mm": [round(s.se_rms_mm, 4) for s in scores], "workspace_ratio": [round(r, 2) for r in ratios],
            "within_workspace_limit": bool(ok)}
        log.info("local prior %g (%s reference) chosen on held-out clusters: %s", chosen, reference,
                 self._cache["local_prior_cv"][reference])
        return chosen

    def fit(self, method: str) -> tuple[KinematicModel, float]:
        """Fit one method. Returns the model and its fit time [s], shared global/local fits included."""
        if method not in METHODS:
            raise ModelError(f"unknown method {method!r}; valid: {', '.join(METHODS)}")
        shared = self._prepare_shared(method)
        start = time.perf_counter()
        fit_one = getattr(self, f"_fit_{method}", None)
        model = fit_one() if fit_one is not None else self._fit_cdc(method)
        # A prefetched fit ran in worker processes: its time is what its jobs took there, as if run here.
        seconds = self._cache.get("worker_seconds", {}).pop(method, time.perf_counter() - start) + shared
        self._cache.setdefault("fitted", set()).add(method)
        model.info.setdefault("fit_seconds", seconds)
        model.info.setdefault("train_samples", len(self.train))
        if self.gross is not None and (self.gross.rows or self.gross.too_many):
            model.info.setdefault("gross_rows", self.gross.to_json())
        region = Region.of(self.train.q, context=self.train.context())  # the extrapolation guard's region
        model.info.setdefault(REGION_KEY, region.to_dict())
        return model, seconds

    def _prepare_shared(self, method: str) -> float:
        """Run (once) the shared fits ``method`` builds on; returns their wall time [s], charged to each user."""
        needs = {"nls1": ("global",), "pi": ("pi",)}.get(method, ())
        if method in CDC_METHODS:
            reference = cdc_method(method)[0]
            needs = ("pi", "local pi") if reference == "pi" else ("global", "local geometric")
        steps = {"global": self.global_fit, "pi": self.physics_informed,
                 "local pi": lambda: self.local_fits("pi"), "local geometric": lambda: self.local_fits("geometric")}
        seconds = self._cache.setdefault("seconds", {})
        for step in needs:
            if step not in seconds:
                start = time.perf_counter()
                steps[step]()
                seconds[step] = time.perf_counter() - start
        return sum(seconds[step] for step in needs)

    def _constant(self, method: str, x: np.ndarray, n_params: int, **info: Any) -> ConstantModel:
        return ConstantModel(self.robot, method, self.par.model(x), n_params, dict(info))

    def _fit_nominal(self) -> ConstantModel:
        return ConstantModel(self.robot, "nominal", self.nominal, 0, {})

    def _fit_base(self) -> ConstantModel:
        R, p = self.nominal.fk(self.train.q)
        shift = np.mean(self.train.p - p, axis=0)  # the least-squares optimum: orientation does not change
        P = self.nominal.P.copy()
        P[:, 0] += shift
        return ConstantModel(self.robot, "base", self.nominal.with_geometry(self.nominal.H, P), 3,
                             {"base_shift_mm": shift.tolist()})

    def _fit_cpa(self) -> ConstantModel:
        if self.cpa_data is None:
            raise ModelError("cpa needs single-joint sweep data (a recording with one cluster id per sweep); "
                             "none was given")
        x, circles = identify_cpa(self.par, split_sweeps(self.cpa_data))
        if self.par.fit_tool:
            # Circles give axes and points on them, not where along the last axes the tool sits: the flange
            # shift is fitted on the sweep positions with the axes held.
            g = 4 * self.par.n_joints
            basis = np.zeros((self.par.size, 3))
            basis[g:] = np.eye(3)
            d = self.cpa_data
            x = GeometricProblem(self.par, d.q, d.R, d.p, a=0.0, basis=basis, x_ref=x).solve().x[0]
        return self._constant("cpa", x, self.par.size, circle_rms_mm=[c.rms_mm for c in circles])

    def _fit_nls0(self) -> ConstantModel:
        """The paper's NLS on the ``nls0_clusters`` clusters nearest q = 0, damped toward nominal.

        The paper fits these clusters by plain least squares. Their poses sit in one corner of the workspace, so
        directions they see only weakly are fitted to noise and the model extrapolates far worse than nominal
        (3.8 mm max on a shared test recording where nominal reaches 2.3). The one change: a Tikhonov filter toward nominal at a
        relative cutoff (:func:`~calibration.identification.observability.filter_weights`; directions well above
        it are fitted as before, those below it stay near nominal), its cutoff chosen from ``nls0_damping_grid``
        on the training clusters nls0 does not use (held out by construction; one-standard-error rule toward the
        stronger damping). A fold refit takes the cutoff of the fit on every cluster.

        The model carries ``info["heldout"]``: its RMS on those clusters against nls1's held out from its own
        fit (:meth:`held_out_errors`), and ``info["warning"]`` when its worst error there exceeds nls1's by
        :data:`NLS0_HELDOUT_MAX_RATIO`.

        Raises:
            ModelError: the recording has fewer than 2 clusters beyond the ones nls0 fits (nothing to check on).
        """
        groups, anchors = cluster_anchors(self.train, self.options.cluster_size)
        in_cluster = np.bincount(groups[~standalone_mask(self.train)], minlength=len(anchors)) > 0
        distance = np.where(in_cluster, np.linalg.norm(anchors, axis=1), np.inf)  # stand-alone poses: no cluster
        nearest = np.argsort(distance)[: min(self.options.nls0_clusters, int(in_cluster.sum()))]
        used = np.isin(groups, nearest)
        sub = self.train.subset(used)
        obs = analyse(self.par, sub.q, a=self.options.a, tolerance=self.options.tolerance)
        fits: dict[float, tuple[Observability, np.ndarray]] = {}

        def at(cutoff: float) -> tuple[Observability, np.ndarray]:
            if cutoff not in fits:
                o = replace(obs, tolerance=cutoff, rank=int(np.sum(obs.singular_values >= cutoff *
                                                                   obs.singular_values[0])))
                res = GeometricProblem(self.par, sub.q, sub.R, sub.p, a=self.options.a,
                                       prior_weight=filter_weights(o)).solve()
                if not res.converged.all():
                    log.warning("nls0 fit stopped after %d iterations without converging (%s)", res.iterations,
                                res.reason[0].value)
                fits[cutoff] = o, res.x[0]
            return fits[cutoff]

        info: dict[str, Any] = {"clusters": nearest.tolist()}
        if self.warm is not None:  # a fold refit is not checked: the fit on every cluster was
            cutoff = self.warm.nls0_damping()
        else:
            cutoff, info["damping"], info["heldout"] = self._nls0_held_out(at, used, groups)
            if "warning" in info["heldout"]:
                info["warning"] = info["heldout"].pop("warning")
        o, x = at(cutoff)
        self._cache["nls0_damping"] = cutoff
        return self._constant("nls0", x, o.rank, **info, hidden_directions=o.unobservable())

    def nls0_damping(self) -> float:
        """The Tikhonov cutoff of ``nls0`` (FitOptions.nls0_damping, or the one chosen on held-out clusters)."""
        if self.options.nls0_damping is not None:
            return self.options.nls0_damping
        if "nls0_damping" not in self._cache:
            self.fit("nls0")
        return self._cache["nls0_damping"]

    def _nls0_held_out(self, at: Callable[[float], tuple[Observability, np.ndarray]], used: np.ndarray,
                       groups: np.ndarray) -> tuple[float, dict[str, Any], dict[str, Any]]:
        """nls0's cutoff (FitOptions.nls0_damping, else the one of ``nls0_damping_grid`` best on the training
        clusters it does not use: ``~used``, a mask over the training poses, ``groups`` their cluster index), how
        it was chosen, and the held-out figures of that fit against nls1's on those clusters (with a warning)."""

        rest = ~used
        groups = np.unique(groups[rest], return_inverse=True)[1]
        if groups.size == 0 or groups.max() < 1:
            raise ModelError(f"nls0 needs at least 2 training clusters beyond the {self.options.nls0_clusters} it "
                             f"fits, to choose its damping and check it on them; the recording has "
                             f"{len(np.unique(self.train.clusters(self.options.cluster_size)))}. Use nls1, or a training "
                             "recording with more clusters")
        held = self.train.subset(rest)
        nominal_mm = errors(self._fit_nominal(), held).position_mm
        if self.options.nls0_damping is not None:
            cutoff = self.options.nls0_damping
            damping: dict[str, Any] = {"chosen": cutoff, "grid": None}
        else:
            grid = tuple(self.options.nls0_damping_grid)
            scores = [robust.HeldOut.of_errors(errors(self._constant("nls0", at(c)[1], 0), held).position_mm,
                                               nominal_mm, groups) for c in grid]
            cutoff = grid[robust.one_se_choice(grid, scores)]
            damping = {"chosen": cutoff, "grid": list(grid), "heldout_rms_mm": [round(s.rms_mm, 4) for s in scores],
                       "se_mm": [round(s.se_rms_mm, 4) for s in scores]}
        nls1_mm = self.held_out_errors("nls1")[rest]
        h = robust.HeldOut.of_errors(errors(self._constant("nls0", at(cutoff)[1], 0), held).position_mm,
                                     nls1_mm, groups)
        heldout = {"clusters": int(groups.max()) + 1, "rms_mm": round(h.rms_mm, 4), "max_mm": round(h.max_mm, 4),
                   "nls1_rms_mm": round(h.reference_rms_mm, 4), "nls1_max_mm": round(h.reference_max_mm, 4),
                   "nominal_rms_mm": round(float(np.sqrt(np.mean(nominal_mm ** 2))), 4)}
        log.info("nls0 damping %g (%s) on the %d training clusters it does not use: %s", cutoff, damping,
                 heldout["clusters"], heldout)
        if h.max_mm > NLS0_HELDOUT_MAX_RATIO * h.reference_max_mm:
            heldout["warning"] = (
                f"nls0 extrapolates from the {self.options.nls0_clusters} clusters nearest q = 0: on the other "
                f"{heldout['clusters']} training clusters its position error reaches {h.max_mm:.3f} mm (RMS "
                f"{h.rms_mm:.3f}) against {h.reference_max_mm:.3f} mm (RMS {h.reference_rms_mm:.3f}) for nls1 held "
                f"out from them (x{h.max_mm / max(h.reference_max_mm, 1e-12):.2f} on the max), even damped toward "
                f"nominal at cutoff {cutoff:g}. Prefer nls1 or pi.")
        return cutoff, damping, heldout

    def _fit_nls1(self) -> ConstantModel:
        obs = self.observability()
        return self._constant("nls1", self.global_fit(), obs.rank, hidden_directions=obs.unobservable(),
                              warning=obs.summary())

    def _fit_pi(self) -> PhysicsInformedModel:
        return self.physics_informed()

    def _fit_diagnosed(self) -> KinematicModel:
        job = self._cache.pop("diagnosis_job", None)
        if job is not None:  # started by prefetch in its own worker process: the same bits as here
            pool, future = job
            try:
                model, seconds = future.result()  # the worker's own error, or BrokenProcessPool if it died
            except BaseException:  # an interrupt here must not wait for the rest of the diagnosis
                pool.terminate()
                raise
            pool.shutdown(cancel=False)
            self._cache.setdefault("worker_seconds", {})["diagnosed"] = seconds
            return model
        return self._diagnose()

    def _diagnose(self) -> KinematicModel:

        opts = DiagnoseOptions(a=self.options.a, tolerance=self.options.tolerance, cluster_size=self.options.cluster_size)
        found = diagnose(self.robot, self.nominal, self.train, gravity=self.gravity, joint_limits=self.joint_limits,
                         options=opts)
        return replace(found.model, method="diagnosed", info={**found.model.info, "verdict": found.verdict})

    def _cdc_options(self, method: str) -> dict[str, Any]:
        kind = cdc_method(method)[1]
        options: dict[str, Any] = {}
        if kind == "fbf7":
            options["rank"] = self.options.fbf7_rank
        if method == "pi+ae":
            options["hidden"] = tuple(self.options.pi_ae_hidden)
        if kind in ("nn", "ae"):
            options["random_state"] = self.options.seed
            options["progress"] = self.options.epoch_progress
        if kind in ("fbf13", "fbf7"):
            options["ridge"] = self._choose_strength(method, options, "ridge", self.options.fourier_ridge_grid)
        return options

    def _build_cdc(self, method: str, options: dict[str, Any]) -> CdcModel:
        reference, kind = cdc_method(method)
        return build_cdc(self.robot, method, self.reference(reference)[0], self.local_fits(reference),
                         interpolator=kind, **options)

    def _fit_cdc(self, method: str) -> KinematicModel:
        options = self._cdc_options(method)
        if self.warm is not None:  # a fold refit is not checked: the fit on every cluster was
            return self._build_cdc(method, options)
        if method not in NEURAL_METHODS:
            check = self._held_out_check(method, options)
            model = self._build_cdc(method, options)
            h = check.result()
        else:
            final = self._cache.get("prefetched", {}).pop(method, None)
            if final is not None:  # final network (and the check's fold refits) trained in worker processes
                model, final_s = self._collect(final)
            else:
                # The check's fold refits are network trainings: started in worker processes first, they run
                # while the final network trains here (the same bits as in-process)
                self._submit_folds([(method, f) for f in range(robust.NEURAL_EVALUATED_FOLDS)])
                try:
                    start = time.perf_counter()
                    model = self._build_cdc(method, options)
                    final_s = time.perf_counter() - start
                    for f in range(robust.NEURAL_EVALUATED_FOLDS):
                        self._fold_error(method, f)  # collected here, so a worker failure shuts the pool
                except BaseException:
                    self._shutdown_jobs()
                    raise
            for f in range(robust.NEURAL_EVALUATED_FOLDS):
                self._fold_error(method, f)
            self._cache.setdefault("worker_seconds", {})[method] = final_s + sum(
                self._cache["fold_seconds"][method, f] for f in range(robust.NEURAL_EVALUATED_FOLDS))
            h = self._neural_check(method)
        model.info.update(self._cdc_checks(method, model, h))
        return model

    def _held_out_check(self, method: str, options: dict[str, Any]) -> robust.HeldOutCheck:

        reference, kind = cdc_method(method)
        (kin, theta), local = self.reference(reference), self.local_fits(reference)
        groups, _ = cluster_anchors(self.clustered, self.options.cluster_size)
        return robust.HeldOutCheck(lambda: make_interpolator(kind, **options), kin, theta,
                                   local.anchors, local.x, groups, self.clustered, CDC_INPUTS, seed=self.options.seed)

    def _neural_check(self, method: str) -> robust.HeldOut:
        """The neural kinds' held-out check: the method and its constant reference (``nls1`` / ``pi``) refitted
        without each of the first :data:`robust.NEURAL_EVALUATED_FOLDS` folds (the recommendation's own fold refits,
        :meth:`held_out_errors`), on those folds' poses."""
        reference = REFERENCE_FITS[cdc_method(method)[0]]
        groups, _ = cluster_anchors(self.train, self.options.cluster_size)
        folds = self._fold_fitters()[: robust.NEURAL_EVALUATED_FOLDS]
        rows = np.concatenate([np.flatnonzero(held) for held, _ in folds])
        return robust.HeldOut.of_errors(
            np.concatenate([self._fold_error(method, f) for f in range(len(folds))]),
            np.concatenate([self._fold_error(reference, f) for f in range(len(folds))]), groups[rows])

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
            self._start_diagnosis()
        prefetched = self._cache.setdefault("prefetched", {})
        neural = [m for m in ("ae", "pi+ae", "nn", "pi+nn") if m in methods and m not in prefetched
                  and m not in self._cache.get("fitted", ())]
        if not neural or workers.default_workers(robust.N_FOLDS) < 2 or "fork" not in mp.get_all_start_methods():
            return
        for m in neural:  # the shared fits of each reference, once, before the workers fork
            self._prepare_shared(m)
        jobs = {m: self._cdc_options(m) for m in neural}
        folds = [(m, f) for m in neural for f in range(robust.NEURAL_EVALUATED_FOLDS)]
        if held_out:

            unread = off_reference({m: (ref, self.held_out_errors(ref)) for m in methods if m in CDC_METHODS
                                    for ref in [REFERENCE_FITS[cdc_method(m)[0]]]})
            folds += [(m, f) for m in neural if m not in unread
                      for f in range(robust.NEURAL_EVALUATED_FOLDS, robust.N_FOLDS)]
        self._prepare_folds(folds)  # the fold refits' shared fits too, before the fork
        for m, options in jobs.items():  # the longest (ae's final training) first
            prefetched[m] = self._submit(_prefetch_final, m, options)
        self._submit_folds(folds)

    def _start_diagnosis(self) -> None:
        """Start ``diagnosed``'s fit in a forked worker process of its own (collected by :meth:`fit`); a no-op
        when it is fitted or started, without ``fork`` or with one usable core."""
        if ("diagnosis_job" in self._cache or "diagnosed" in self._cache.get("fitted", ())
                or workers.default_workers(robust.N_FOLDS) < 2 or "fork" not in mp.get_all_start_methods()):
            return
        pool = workers.ForkPool(1, self)  # the worker forks during the submit, with this Fitter as it is then
        self._cache["diagnosis_job"] = pool, pool.submit(_diagnosis_job)

    def prefetch_held_out_errors(self, methods: list[str] | tuple[str, ...]) -> None:
        """:meth:`held_out_errors` of the neural CDC methods among ``methods``, their fold refits (a network
        trained per method and fold, the bulk of a recommendation's cost) run in forked worker processes; the same
        bits as refitted here (every training is deterministic on one BLAS thread).

        The fold Fitters' shared fits (reference, local fits) are made here first, so no worker repeats them.
        A no-op without the ``fork`` start method or with one usable core.
        """
        cache = self._cache.setdefault("held_out_errors", {})
        neural = [m for m in methods if m in NEURAL_METHODS and m not in cache]
        if not neural or workers.default_workers(robust.N_FOLDS) < 2 or "fork" not in mp.get_all_start_methods():
            return
        for m in neural:
            if m not in self._cache.get("fitted", ()):
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
        if "pool" not in self._cache:
            self._cache["pool"] = workers.ForkPool(workers.default_workers(robust.N_FOLDS), self)
        return self._cache["pool"].submit(job, *args)

    def _submit_folds(self, jobs: list[tuple[str, int]]) -> None:
        """Start the fold refits ``(method, fold)`` not yet made or started, in forked workers (in this process
        when there is one usable core or no ``fork``)."""
        cached, pending = self._cache.setdefault("fold_errors", {}), self._cache.setdefault("fold_jobs", {})
        jobs = [j for j in jobs if j not in cached and j not in pending]
        if not jobs or workers.default_workers(robust.N_FOLDS) < 2 or "fork" not in mp.get_all_start_methods():
            return
        if "pool" not in self._cache:  # workers forked later see them
            self._prepare_folds(jobs)
        for m, f in jobs:
            pending[m, f] = self._submit(_fold_error_job, m, f)

    def _collect(self, future: Any) -> Any:
        """A worker job's result; the pool is shut once no job is pending."""
        try:
            return future.result()  # a worker that died raises BrokenProcessPool
        finally:
            if not self._cache.get("prefetched") and not self._cache.get("fold_jobs"):
                self._shutdown_jobs()

    def _shutdown_jobs(self) -> None:
        """Drop the jobs not started and wait for the workers to exit."""
        pool = self._cache.pop("pool", None)
        if pool is not None:
            pool.shutdown()
        self._cache.pop("fold_jobs", None)
        self._cache.pop("prefetched", None)

    def abort_jobs(self) -> None:
        """Stop every worker process now (the network pool and ``diagnosed``'s), its results dropped: after a
        failure or an interrupt in the parent, which must not wait for a fit nobody will collect."""
        job = self._cache.pop("diagnosis_job", None)
        for pool in (job[0] if job else None, self._cache.get("pool")):
            if pool is not None:
                pool.terminate()
        self._shutdown_jobs()  # drops the network jobs' bookkeeping (their workers are gone already)

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
        if method not in self._cache.get("fitted", ()):
            self.fit(method)  # chooses the strengths the fold refits reuse
        return self._fold_errors(method)

    def _fold_errors(self, method: str) -> np.ndarray:
        """:meth:`held_out_errors` of a method whose strengths are chosen (cached)."""
        cache = self._cache.setdefault("held_out_errors", {})
        if method not in cache:
            err = np.empty(len(self.train))
            for f, (held, _) in enumerate(self._fold_fitters()):
                err[held] = self._fold_error(method, f)
            cache[method] = err
        return cache[method]

    def _fold_error(self, method: str, fold: int) -> np.ndarray:
        """Position errors [mm] on fold ``fold``'s poses of ``method`` refitted without them (cached; collected
        from a worker when one refits it)."""
        cached = self._cache.setdefault("fold_errors", {})
        if (method, fold) not in cached:
            job = self._cache.get("fold_jobs", {}).pop((method, fold), None)
            err, seconds = self._collect(job) if job is not None else _fold_error_of(self, method, fold)
            cached[method, fold] = err
            self._cache.setdefault("fold_seconds", {})[method, fold] = seconds
        return cached[method, fold]

    def _fold_fitters(self) -> list[tuple[np.ndarray, Fitter]]:
        """``(held-out mask, Fitter on the other clusters)`` per fold, shared by every method (cached)."""
        if "folds" not in self._cache:
            self._require_clusters(2, "held-out figures (each fold refitted on the other clusters)")
            groups, anchors = cluster_anchors(self.train, self.options.cluster_size)
            folds = robust.cluster_folds(len(anchors), robust.N_FOLDS, self.options.seed)[groups]
            self._cache["folds"] = [(folds == f, replace(self, train=self.train.subset(folds != f), warm=self,
                                                         _cache={})) for f in range(robust.N_FOLDS)]
        return self._cache["folds"]

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
        if "workspace_probes" not in self._cache:
            _, anchor_q = cluster_anchors(self.clustered, self.options.cluster_size)
            self._cache["workspace_probes"] = workspace.workspace_probes(
                anchor_q[:, list(CDC_INPUTS)], self.joint_limits, self.par.n_joints, CDC_INPUTS,
                seed=self.options.seed)
        return self._cache["workspace_probes"]

    def _choose_strength(self, method: str, options: dict[str, Any], name: str, grid: tuple[float, ...]) -> float:
        """Option ``name`` of CDC ``method``'s interpolator from ``grid``, on held-out training clusters (1-SE rule);
        a fold refit takes the :attr:`warm` Fitter's choice."""

        if self.warm is not None:
            if method not in self.warm._cache.get("strengths", {}):
                self.warm.fit(method)
            return self.warm._cache["strengths"][method][name]
        ref_name, kind = cdc_method(method)
        (kin, theta), local = self.reference(ref_name), self.local_fits(ref_name)
        groups, _ = cluster_anchors(self.clustered, self.options.cluster_size)
        scores: list[robust.HeldOut | None] = []
        reference = robust.position_errors(kin, theta, self.clustered)
        for v in grid:
            try:
                scores.append(robust.held_out(lambda: make_interpolator(kind, **{**options, name: v}),
                                              kin, theta, local.anchors, local.x, groups, self.clustered,
                                              CDC_INPUTS, seed=self.options.seed, reference_mm=reference))
            except ModelError as e:  # e.g. ridge 0 with fewer than 13 anchors in a fold: that strength is out
                log.info("%s %s=%g cannot be fitted on the held-out folds: %s", method, name, v, e)
                scores.append(None)
        usable = [i for i, s in enumerate(scores) if s is not None]
        if not usable:
            raise ModelError(f"{method}: no {name} of {list(grid)} can be fitted on the held-out folds of "
                             f"{len(local.anchors)} clusters")
        chosen = grid[usable[robust.one_se_choice(tuple(grid[i] for i in usable), [scores[i] for i in usable])]]
        self._cache.setdefault("strengths", {})[method] = {
            name: chosen, "grid": list(grid),
            "heldout_rms_mm": [None if s is None else round(s.rms_mm, 4) for s in scores]}
        return chosen

    def _cdc_checks(self, method: str, model: Any, h: robust.HeldOut) -> dict[str, Any]:
        """Held-out-cluster (``h``) and probe-range checks of a CDC fit (training data only); a warning when
        one fails."""
        reference = cdc_method(method)[0]
        local = self.local_fits(reference)
        probes = workspace.probe_grid(local.anchors)
        excess = workspace.range_excess(model.interpolator.predict(probes), local.x, 0.01 * self.par.scale())
        ratio, probe_mm, train_mm = workspace.workspace_ratio(model.fk, self._reference_fk(reference), self.train.q,
                                                           self._workspace_probes())
        info: dict[str, Any] = {
            "heldout": {"rms_mm": round(h.rms_mm, 4), "max_mm": round(h.max_mm, 4),
                        "reference_rms_mm": round(h.reference_rms_mm, 4),
                        "reference_max_mm": round(h.reference_max_mm, 4)},
            "probe_range_excess": {"max": round(float(excess.max()), 3),
                                   "share_over_limit": round(float(np.mean(excess > workspace.RANGE_EXCESS_LIMIT)), 3)},
            "workspace_correction": {"ratio": round(ratio, 2), "probe_p99_mm": round(probe_mm, 4),
                                     "train_p99_mm": round(train_mm, 4)},
            "reference": reference,
            "local_prior": self._cache.get("local_prior_cv", {}).get(reference, {"chosen": self.options.local_prior}),
        }
        if method in self._cache.get("strengths", {}):
            info["strength"] = self._cache["strengths"][method]
        problems = []
        if h.ratio > robust.HELDOUT_RATIO_LIMIT:
            problems.append(f"on training clusters held out from it, its position RMS is {h.rms_mm:.3f} mm (max "
                            f"{h.max_mm:.3f}) against {h.reference_rms_mm:.3f} mm (max {h.reference_max_mm:.3f}) "
                            f"for the constant {reference} reference fit (x{h.ratio:.2f})")
        if ratio > workspace.WORKSPACE_RATIO_LIMIT:
            problems.append(f"its correction over the constant reference reaches {probe_mm:.3f} mm (99th "
                            f"percentile) at configurations spread over the joint limits against {train_mm:.3f} mm "
                            f"on the training poses (x{ratio:.1f}): the local fits carry directions the clusters "
                            f"cannot see")
        if not info["local_prior"].get("within_workspace_limit", True):
            problems.append(f"no local prior of {info['local_prior']['grid']} kept its correction over the workspace "
                            f"within {workspace.WORKSPACE_RATIO_LIMIT:g} times that on the training poses (ratios "
                            f"{info['local_prior']['workspace_ratio']}), so the strongest was taken: the local fits "
                            f"are held near the {reference} reference and the method gives about what it gives")
        if excess.max() > workspace.RANGE_EXCESS_LIMIT:
            problems.append(f"at {np.mean(excess > workspace.RANGE_EXCESS_LIMIT):.0%} of {len(probes)} probe "
                            f"configurations within 10 deg of the anchors' (q2, q3) box its raw parameters leave "
                            f"the local fits' range by up to {excess.max():.1f} times that range (clipped to it)")
        if problems:
            info["warning"] = f"{method} may be unstable: " + "; ".join(problems) + \
                ". Prefer the pi method (--method pi), or train on more clusters (a denser plan)."
        return info


def _fold_error_of(fitter: Fitter, method: str, fold: int) -> tuple[np.ndarray, float]:
    """``method`` refitted without fold ``fold``'s clusters of ``fitter``: its position errors [mm] on them and the
    refit's time [s]."""

    start = time.perf_counter()
    held, sub = fitter._fold_fitters()[fold]
    err = errors(sub.fit(method)[0], fitter.train.subset(held)).position_mm
    return err, time.perf_counter() - start


def _fold_error_job(fitter: Fitter, method: str, fold: int) -> tuple[np.ndarray, float]:
    """Worker job of :meth:`Fitter._submit_folds`: :func:`_fold_error_of` on the Fitter that forked it."""
    return _fold_error_of(fitter, method, fold)


def _prefetch_final(fitter: Fitter, method: str, options: dict[str, Any]) -> tuple[CdcModel, float]:
    """Worker job of :meth:`Fitter.prefetch`: the final model and its fit time [s]."""
    start = time.perf_counter()
    model = fitter._build_cdc(method, options)
    return model, time.perf_counter() - start


def _diagnosis_job(fitter: Fitter) -> tuple[KinematicModel, float]:
    """Worker job of :meth:`Fitter._start_diagnosis`: ``diagnosed``'s model and its fit time [s]."""
    start = time.perf_counter()
    model = fitter._diagnose()
    return model, time.perf_counter() - start


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


