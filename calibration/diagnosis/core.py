"""Diagnose a kinematic model against recordings: find the physics it left out, model it, show the gain.

1. Fit the model in use (geometric NLS, or refit a given model's geometry along the observable directions; any
   kind: constant, physics, pi, cdc, see :mod:`.inuse`).
2. Locate the mismatch: correlate its residual with every driver (:mod:`.drivers`).
3. Hypothesise: the candidate library with signatures, what the geometry absorbs projected out
   (:mod:`.candidates`).
4. Select with blocked cross-validation, the BIC and nested F-tests (:mod:`.selection`).
5. Refit the model in use and the selected effects together (:mod:`.refit`) into a model file
   (:func:`.model.result_model`).
6. Report held-out accuracy before and after, per effect, with a plain-language verdict (:mod:`.explain`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import block_diag
from scipy.optimize import minimize_scalar

from calibration.diagnosis import explain
from calibration.diagnosis.candidates import KINDS, Candidate, dedupe, library, merge, tune_warmup, visibility
from calibration.diagnosis.inuse import InUse
from calibration.diagnosis.model import result_model
from calibration.diagnosis.drivers import drivers, locate_mismatch
from calibration.diagnosis.noise import noise_floor
from calibration.diagnosis.refit import JointFit, JointProblem, filter_prior
from calibration.diagnosis.report import Accuracy, Diagnosis, Evidence, PlotData
from calibration.diagnosis.selection import LinearSelection, SelectionOptions, blocked_folds, forward_select
from calibration.errors import DataError
from calibration.identification import DEFAULT_ORIENTATION_WEIGHT, rotation_residual_scale, weighted_residuals
from calibration.models import KinematicModel
from calibration.observability import DEFAULT_RELATIVE_TOLERANCE, analyse
from calibration.physics.base import Context, Effect
from calibration.physics.gravity import GravityModel
from calibration.physics.joint_effects import JointOffset
from calibration.physics.thermal import ThermalDrift
from calibration.poe import PoeModel, pose_error
from calibration.recording import Recording

log = logging.getLogger("cellcal.calibration")


@dataclass(frozen=True)
class DiagnoseOptions:
    """Settings of a diagnosis.

    Attributes:
        a: orientation weight (1641: 1 mm ~ 1 deg).
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
    tolerance: float = DEFAULT_RELATIVE_TOLERANCE
    selection: SelectionOptions = field(default_factory=SelectionOptions)
    kinds: tuple[str, ...] = KINDS
    compliance_form: str = "auto"
    refit_geometry: str = "auto"
    heldout_fraction: float = 0.2
    cluster_size: int = 7
    n_reference: int = 1000
    seed: int = 0


#: Kinds acting on one joint's angle: each is tested beyond what a zero offset of that joint explains.
ONE_JOINT_KINDS = ("joint_compliance", "payload_compliance", "gear_transmission", "backlash")


def _groups(rec: Recording, size: int) -> np.ndarray:
    try:
        return rec.clusters(size)
    except DataError:
        return np.arange(len(rec)) // size


def _accuracy(name: str, inuse: InUse, theta: np.ndarray, effects: tuple[Effect, ...], rec: Recording, ctx: Context
              ) -> tuple[Accuracy, np.ndarray]:
    R, p = inuse.pose(rec.q, effects, ctx, theta)
    dp, dR = pose_error(rec.R, rec.p, R, p)
    return Accuracy.of(name, dp, dR), dp


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
    return J.reshape(J.shape[0] * 6, J.shape[-1])


