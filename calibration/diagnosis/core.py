"""Diagnose a kinematic model against recordings: find the physics it left out, model it, show the gain.

:func:`diagnose` runs these steps, each a function of this module that takes and returns plain data:

1. :func:`split_data`: the fit and the held-out data (a share of the clusters set aside when no held-out
   recording is given).
2. :func:`fit_model_in_use`: the geometric NLS, or a given model's geometry refitted along its observable
   directions (any kind: constant, physics, pi, cdc, see :mod:`.inuse`); its held-out accuracy is the baseline.
3. :func:`residual_drivers`: where the mismatch is, its residual correlated with every driver (:mod:`.drivers`).
4. :func:`candidate_signatures`: the hypotheses, the candidate library with signatures, what the geometry
   absorbs projected out (:mod:`.candidates`).
5. :func:`select_effects`: forward selection with blocked cross-validation, the BIC and nested F-tests
   (:mod:`.selection`).
6. :func:`confirm_on_heldout`: the selected kinds, in order, refitted jointly with the model in use
   (:mod:`.refit`); each kept only if the held-out data confirm it.
7. :func:`refit_model`: the noise floor and the model file (:func:`.model.result_model`), refitted on all
   the data when the held-out share was set aside from it.
8. :func:`report`: held-out accuracy before and after, per effect, with a plain-language verdict
   (:mod:`.explain`).

Every acceptance (selection, its backward confirmation, the held-out confirmation) is the one rule
:meth:`.selection.Evidence.accepted`.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any, Protocol, cast

import numpy as np
from scipy import special  # not scipy.stats: its import costs ~1 s per command (the same values, bit for bit)
from scipy.linalg import block_diag

from calibration.data.recording import Recording
from calibration.diagnosis import explain
from calibration.diagnosis.candidates import (
    KINDS,
    Candidate,
    CandidateKey,
    Signatures,
    Untested,
    dedupe,
    library,
    merge,
    visibility,
)
from calibration.diagnosis.drivers import Driver, Mismatch, drivers, locate_mismatch
from calibration.diagnosis.fits import JointFits
from calibration.diagnosis.inuse import InUse
from calibration.diagnosis.noise import NoiseFloor, channel_weight, noise_floor
from calibration.diagnosis.refit import JointFit, JointProblem, filter_prior
from calibration.diagnosis.refitted_model import result_model
from calibration.diagnosis.report import Accuracy, Diagnosis, EffectEvidence, FoundEffect, PlotData
from calibration.diagnosis.selection import (
    SAME_PHYSICS,
    Evidence,
    LinearSelection,
    Selection,
    SelectionOptions,
    blocked_folds,
    extends,
    forward_select,
    tune_warmup,
)
from calibration.errors import DataError, ModelError
from calibration.identification import DEFAULT_ORIENTATION_WEIGHT, rotation_residual_scale, weighted_residuals
from calibration.identification.observability import DEFAULT_RELATIVE_TOLERANCE, Observability, analyse
from calibration.kinematics.arrays import FloatArray
from calibration.kinematics.poe import PoeModel, pose_error
from calibration.models import KinematicModel
from calibration.models.guard import REGION_KEY, Region, extrapolation
from calibration.physics.base import Effect
from calibration.physics.compliance import JointCompliance, LumpedCompliance, LumpedPayloadCompliance, PayloadCompliance
from calibration.physics.context import Context
from calibration.physics.gravity import GravityModel
from calibration.physics.joint_effects import JointOffset
from calibration.workers import usable_workers

log = logging.getLogger("cellcal.calibration")


class _PerJoint(Protocol):
    """An effect on named joints: the compliances in every form, backlash, joint offsets."""

    @property
    def joints(self) -> tuple[int, ...]: ...


@dataclass(frozen=True)
class DiagnoseOptions:
    """Settings of a diagnosis.

    Attributes:
        a: orientation weight (1641: 1 mm ~ 1 deg): the weight of the pilot fit that estimates the noise floors,
            and the weight throughout when ``weighting`` is ``fixed``.
        weighting: ``noise`` (each channel weighed by its own noise floor estimated from the data, see
            :func:`.noise.channel_weight`: a Gaussian likelihood with per-channel variances; the fixed ``a`` when
            that weight raises the model in use's held-out position RMS by more than ``WEIGHT_CHECK``) or
            ``fixed`` (``a``).
        tolerance: relative singular value below which a geometric direction is held at its reference.
        selection: selection thresholds.
        kinds: effect kinds to consider.
        heldout_fraction: share of clusters set aside when no held-out recording is given.
        cluster_size: samples per cluster when the data has no cluster column.
        n_reference: random poses of the reference workspace when no held-out recording is given.
        seed: seed of the reference workspace and of the context resampling.
        compliance_form: ``joint_compliance`` candidates: ``masses`` (per joint, proportional to the gravity
            torque of the link masses), ``mass_free`` (the 5-term form of joints 2 and 3), ``auto`` (masses
            when known, else mass-free).
        refit_geometry: refit the geometric block of a given model along its observable directions: ``yes``,
            ``no``, or ``auto`` (constant and physics models yes; pi models no, so the baseline and the residuals
            are the model's own predictions; on the real R1 data refitting the pi geometry alone changes the
            held-out RMS only from 0.2932 to 0.2929 mm; cdc never, see :mod:`.model`).
    """

    a: float = DEFAULT_ORIENTATION_WEIGHT
    weighting: str = "noise"
    tolerance: float = DEFAULT_RELATIVE_TOLERANCE
    selection: SelectionOptions = field(default_factory=SelectionOptions)
    kinds: tuple[str, ...] = KINDS
    compliance_form: str = "auto"
    refit_geometry: str = "auto"
    heldout_fraction: float = 0.2
    cluster_size: int = 7
    n_reference: int = 1000
    seed: int = 0


#: How the orientation channel is weighed against the position channel.
WEIGHTINGS = ("noise", "fixed")

#: Kinds acting on one joint's angle: each is tested beyond what a zero offset of that joint explains.
ONE_JOINT_KINDS = ("joint_compliance", "payload_compliance", "gear_transmission", "backlash")


@dataclass(frozen=True)
class Split:
    """The data of a diagnosis.

    Attributes:
        fit: the samples the model and the effects are fitted on.
        heldout: the samples that confirm them.
        everything: the data as given (with the set-aside share when ``source`` is ``split``).
        groups: cluster id per fit sample (N,).
        source: ``given`` (a separate held-out recording) or ``split`` (clusters set aside from the data).
        context, heldout_context: the per-sample context of ``fit`` and ``heldout``.
    """

    fit: Recording
    heldout: Recording
    everything: Recording
    groups: np.ndarray
    source: str
    context: Context
    heldout_context: Context


@dataclass(frozen=True)
class FittedInUse:
    """The model in use fitted to the fit data: what the effects are added to.

    Attributes:
        inuse: the model in use at its fitted parameters.
        effects: its own effects, refitted (physics models).
        name: its name in the report (``geometric``, ``pi``, ``cdc-<method>``, with its effects).
        basis: the geometric directions (27, k) the selection's columns span (what the data see).
        refit_basis: the geometric directions the joint refit moves (with the filter prior: all, damped).
        prior: whether the joint refit uses the Tikhonov filter prior (the geometric NLS).
        observability: the observability of its geometry, when analysed.
        accuracy: its held-out accuracy (the baseline).
        heldout_mm: its held-out position errors [mm] (M,).
        heldout_loss: its held-out squared errors of both channels, weighed by their noise [mm^2] (M,).
    """

    inuse: InUse
    effects: tuple[Effect, ...]
    name: str
    basis: np.ndarray
    refit_basis: np.ndarray
    prior: bool
    observability: Observability | None
    accuracy: Accuracy
    heldout_mm: np.ndarray
    heldout_loss: np.ndarray

    def theta_at(self, x: np.ndarray) -> np.ndarray:
        """The fitted parameters with the geometric block ``x``."""
        th = self.inuse.theta.copy()
        th[: self.inuse.n_geometric] = x
        return th


@dataclass(frozen=True)
class ResidualDrivers:
    """The baseline's weighted residual on the fit data (N, 6), the drivers and the ones it follows."""

    residual: np.ndarray
    drivers: tuple[Driver, ...]
    mismatch: tuple[Mismatch, ...]


@dataclass(frozen=True)
class Hypotheses:
    """The candidates the data can test, as columns of the linearised selection problem.

    Attributes:
        problem: the selection problem (baseline columns and every candidate's).
        pool: identifiable candidates with the indices of their columns in ``problem``.
        bases: the visible parameter directions of each candidate, by :meth:`Candidate.key`.
        hidden: candidates the data cannot identify, with the reason.
        untested: candidates the data cannot test (missing columns), with the reason.
        signature: the signatures on the fitted model in use.
        flexible: per kind, the further form it takes at its most flexible, with its visible parameter basis
            (``joint_compliance``: the mass-free form of joints 2-3, whose gravity shape the data fix rather than
            the robot YAML's inertias), when the data identify it.
    """

    problem: LinearSelection
    pool: list[tuple[Candidate, np.ndarray]]
    bases: dict[CandidateKey, np.ndarray]
    hidden: list[Untested]
    untested: list[Untested]
    signature: Signatures
    flexible: dict[str, tuple[Effect, np.ndarray]] = field(default_factory=dict)
    flexible_columns: dict[str, np.ndarray] = field(default_factory=dict)
    forms: dict[str, list[tuple[Effect, np.ndarray]]] = field(default_factory=dict)


#: The further forms of ``joint_compliance`` on joints 2-3, least flexible first: the 5-term mass-free form of a planar
#: shoulder and elbow, then the lumped form (any link masses and centres of mass, the wrist's position included). The
#: most flexible is the reference every other kind must beat (:func:`.selection.forward_select`,
#: :func:`_beyond_flexible`); the YAML-shaped compliance is replaced by the least flexible form the data confirm.
FLEXIBLE_FORMS = ("mass_free", "lumped")


@dataclass(frozen=True)
class Confirmed:
    """The outcome of the held-out confirmation.

    Attributes:
        kept: the effects kept (zero-valued templates) with their parameter bases, in order.
        kinds: their kinds.
        fit: the joint fit of the model in use with the kept effects on the fit data.
        accuracy: its held-out accuracy.
        heldout_mm: its held-out position errors [mm] (M,).
        heldout_loss: its held-out squared errors of both channels, weighed by their noise [mm^2] (M,).
        effects: the report entries of the kept effects (parameters from ``fit``).
        rejected: the report entries of the selected kinds the held-out data did not confirm.
    """

    kept: list[tuple[Effect, np.ndarray]]
    kinds: list[str]
    fit: JointFit
    accuracy: Accuracy
    heldout_mm: np.ndarray
    heldout_loss: np.ndarray
    effects: list[FoundEffect]
    rejected: list[FoundEffect]


@dataclass(frozen=True)
class Refitted:
    """The noise floors after the final fit, the model file and the notes on how it was refitted."""

    noise: NoiseFloor
    model: KinematicModel
    notes: tuple[str, ...]
    orientation_weight_a: float
    weighting: str


def diagnose(robot: str, nominal: PoeModel, data: Recording, heldout: Recording | None = None,
             model: KinematicModel | None = None, gravity: GravityModel | None = None,
             joint_limits: tuple[np.ndarray, np.ndarray] | None = None,
             options: DiagnoseOptions | None = None, progress: Callable[[str], None] | None = None) -> Diagnosis:
    """Find, model and quantify the physics a kinematic model leaves out.

    Args:
        robot: robot name (``R1``).
        nominal: the nominal arm with its tool.
        data: the recording to diagnose on (extra columns ``t``, ``temp_c``, ``payload_kg``, ``dir1..6``,
            ``qd1..qd6``, ``cluster`` are used when present).
        heldout: a separate recording for the before/after figures; None sets aside a share of the clusters.
        model: the model in use (constant, physics, pi or cdc); None fits the geometric NLS (``nls1``).
        gravity: link masses for gravity torques (``joint_compliance``); None leaves that kind untested.
        joint_limits: ``(lower, upper)`` [rad] (6,), the reference workspace when no held-out data is given.
        options: settings.
        progress: called with each step's name (``DIAGNOSE_STEPS``) as it starts (a progress bar).

    Raises:
        ModelError: a model kind diagnose does not know.
    """
    opts = options or DiagnoseOptions()
    if opts.weighting not in WEIGHTINGS:
        raise ModelError(f"unknown weighting {opts.weighting!r}; valid: {', '.join(WEIGHTINGS)}")
    step = progress or (lambda name: None)
    step(DIAGNOSE_STEPS[0])
    split = split_data(data, heldout, opts)
    _require_data(split, opts.cluster_size)
    base = fit_model_in_use(model, nominal, split, opts)
    if opts.weighting == "fixed":
        return _diagnose_weighed(robot, nominal, model, split, gravity, joint_limits, opts, base,
                                 f"Orientation weighed by the fixed a = {opts.a:g}.", step)
    # The pilot's floors are inflated by whatever it leaves out (backlash scatters within clusters): the floors
    # of the final model weigh a second pass when they move the weight by more than WEIGHT_STEP.
    a, problem = channel_weight(_pilot_noise(base, split, opts), opts.a)
    weighed_base = fit_model_in_use(model, nominal, split, replace(opts, a=a))
    if weighed_base.accuracy.rms_mm > WEIGHT_CHECK * base.accuracy.rms_mm:
        # The channels disagree under the model in use: weighing the orientation by its noise bends the fit away
        # from the positions (the held-out clusters' position error grows), so the fixed weight stays.
        note = (f"The orientation weight from the noise floors (a = {a:.4g}) raises the model in use's held-out "
                f"position RMS from {base.accuracy.rms_mm:.3f} to {weighed_base.accuracy.rms_mm:.3f} mm (more than "
                f"{WEIGHT_CHECK:g}x): the channels disagree under it, so the orientation is weighed by the fixed "
                f"a = {opts.a:g}.")
        log.info("diagnose: %s", note)
        return _diagnose_weighed(robot, nominal, model, split, gravity, joint_limits, replace(opts, weighting="fixed"),
                                 base, note, step)
    for n_pass in range(1, 3):
        weighed = replace(opts, a=a)
        result = _diagnose_weighed(robot, nominal, model, split, gravity, joint_limits, weighed,
                                   weighed_base if n_pass == 1 else fit_model_in_use(model, nominal, split, weighed),
                                   problem, step if n_pass == 1 else (lambda name: None))  # a second pass is not re-counted
        a_final, problem = channel_weight(result.noise, opts.a)
        if abs(np.log(a_final / a)) <= np.log(WEIGHT_STEP) or n_pass == 2:
            break
        log.info("diagnose: the final floors move the orientation weight from %.4g to %.4g; second pass", a, a_final)
        a = a_final
    return result


#: The final model's noise floors trigger a second pass when they move the orientation weight by more than this factor.
WEIGHT_STEP = 1.5
#: The noise weight is kept only while the model in use's held-out position RMS at it stays within this factor of
#: its RMS at the fixed weight. Chosen on the shared days' training recordings (their held-out clusters): the
#: ratio is 1.62 on 0516, whose orientation the geometry cannot follow, and 1.00-1.06 on the six other days.
WEIGHT_CHECK = 1.10


def _pilot_noise(base: FittedInUse, split: Split, options: DiagnoseOptions) -> NoiseFloor:
    """The noise floors of both channels on the model in use (before any effect is added)."""
    fit, inuse, w = split.fit, base.inuse, rotation_residual_scale(options.a)
    R, p = inuse.pose(fit.q, base.effects, split.context, inuse.theta)
    r, _ = weighted_residuals(fit.R, fit.p, R, p, w)
    return noise_floor(r, split.groups, base.basis.shape[1] + sum(e.size for e in base.effects), w)


def _diagnose_weighed(robot: str, nominal: PoeModel, model: KinematicModel | None, split: Split,
                      gravity: GravityModel | None, joint_limits: tuple[np.ndarray, np.ndarray] | None,
                      options: DiagnoseOptions, base: FittedInUse, weight_note: str,
                      step: Callable[[str], None] = lambda name: None) -> Diagnosis:
    """Steps 3-8 at one orientation weight ``options.a`` (the model in use ``base`` fitted with it); ``step`` is
    told each step's name as it starts (a progress bar)."""
    step(DIAGNOSE_STEPS[1])
    residual = residual_drivers(base, split, gravity, options)
    hypotheses = candidate_signatures(base, split, residual, gravity, joint_limits, options)
    step(DIAGNOSE_STEPS[2])
    selection = select_effects(hypotheses)
    step(DIAGNOSE_STEPS[3])
    confirmed = confirm_on_heldout(base, split, hypotheses, selection, options)
    step(DIAGNOSE_STEPS[4])
    if not weight_note:
        weight_note = (f"Each channel weighed by its own noise (a Gaussian likelihood with per-channel variances): "
                       f"orientation weight a = {options.a:.4g}.")
    refitted = refit_model(robot, model, base, split, confirmed, options, weight_note)
    return report(robot, split, base, residual, hypotheses, confirmed, refitted)


#: The steps of :func:`diagnose`, in order, as its ``progress`` callback names them.
DIAGNOSE_STEPS = ("fit the model in use", "candidate effects", "selection", "held-out check", "refit")


def split_data(data: Recording, heldout: Recording | None, options: DiagnoseOptions) -> Split:
    """The fit and held-out data: ``heldout`` when given, else every ``1/heldout_fraction``-th block of
    clusters set aside."""
    groups = _groups(data, options.cluster_size)
    if heldout is not None:
        return Split(data, heldout, data, groups, "given", data.context(), heldout.context())
    k = max(2, int(round(1.0 / options.heldout_fraction)))
    ho = blocked_folds(groups, k) == 0
    fit, held = data.subset(~ho), data.subset(ho)
    return Split(fit, held, data, groups[~ho], "split", fit.context(), held.context())


def fit_model_in_use(model: KinematicModel | None, nominal: PoeModel, split: Split, options: DiagnoseOptions
                     ) -> FittedInUse:
    """The model in use fitted to the fit data: its geometric block (cdc: held) and its own effects."""
    obs: Observability | None
    if model is None:
        inuse, effects, basis, obs, name = _fit_geometric(nominal, split, options)
    else:
        inuse, effects, basis, obs, name = _refit_given(model, nominal, split, options)
    prior = model is None  # the geometric model and the effects are fitted with the Tikhonov filter
    refit_basis = np.eye(inuse.n_geometric) if prior else basis  # with the filter every direction moves, damped
    accuracy, heldout_mm, loss = _accuracy(name, inuse, inuse.theta, effects, split.heldout, split.heldout_context,
                                           options)
    return FittedInUse(inuse, effects, name, basis, refit_basis, prior, obs, accuracy, heldout_mm, loss)


def _fit_geometric(nominal: PoeModel, split: Split, options: DiagnoseOptions
                   ) -> tuple[InUse, tuple[Effect, ...], np.ndarray, Observability, str]:
    """The geometric NLS with the filter prior; the selection sees the directions the data see."""
    fit, ctx = split.fit, split.context
    inuse = InUse.from_model(None, nominal)
    g = inuse.n_geometric
    obs = analyse(inuse.par, fit.q, a=options.a, tolerance=options.tolerance)
    prior = filter_prior(inuse, fit.q, ctx, (), options.a, options.tolerance)
    sol = JointProblem(inuse.par, fit.q, fit.R, fit.p, ctx, np.zeros(g), np.eye(g), (),
                       rotation_residual_scale(options.a), prior_weight=prior).solve()
    return inuse.with_theta(sol.theta), (), obs.basis, obs, "geometric"


def _refit_given(model: KinematicModel, nominal: PoeModel, split: Split, options: DiagnoseOptions
                 ) -> tuple[InUse, tuple[Effect, ...], np.ndarray, Observability | None, str]:
    """A given model with its geometry refitted along its observable directions (when refitted) and its own
    effects refitted."""
    fit = split.fit
    inuse = InUse.from_model(model, nominal)
    g = inuse.n_geometric
    obs = None
    refit = options.refit_geometry == "yes" or (options.refit_geometry == "auto"
                                                and inuse.kind in ("constant", "physics"))
    if inuse.kind == "cdc" or not refit:
        basis = np.zeros((g, 0))  # cdc: a file cannot carry a shift of the interpolated geometry
    else:
        view = inuse.par if inuse.plain(inuse.theta) else inuse.kin.geometry_view(inuse.theta)
        obs = analyse(view, fit.q, inuse.theta[:g], options.a, options.tolerance)
        basis = obs.basis
    sol = JointProblem(inuse.par, fit.q, fit.R, fit.p, split.context, inuse.theta[:g], basis, inuse.effects,
                       rotation_residual_scale(options.a), inuse=inuse).solve()
    name = "+".join([_base_name(model)] + [e.kind for e in sol.effects])
    return inuse.with_theta(sol.theta, ()), sol.effects, basis, obs, name


def residual_drivers(base: FittedInUse, split: Split, gravity: GravityModel | None, options: DiagnoseOptions
                     ) -> ResidualDrivers:
    """The baseline's residual on the fit data, and the drivers it follows, strongest first."""
    fit, inuse = split.fit, base.inuse
    R, p = inuse.pose(fit.q, base.effects, split.context, inuse.theta)
    r0, _ = weighted_residuals(fit.R, fit.p, R, p, rotation_residual_scale(options.a))
    drv = drivers(inuse.geometry(inuse.theta), fit.q, split.context, gravity)
    return ResidualDrivers(r0, tuple(drv), tuple(locate_mismatch(r0, drv)))


def candidate_signatures(base: FittedInUse, split: Split, residual: ResidualDrivers, gravity: GravityModel | None,
                         joint_limits: tuple[np.ndarray, np.ndarray] | None, options: DiagnoseOptions) -> Hypotheses:
    """The candidates with their signatures on the fitted model in use, the ones the data cannot identify set
    apart, as columns of the selection problem."""
    fit, ctx, inuse = split.fit, split.context, base.inuse
    w_rot = rotation_residual_scale(options.a)
    sig = Signatures(inuse, fit.q, ctx, w_rot)
    A = np.concatenate([_geometric_columns(inuse, fit.q, inuse.theta, base.basis, w_rot)]
                       + [sig(e) for e in base.effects], axis=1)
    kinds = tuple(k for k in options.kinds if k not in _present_kinds(base))
    cands, untested = library(inuse.geometry(inuse.theta), fit.q, ctx, gravity, kinds, options.compliance_form)
    q_ref, ctx_ref = _reference(None if split.source == "split" else split.heldout, fit.q, ctx, joint_limits, options)
    pool, hidden, bases = _screen(cands, A, sig, q_ref, ctx_ref, options.selection.visible_min)
    flexible, forms = {}, {}
    if "joint_compliance" in kinds and gravity is not None and options.compliance_form == "auto":
        steps = []
        for form in FLEXIBLE_FORMS:  # least flexible first
            free = library(inuse.geometry(inuse.theta), fit.q, ctx, gravity, ("joint_compliance",), form)[0]
            seen, _, free_bases = _screen(free, A, sig, q_ref, ctx_ref, options.selection.visible_min)
            if seen:
                steps.append((free[0].effect, free_bases[free[0].key()]))
                if form == FLEXIBLE_FORMS[-1]:
                    # The most flexible form is a candidate too: when the YAML's shape is far off, a gear error's
                    # harmonics of q2 fitted the shoulder's own weight better than it and took its place (family
                    # training seed 60003, R2); the BIC charges the form's every parameter.
                    pool += seen
                    bases.update(free_bases)
        if steps:
            flexible["joint_compliance"], forms["joint_compliance"] = steps[-1], steps
    if any(c.kind == "payload_compliance" for c in cands):
        # The payload's point is not known either: its lumped form (any point of the last link) is what a payload
        # deflection of another shape is measured against, so a gear error does not take up the tool point's misfit.
        free = [Candidate("payload_compliance", "joints 2-3 (lumped form)", (2, 3),
                          LumpedPayloadCompliance((2, 3), np.zeros(8), n_joints=fit.q.shape[1]))]
        seen, _, free_bases = _screen(free, A, sig, q_ref, ctx_ref, options.selection.visible_min)
        if seen:
            flexible["payload_compliance"] = (free[0].effect, free_bases[free[0].key()])
    problem = LinearSelection(A, residual.residual, split.groups, options.selection)
    pool = tune_warmup(pool, problem, sig)
    pool = [(c, problem.add(S)) for c, S in pool]
    flexible_columns = {k: problem.add(sig(e) @ B) for k, (e, B) in flexible.items()}
    hidden = dedupe(hidden, {c.label for c, _ in pool})
    log.info("diagnose: %d candidates testable, %d not identifiable, %d untested", len(pool), len(hidden), len(untested))
    return Hypotheses(problem, pool, bases, hidden, untested, sig, flexible, flexible_columns, forms)


def _present_kinds(base: FittedInUse) -> set[str]:
    """Kinds the model in use already carries (not candidates)."""
    present = {e.kind for e in base.effects}
    if base.inuse.kind in ("pi", "cdc"):  # they carry the tool rotation, the mass-free compliance and the deflection
        present |= {"tool_frame", "joint_compliance", "structural_deflection"}
    return present


def _screen(cands: list[Candidate], A: np.ndarray, sig: Signatures, q_ref: np.ndarray, ctx_ref: Context,
            visible_min: float
            ) -> tuple[list[tuple[Candidate, np.ndarray]], list[Untested], dict[CandidateKey, np.ndarray]]:
    """Identifiable candidates with their signatures in their visible directions, the others with the reason,
    and the visible directions of each identifiable one."""
    Q = np.linalg.qr(A)[0]
    n_fit, n_ref = sig.q.shape[0], q_ref.shape[0]
    pool, hidden, bases = [], [], {}
    for c in cands:
        S = sig(c.effect)
        S_ref = sig.on(c.effect, q_ref, ctx_ref)
        Qc, S_ref_varying = Q, S_ref
        if c.kind in ONE_JOINT_KINDS and len(c.joints) == 1:
            # An effect on one joint's angle is identifiable only beyond its mean over the data, which is a joint
            # offset (a compliance whose torque barely varies is an offset, not a compliance). Once identified a
            # gear error carries that mean itself, so it is not reported as a gear error plus an offset.
            # Its variation on the data is measured against its variation over the reference workspace.
            Qc = np.linalg.qr(np.concatenate([A, sig(JointOffset((c.joints[0],), np.zeros(1)))], axis=1))[0]
            off = sig.on(JointOffset(c.joints, np.zeros(1)), q_ref, ctx_ref)
            S_ref_varying = S_ref - off @ np.linalg.lstsq(off, S_ref, rcond=None)[0]
        vis, exc, B = visibility(S, Qc, S_ref_varying, n_fit, n_ref, visible_min)
        if vis < visible_min:
            hidden.append(explain.not_identifiable(c, vis, exc, sig.q, q_ref))
            continue
        if c.kind == "gear_transmission":
            B = visibility(S, Q, S_ref, n_fit, n_ref, visible_min)[2]
        bases[c.key()] = B
        pool.append((c, S @ B))
    return pool, hidden, bases


def select_effects(hypotheses: Hypotheses) -> Selection:
    """Forward selection on the fit data, confirmed backward per kind (see :mod:`.selection`)."""
    return forward_select(hypotheses.problem, hypotheses.pool, hypotheses.signature, hypotheses.flexible_columns,
                          {k: tuple(getattr(e, "joints", ())) for k, (e, _) in hypotheses.flexible.items()})


def confirm_on_heldout(base: FittedInUse, split: Split, hypotheses: Hypotheses, selection: Selection,
                       options: DiagnoseOptions) -> Confirmed:
    """Each selected kind, in the order first selected and merged over its joints or links, refitted jointly
    with the model in use and the kinds kept before it; kept only when the rule accepts it on the held-out data."""
    kinds = selection.kinds()
    merged = [merge(k, _on_compliant_joints(k, selection, hypotheses.pool), hypotheses.bases) for k in kinds]
    fits = JointFits(lambda chosen: joint_fit(base, chosen, split.fit, options),
                     usable_workers() if merged else 1)
    with fits:
        return _confirm(base, split, hypotheses, selection, kinds, merged, fits, options)


def _on_compliant_joints(kind: str, selection: Selection, pool: list[tuple[Candidate, np.ndarray]]) -> list[Candidate]:
    """The selected candidates of ``kind``; for a kind of the same physics under another load (:data:`SAME_PHYSICS`:
    the payload's deflection), joined by the pool's one-joint candidates of the other joints whose own-weight
    compliance is selected: the payload's torque bends every compliant joint it loads, so the held-out confirmation
    tests the payload compliance on that set (the forward pass may have met the elbow's share before the elbow's own
    weight was established; a joint fitted with the unphysical sign still leaves it, see :func:`_wrong_sign`)."""
    chosen = selection.of_kind(kind)
    if len(chosen) > 1 and any(isinstance(c.effect, LumpedCompliance) for c in chosen):
        # One effect holds a kind's joints: the lumped form of joints 2-3 beside a YAML-shaped joint 5 is confirmed
        # as the YAML shape of all of them, which the lumped form then replaces on joints 2-3 when the held-out data
        # ask for it (as when the forward pass chose the YAML pair).
        pair = [c for c, _ in pool if c.kind == kind and c.joints == (2, 3) and isinstance(c.effect, JointCompliance)]
        if pair:
            chosen = pair + [c for c in chosen if not isinstance(c.effect, LumpedCompliance)]
        else:  # no YAML pair to stand for it: the lumped form alone (one effect cannot hold both shapes)
            log.info("diagnose: %s on joints %s left out beside the lumped form of joints 2-3", kind,
                     sorted({j for c in chosen if not isinstance(c.effect, LumpedCompliance) for j in c.joints}))
            chosen = [c for c in chosen if isinstance(c.effect, LumpedCompliance)]
    base = SAME_PHYSICS.get(kind)
    if base is None or not chosen:
        return chosen
    compliant = {j for c in selection.of_kind(base) for j in c.joints}
    have = {j for c in chosen for j in c.joints}
    extra = [c for c, _ in pool if c.kind == kind and len(c.joints) == 1 and c.joints[0] in compliant - have]
    return chosen + extra


def _confirm(base: FittedInUse, split: Split, hypotheses: Hypotheses, selection: Selection, kinds: list[str],
             merged: list[tuple[Effect, np.ndarray]], fits: JointFits, options: DiagnoseOptions) -> Confirmed:
    """:func:`confirm_on_heldout` with its joint fits made by ``fits``: each step starts the fits it may need
    (the trial and both of :func:`_beyond_flexible`'s) before it waits for the first."""
    kept: list[tuple[Effect, np.ndarray]] = []
    kept_kinds: list[str] = []
    fits.start([], merged[:1])
    final, acc, dp, loss = fits.get([]), base.accuracy, base.heldout_mm, base.heldout_loss
    found, rejected = [], []
    for kind, (e0, B) in zip(kinds, merged):
        flex = _flexible(kept, hypotheses)
        fits.start(kept + [(e0, B)], *((flex, flex + [(e0, B)]) if not _same(flex, kept) else ()))
        trial = fits.get(kept + [(e0, B)])
        t_acc, t_dp, t_loss = _accuracy("+".join([base.name] + kept_kinds + [kind]), base.inuse, base.theta_at(trial.x),
                                        trial.effects, split.heldout, split.heldout_context, options)
        rule, reported = _heldout_evidence(hypotheses.problem, selection, kind, kept_kinds, (acc, loss), (t_acc, t_loss))
        item = explain.found(trial.effects[-1], trial.effect_std[-1], reported)
        if (rule.accepted(options.selection, extends(kind, kept_kinds))
                and _beyond_flexible(base, split, flex, kept, (e0, B), options, fits, extends(kind, kept_kinds))):
            kept.append((e0, B))
            kept_kinds.append(kind)
            found.append(item)
            final, acc, dp, loss = trial, t_acc, t_dp, t_loss
        else:
            rejected.append(item)
    yaml_kept = kept
    for form in hypotheses.forms.get("joint_compliance", []) if "joint_compliance" in kept_kinds else []:
        # A further form replaces the YAML-shaped one on joints 2-3 when the data show a shape the form before cannot.
        flex = _flexible(yaml_kept, hypotheses, form)
        trial = fits.get(flex)
        name = "+".join([base.name] + kept_kinds)
        t_acc, t_dp, t_loss = _accuracy(name, base.inuse, base.theta_at(trial.x), trial.effects, split.heldout,
                                        split.heldout_context, options)
        if _joint_evidence(final, trial, split, (acc, loss), (t_acc, t_loss)).accepted(options.selection, extends=True):
            log.info("diagnose: the %s compliance explains what the shape before it cannot; it replaces it",
                     form[0].form)
            kept, final, acc, dp, loss = flex, trial, t_acc, t_dp, t_loss
            kept_kinds = [e.kind for e, _ in kept]
            found = [found[[i.kind for i in found].index(k)] for k in kept_kinds]
    n = len(base.effects)
    # A compliance or a backlash fitted significantly negative with every kind in is not physics: those joints go.
    while any(wrong := [_wrong_sign(e, sd) for e, sd in zip(final.effects[n:], final.effect_std[n:])]):
        log.info("diagnose: joints %s fitted with the unphysical sign; refitted without them", wrong)
        keep = [i for i, w in enumerate(wrong) if not w or len(w) < len(getattr(kept[i][0], "joints", ()))]
        rejected += [explain.found(final.effects[n + i], final.effect_std[n + i], found[i].evidence)
                     for i in range(len(kept)) if i not in keep]
        kept = [_subset_joints(*kept[i], [k for k, j in enumerate(cast(_PerJoint, kept[i][0]).joints)
                                          if j not in wrong[i]])
                if wrong[i] else kept[i] for i in keep]
        found, kept_kinds = [found[i] for i in keep], [kept_kinds[i] for i in keep]
        final = fits.get(kept)
        acc, dp, loss = _accuracy("+".join([base.name] + kept_kinds), base.inuse, base.theta_at(final.x), final.effects,
                                  split.heldout, split.heldout_context, options)
    # Parameters and uncertainties of the kept effects from the final joint fit.
    found = [explain.found(final.effects[n + i], final.effect_std[n + i], item.evidence) for i, item in enumerate(found)]
    return Confirmed(kept, kept_kinds, final, acc, dp, loss, found, rejected)


#: Kinds whose per-joint values are physically non-negative (a joint sags under load, lost motion is a width).
ONE_SIGNED = ("joint_compliance", "payload_compliance", "backlash")


def _wrong_sign(effect: Effect, std: np.ndarray) -> list[int]:
    """Joints of a one-signed per-joint effect whose fitted value is negative by more than two standard
    deviations."""
    joints = tuple(getattr(effect, "joints", ()))
    if effect.kind not in ONE_SIGNED or effect.size != len(joints):
        return []
    return [j for j, v, sd in zip(joints, effect.values, std) if v < -2.0 * sd]


def _subset_joints(effect: Effect, B: np.ndarray, keep: list[int]) -> tuple[Effect, np.ndarray]:
    """A per-joint effect restricted to the joints at indices ``keep``, with its parameter basis."""
    joints = tuple(cast(_PerJoint, effect).joints[i] for i in keep)  # a per-joint effect (_wrong_sign)
    rows = B[keep]
    cols = np.flatnonzero(np.any(rows != 0, axis=0))
    values = np.zeros(len(joints))
    e = (JointCompliance(effect.gravity, joints, values) if isinstance(effect, JointCompliance)
         else type(effect)(joints=joints, values=values))
    return e, rows[:, cols]


def _flexible(kept: list[tuple[Effect, np.ndarray]], hypotheses: Hypotheses,
              form: tuple[Effect, np.ndarray] | None = None) -> list[tuple[Effect, np.ndarray]]:
    """The kept effects in their most flexible form (or only the kind of ``form``, in ``form``): a joint compliance
    from the YAML's inertias becomes the lumped form on joints 2-3 (its other joints keep the YAML's form), a payload
    compliance at the tool point its lumped form (a payload anywhere on the last link)."""
    out = []
    for e, B in kept:
        flex = (form if e.kind == form[0].kind else None) if form is not None else hypotheses.flexible.get(e.kind)
        if flex is None or e is flex[0] or not isinstance(e, (JointCompliance, PayloadCompliance)):
            out.append((e, B))
            continue
        out.append(flex)
        rest = [i for i, j in enumerate(e.joints) if j not in cast(_PerJoint, flex[0]).joints]  # a compliance form
        if rest:
            out.append(_subset_joints(e, B, rest))
    return out


def _same(a: list[tuple[Effect, np.ndarray]], b: list[tuple[Effect, np.ndarray]]) -> bool:
    """Whether two lists of effect templates hold the same templates."""
    return len(a) == len(b) and all(x is y for (x, _), (y, _) in zip(a, b))


def _beyond_flexible(base: FittedInUse, split: Split, flex: list[tuple[Effect, np.ndarray]],
                     kept: list[tuple[Effect, np.ndarray]], new: tuple[Effect, np.ndarray], options: DiagnoseOptions,
                     joint_fits: JointFits, extending: bool = False) -> bool:
    """Whether ``new`` explains what the kinds kept cannot even in their most flexible form ``flex``
    (:func:`_flexible`; True when they have no further form): a shape mismatch of the YAML's inertias is not a
    second kind. ``extending``: ``new`` extends physics already kept (:func:`.selection.extends`), judged at
    ``z_extend``."""
    if _same(flex, kept):
        return True
    fits, held = [], []
    for chosen in (flex, flex + [new]):
        f = joint_fits.get(chosen)
        fits.append(f)
        held.append(_accuracy("+".join([base.name] + [e.kind for e, _ in chosen]), base.inuse, base.theta_at(f.x),
                              f.effects, split.heldout, split.heldout_context, options))
    ok = _joint_evidence(fits[0], fits[1], split, (held[0][0], held[0][2]), (held[1][0], held[1][2])
                         ).accepted(options.selection, extending)
    if not ok:
        log.info("diagnose: %s is explained by the flexible form of %s; not added", new[0].kind,
                 ", ".join(e.kind for e, _ in kept))
    return ok


def _joint_evidence(before: JointFit, after: JointFit, split: Split, ho_before: tuple[Accuracy, np.ndarray],
                    ho_after: tuple[Accuracy, np.ndarray]) -> Evidence:
    """The rule's evidence from two joint fits on the fit data (BIC, F-test of their weighted RSS) and their
    held-out errors."""
    n_res = 6 * len(split.fit)
    rss = [f.residual_variance * max(n_res - f.n_parameters, 1) for f in (before, after)]
    p = [before.n_parameters, after.n_parameters]
    bic = [n_res * np.log(r / n_res) + k * np.log(n_res) for r, k in zip(rss, p)]
    m, dof2 = max(p[1] - p[0], 1), max(n_res - p[1], 1)
    F = ((rss[0] - rss[1]) / m) / max(rss[1] / dof2, 1e-300)
    pval = float(special.fdtrc(m, dof2, F)) if rss[1] < rss[0] else 1.0
    z = _paired_z(ho_before[1] - ho_after[1])
    return Evidence(float(bic[1] - bic[0]), pval, z, ho_before[0].rms_mm, ho_after[0].rms_mm,
                    float(np.mean(ho_before[1])), float(np.mean(ho_after[1])))


def _heldout_evidence(problem: LinearSelection, selection: Selection, kind: str, kept_kinds: list[str],
                      before: tuple[Accuracy, np.ndarray], after: tuple[Accuracy, np.ndarray]
                      ) -> tuple[Evidence, EffectEvidence]:
    """The evidence for adding ``kind`` to the kinds kept (fit-data tests and the held-out improvement of both
    channels, each weighed by its noise: ``before``/``after`` carry the per-sample weighed squared errors), and
    its report form."""
    fit = selection.fit_evidence(problem, kind, kept_kinds)
    z = _paired_z(before[1] - after[1])
    cv_z = next(s.evidence.heldout_z for s in selection.steps if s.candidate.kind == kind)
    rule = Evidence(fit.delta_bic, fit.f_pvalue, z, before[0].rms_mm, after[0].rms_mm, float(np.mean(before[1])),
                    float(np.mean(after[1])))
    return rule, EffectEvidence(fit.delta_bic, fit.f_pvalue, cv_z, before[0], after[0], z)


def joint_fit(base: FittedInUse, chosen: list[tuple[Effect, np.ndarray]], rec: Recording, options: DiagnoseOptions
              ) -> JointFit:
    """The model in use, its own effects and ``chosen`` (templates with their parameter bases) refitted on
    ``rec``."""
    inuse = base.inuse
    n_base = sum(e.size for e in base.effects)
    B = block_diag(np.eye(n_base), *[b for _, b in chosen])
    effects = base.effects + tuple(e for e, _ in chosen)
    c = rec.context()
    weights = filter_prior(inuse, rec.q, c, effects, options.a, options.tolerance) if base.prior else None
    return JointProblem(inuse.par, rec.q, rec.R, rec.p, c, inuse.theta[: inuse.n_geometric], base.refit_basis,
                        effects, rotation_residual_scale(options.a), B if B.size else None, inuse=inuse,
                        prior_weight=weights).solve()


def refit_model(robot: str, model: KinematicModel | None, base: FittedInUse, split: Split, confirmed: Confirmed,
                options: DiagnoseOptions, weight_note: str = "") -> Refitted:
    """The noise floor after the final fit and the model file; when the held-out share was set aside from the
    data, the saved model is refitted on all of it (the held-out figures stay those of the fit data)."""
    fit, final = split.fit, confirmed.fit
    R, p = base.inuse.pose(fit.q, final.effects, split.context, base.theta_at(final.x))
    w_rot = rotation_residual_scale(options.a)
    r_final, _ = weighted_residuals(fit.R, fit.p, R, p, w_rot)
    noise = noise_floor(r_final, split.groups, final.n_parameters, w_rot)
    saved, saved_on, all_note = final, fit, ""
    if split.source == "split":  # the set-aside clusters chose the effects; the saved model learns from them too
        saved, saved_on = joint_fit(base, confirmed.kept, split.everything, options), split.everything
        all_note = (f"The saved model is refitted on all {len(split.everything)} samples (the {len(fit)} fit samples "
                    f"and the {len(split.heldout)} set-aside ones); the held-out figures are those of the fit on "
                    f"{len(fit)}.")
    info = {"baseline": base.name, "fit_samples": len(saved_on), "effects_found": confirmed.kinds,
            "orientation_weight_a": options.a, REGION_KEY: Region.of(saved_on.q, context=saved_on.context()).to_dict()}
    physics, refit_note = result_model(robot, base.inuse, model, base.theta_at(saved.x), saved.effects,
                                       base.refit_basis.shape[1], info)
    obs = base.observability
    notes = tuple(n for n in [weight_note, obs.summary(damped=base.prior) if obs is not None else "", refit_note,
                              all_note] if n)
    return Refitted(noise, physics, notes, options.a, options.weighting)


def report(robot: str, split: Split, base: FittedInUse, residual: ResidualDrivers, hypotheses: Hypotheses,
           confirmed: Confirmed, refitted: Refitted) -> Diagnosis:
    """Everything found, with the held-out accuracy before and after and the verdict."""
    c = confirmed
    verdict = explain.verdict(c.effects, base.accuracy, c.accuracy, refitted.noise.floor_mm, hypotheses.hidden,
                              hypotheses.untested, c.rejected)
    plots = PlotData(np.linalg.norm(residual.residual[:, :3], axis=1), residual.drivers, base.heldout_mm, c.heldout_mm)
    ex = extrapolation(refitted.model, split.heldout.q, split.heldout.context())
    notes = refitted.notes + ((extrapolation_note(ex),) if ex["outside_training_range"] else ())
    return Diagnosis(robot, len(split.fit), len(split.heldout), split.source, refitted.noise, base.accuracy,
                     c.accuracy, residual.mismatch, tuple(c.effects), tuple(hypotheses.hidden),
                     tuple(hypotheses.untested), verdict, refitted.model, notes, plots, tuple(c.rejected),
                     refitted.orientation_weight_a, refitted.weighting, extrapolation=ex)


def extrapolation_note(ex: dict[str, Any]) -> str:
    """One sentence on the held-out poses outside the saved model's training range and what the guard did."""
    did = (f"the extrapolation guard held the model's effects fitted in joints the data saw narrowly at the edge of "
           f"that range, moving the predicted position by up to {ex['guard_shift_mm_max']:.3f} mm" if ex["guard_acted"]
           else "the guard did not change the prediction (no effect fitted in a narrowly seen joint acts there)")
    return (f"{ex['outside_training_range']} of {ex['poses']} held-out poses lie outside the fit data's joint range "
            f"(by up to {ex['max_excess_deg']:.1f} deg, RMS {ex['rms_excess_deg']:.1f} deg); {did}.")


#: Fewest clusters the fit data and the held-out data each need: a diagnosis compares fits across clusters.
MIN_DIAGNOSE_CLUSTERS = 2


def _require_data(split: Split, cluster_size: int) -> None:
    """Refuse data a diagnosis cannot use: fewer than :data:`MIN_DIAGNOSE_CLUSTERS` clusters to fit on or to hold
    out (7 rows left nothing to fit on: an IndexError), or measurements that never differ within a cluster (copied
    rows: a noise floor of 0, a division by zero).

    Raises:
        DataError: naming the recording and what it lacks.
    """
    for what, rec, groups in (("to fit on", split.fit, split.groups), ("held out", split.heldout, None)):
        n = len(np.unique(groups if groups is not None else _groups(rec, cluster_size))) if len(rec) else 0
        if n < MIN_DIAGNOSE_CLUSTERS:
            raise DataError(split.everything.source or rec.source, None, None,
                            f"too few clusters for a diagnosis: {n} {what} (of {len(split.everything)} rows), at least "
                            f"{MIN_DIAGNOSE_CLUSTERS} needed; give a longer recording (or --test for the held-out "
                            "poses)")
    pose = np.concatenate([split.fit.p, split.fit.quat], axis=1)
    scatter = [np.ptp(pose[split.groups == g], axis=0).max() for g in np.unique(split.groups)]
    if max(scatter) == 0.0:
        raise DataError(split.everything.source, None, None, "no scatter at all: every cluster's measured poses are "
                                                      "identical (copied rows?), so no noise floor can be estimated")


def _groups(rec: Recording, size: int) -> np.ndarray:
    try:
        return rec.clusters(size)
    except DataError:
        return np.arange(len(rec)) // size


def _accuracy(name: str, inuse: InUse, theta: np.ndarray, effects: tuple[Effect, ...], rec: Recording, ctx: Context,
              options: DiagnoseOptions) -> tuple[Accuracy, np.ndarray, np.ndarray]:
    """Held-out accuracy, position errors [mm] (M,) and squared errors of both channels weighed by their noise
    [mm^2] (M,)."""
    R, p = inuse.pose(rec.q, effects, ctx, theta)
    dp, dR = pose_error(rec.R, rec.p, R, p)
    loss = np.sum(weighted_residuals(rec.R, rec.p, R, p, rotation_residual_scale(options.a))[0] ** 2, axis=1)
    return Accuracy.of(name, dp, dR), dp, loss


def _reference(heldout: Recording | None, fit_q: np.ndarray, ctx: Context, limits: tuple[np.ndarray, np.ndarray] | None,
               options: DiagnoseOptions) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Reference workspace: the held-out poses, else uniform in the joint limits; context resampled from the fit."""
    rng = np.random.default_rng(options.seed)
    if heldout is not None:
        q = heldout.q
    elif limits is not None:
        q = rng.uniform(limits[0], limits[1], (options.n_reference, fit_q.shape[1]))
    else:
        q = fit_q
    idx = rng.integers(0, fit_q.shape[0], q.shape[0])
    return q, {k: np.asarray(v)[idx] for k, v in ctx.items()}


def _geometric_columns(inuse: InUse, q: np.ndarray, theta: np.ndarray, basis: np.ndarray, w_rot: float) -> np.ndarray:
    J = inuse.jacobian_geometry(q, theta) @ basis
    J[:, 3:] *= w_rot
    rows: FloatArray = J.reshape(J.shape[0] * 6, J.shape[-1])
    return rows


def _base_name(model: KinematicModel) -> str:
    return {"constant": "geometric", "physics": "geometric", "pi": "pi"}.get(model.kind, f"{model.kind}-{model.method}")


def _paired_z(d: np.ndarray) -> float:
    """z-score of the mean of paired differences (positive: the second model is better)."""
    if d.size < 2 or d.std(ddof=1) == 0:
        return 0.0
    return float(d.mean() / (d.std(ddof=1) / np.sqrt(d.size)))