def diagnose(robot: str, nominal: PoeModel, data: Recording, heldout: Recording | None = None,
             model: KinematicModel | None = None, gravity: GravityModel | None = None,
             joint_limits: tuple[np.ndarray, np.ndarray] | None = None,
             options: DiagnoseOptions | None = None) -> Diagnosis:
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

    Raises:
        ModelError: a model kind diagnose does not know.
    """
    opts = options or DiagnoseOptions()
    w_rot = rotation_residual_scale(opts.a)
    groups_all = _groups(data, opts.cluster_size)
    everything = data
    source = "given"
    if heldout is None:
        k = max(2, int(round(1.0 / opts.heldout_fraction)))
        ho = blocked_folds(groups_all, k) == 0
        data, heldout, groups_all = data.subset(~ho), data.subset(ho), groups_all[~ho]
        source = "split"
    fit, groups = data, groups_all
    ctx, ctx_ho = fit.context(), heldout.context()
    # 1. The model in use, fitted: its geometric block (cdc: held) and its own effects refitted.
    base_effects: tuple[Effect, ...] = ()
    obs = None
    prior = model is None  # the geometric model and the effects are fitted with the Tikhonov filter
    if model is None:
        inuse = InUse.from_model(None, nominal)
        g = inuse.n_geometric
        obs = analyse(inuse.par, fit.q, a=opts.a, tolerance=opts.tolerance)
        sol = JointProblem(inuse.par, fit.q, fit.R, fit.p, ctx, np.zeros(g), np.eye(g), (), w_rot,
                           prior_weight=filter_prior(inuse, fit.q, ctx, (), opts.a, opts.tolerance)).solve()
        inuse = inuse.with_theta(sol.theta)
        basis = obs.basis  # the selection's geometric columns: what the data see
        base_name = "geometric"
    else:
        inuse = InUse.from_model(model, nominal)
        g = inuse.n_geometric
        refit = opts.refit_geometry == "yes" or (opts.refit_geometry == "auto" and inuse.kind in ("constant", "physics"))
        if inuse.kind == "cdc" or not refit:
            basis = np.zeros((g, 0))  # cdc: a file cannot carry a shift of the interpolated geometry
        else:
            view = inuse.par if inuse.plain(inuse.theta) else inuse.kin.geometry_view(inuse.theta)
            obs = analyse(view, fit.q, inuse.theta[:g], opts.a, opts.tolerance)
            basis = obs.basis
        sol = JointProblem(inuse.par, fit.q, fit.R, fit.p, ctx, inuse.theta[:g], basis, inuse.effects, w_rot,
                           inuse=inuse).solve()
        inuse, base_effects = inuse.with_theta(sol.theta, ()), sol.effects
        base_name = "+".join([_base_name(model)] + [e.kind for e in base_effects])
    par = inuse.par
    theta_base = inuse.theta
    x_base = theta_base[: par.size]

    def theta_at(x: np.ndarray) -> np.ndarray:
        th = theta_base.copy()
        th[: par.size] = x
        return th
    geo = inuse.geometry(theta_base)
    baseline, before_dp = _accuracy(base_name, inuse, theta_base, base_effects, heldout, ctx_ho)

    # 2. Where the mismatch is.
    R, p = inuse.pose(fit.q, base_effects, ctx, theta_base)
    r0, _ = weighted_residuals(fit.R, fit.p, R, p, w_rot)
    drv = drivers(geo, fit.q, ctx, gravity)
    mismatch = locate_mismatch(r0, drv)

    # 3. Candidates, with what the geometry absorbs projected out.
    def signature(e: Effect, q: np.ndarray, c: Context) -> np.ndarray:
        return inuse.signature(e, q, c, theta_base, w_rot)
    A = np.concatenate([_geometric_columns(inuse, fit.q, theta_base, basis, w_rot)]
                       + [signature(e, fit.q, ctx) for e in base_effects], axis=1)
    present = {e.kind for e in base_effects}
    if inuse.kind in ("pi", "cdc"):  # they carry the tool rotation, the mass-free compliance and the deflection
        present |= {"tool_frame", "joint_compliance", "structural_deflection"}
    cands, untested = library(geo, fit.q, ctx, gravity, tuple(k for k in opts.kinds if k not in present),
                              opts.compliance_form)
    q_ref, ctx_ref = _reference(None if source == "split" else heldout, fit.q, ctx, joint_limits, opts)
    Q = np.linalg.qr(A)[0]

    def sig_offset(j: int) -> np.ndarray:
        return signature(JointOffset((j,), np.zeros(1)), fit.q, ctx)
    pool, hidden, bases = [], [], {}
    for c in cands:
        S = signature(c.effect, fit.q, ctx)
        # An effect on one joint's angle is identifiable only beyond its mean over the data, which is a joint
        # offset (a compliance whose torque barely varies is an offset, not a compliance). Once identified a gear
        # error carries that mean itself, so it is not reported as a gear error plus an offset.
        # Its variation on the data is measured against its variation over the reference workspace.
        S_ref = signature(c.effect, q_ref, ctx_ref)
        Qc, S_ref_varying = Q, S_ref
        if c.kind in ONE_JOINT_KINDS and len(c.joints) == 1:
            Qc = np.linalg.qr(np.concatenate([A, sig_offset(c.joints[0])], axis=1))[0]
            off = signature(JointOffset(c.joints, np.zeros(1)), q_ref, ctx_ref)
            S_ref_varying = S_ref - off @ np.linalg.lstsq(off, S_ref, rcond=None)[0]
        vis, exc, B = visibility(S, Qc, S_ref_varying, len(fit), q_ref.shape[0], opts.selection.visible_min)
        if vis < opts.selection.visible_min:
            hidden.append(explain.not_identifiable(c, vis, exc, fit.q, q_ref))
        else:
            if c.kind == "gear_transmission":
                B = visibility(S, Q, S_ref, len(fit), q_ref.shape[0], opts.selection.visible_min)[2]
            bases[c.key()] = B
            pool.append((c, S @ B))
    problem = LinearSelection(A, r0, groups, opts.selection)

    def sig(e: Effect) -> np.ndarray:
        return signature(e, fit.q, ctx)

    pool = tune_warmup(pool, lambda e: problem.rss([], sig(e)), sig)
    pool = [(c, problem.add(S)) for c, S in pool]
    hidden = dedupe(hidden, {c.label for c, _ in pool})
    log.info("diagnose: %d candidates testable, %d not identifiable, %d untested", len(pool), len(hidden), len(untested))

    # 4. Selection.
    def refine(c: Candidate, S: np.ndarray, chosen_S: list[np.ndarray]) -> tuple[Candidate, np.ndarray]:
        e = c.effect
        if c.kind != "thermal_drift" or getattr(e, "mode", "") != "warmup" or c.extra_dof == 0:
            return c, S
        cost = lambda lt: problem.rss(chosen_S, sig(e.__class__(e.links, e.values, "warmup", float(np.exp(lt)))))  # type: ignore[attr-defined]  # noqa: E731
        lt0 = np.log(e.tau_s)  # type: ignore[attr-defined]
        res = minimize_scalar(cost, bounds=(lt0 - 1.2, lt0 + 1.2), method="bounded", options={"xatol": 1e-3})
        e2 = ThermalDrift(e.links, e.values, "warmup", float(np.exp(res.x)))  # type: ignore[attr-defined]
        return Candidate(c.kind, c.label, c.joints, e2, c.extra_dof), problem.add(sig(e2))

    def rebuild(c: Candidate, S: np.ndarray, chosen: list[Candidate]) -> tuple[Candidate, np.ndarray] | None:
        if any(o.kind == c.kind and o.label == c.label for o in chosen):
            return None
        if c.kind != "thermal_drift":
            return c, S
        th = [o for o in chosen if o.kind == "thermal_drift"]
        if not th:
            return c, S
        e, t0 = c.effect, th[0].effect
        if e.mode != t0.mode:  # type: ignore[attr-defined]
            return None
        if e.mode == "warmup" and e.tau_s != t0.tau_s:  # type: ignore[attr-defined]
            e = ThermalDrift(e.links, e.values, "warmup", t0.tau_s)  # type: ignore[attr-defined]
            return Candidate(c.kind, c.label, c.joints, e, 0), problem.add(sig(e))
        return Candidate(c.kind, c.label, c.joints, e, 0), S

    steps, step_S = forward_select(problem, pool, refine, rebuild)

    # 5. Joint refit, effects in the order they were first selected; each confirmed on the held-out data.
    kinds_in_order = list(dict.fromkeys(s.candidate.kind for s in steps))
    merged = [merge(k, [s.candidate for s in steps if s.candidate.kind == k], bases) for k in kinds_in_order]
    n_base = sum(e.size for e in base_effects)
    refit_basis = np.eye(par.size) if prior else basis  # with the filter every geometric direction moves, damped

    def joint_fit(chosen: list[tuple[Effect, np.ndarray]], rec: Recording = fit) -> JointFit:
        B = block_diag(np.eye(n_base), *[b for _, b in chosen])
        effects = base_effects + tuple(e for e, _ in chosen)
        c = rec.context()
        weights = filter_prior(inuse, rec.q, c, effects, opts.a, opts.tolerance) if prior else None
        return JointProblem(par, rec.q, rec.R, rec.p, c, x_base, refit_basis, effects, w_rot, B if B.size else None,
                            inuse=inuse, prior_weight=weights).solve()

    kept: list[tuple[Effect, np.ndarray]] = []
    kept_kinds: list[str] = []
    final_fit = joint_fit([])
    cur_acc, cur_dp = baseline, before_dp
    effects_out, rejected = [], []
    for kind, (e0, B) in zip(kinds_in_order, merged):
        trial = joint_fit(kept + [(e0, B)])
        acc, dp = _accuracy("+".join([base_name] + kept_kinds + [kind]), inuse, theta_at(trial.x), trial.effects,
                            heldout, ctx_ho)
        mine = [j for j, st in enumerate(steps) if st.candidate.kind == kind]
        others = [j for j, st in enumerate(steps) if st.candidate.kind in kept_kinds]
        ev = problem.compare([step_S[j] for j in others], sum(steps[j].candidate.extra_dof for j in others),
                             [step_S[j] for j in mine], sum(steps[j].candidate.extra_dof for j in mine))
        z_ho = _paired_z(cur_dp**2 - dp**2)
        evidence = Evidence(ev["delta_bic"], ev["f_pvalue"], steps[mine[0]].cv_z, cur_acc, acc, z_ho)
        item = explain.found(trial.effects[-1], trial.effect_std[-1], evidence)
        fit_ok = ev["delta_bic"] < opts.selection.bic_threshold and ev["f_pvalue"] < opts.selection.f_alpha
        if fit_ok and z_ho > opts.selection.z_min and acc.rms_mm < cur_acc.rms_mm:
            kept.append((e0, B))
            kept_kinds.append(kind)
            effects_out.append(item)
            final_fit, cur_acc, cur_dp = trial, acc, dp
        else:
            rejected.append(item)
    # Parameters and uncertainties of the kept effects from the final joint fit.
    effects_out = [explain.found(final_fit.effects[len(base_effects) + i], final_fit.effect_std[len(base_effects) + i],
                                 item.evidence) for i, item in enumerate(effects_out)]

    # 6. Noise floor, verdict.
    R, p = inuse.pose(fit.q, final_fit.effects, ctx, theta_at(final_fit.x))
    r_final, _ = weighted_residuals(fit.R, fit.p, R, p, w_rot)
    noise = noise_floor(r_final, groups, final_fit.n_parameters)
    saved, saved_on, all_note = final_fit, fit, ""
    if source == "split":  # the set-aside clusters chose the effects; the saved model learns from them too
        saved, saved_on = joint_fit(kept, everything), everything
        all_note = (f"The saved model is refitted on all {len(everything)} samples (the {len(fit)} fit samples and "
                    f"the {len(heldout)} set-aside ones); the held-out figures are those of the fit on {len(fit)}.")
    physics, refit_note = result_model(robot, inuse, model, theta_at(saved.x), saved.effects, refit_basis.shape[1],
                                       {"baseline": base_name, "fit_samples": len(saved_on), "effects_found": kept_kinds})
    notes = tuple(n for n in [obs.summary(damped=prior) if obs is not None else "", refit_note, all_note] if n)
    verdict = explain.verdict(effects_out, baseline, cur_acc, noise.floor_mm, hidden, untested, rejected)
    return Diagnosis(robot, len(fit), len(heldout), source, noise, baseline, cur_acc, tuple(mismatch),
                     tuple(effects_out), tuple(hidden), tuple(untested), verdict, physics, notes,
                     PlotData(np.linalg.norm(r0[:, :3], axis=1), tuple(drv), before_dp, cur_dp), tuple(rejected))


def _base_name(model: KinematicModel) -> str:
    return {"constant": "geometric", "physics": "geometric", "pi": "pi"}.get(model.kind, f"{model.kind}-{model.method}")


def _paired_z(d: np.ndarray) -> float:
    """z-score of the mean of paired differences (positive: the second model is better)."""
    if d.size < 2 or d.std(ddof=1) == 0:
        return 0.0
    return float(d.mean() / (d.std(ddof=1) / np.sqrt(d.size)))
