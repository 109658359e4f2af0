"""Forward selection of candidate effects with held-out evidence, an information criterion and nested tests.

Selection works on the residual of the model in use linearised around its fit, ``r0 ~ A z + S theta``
(``A``: geometric columns, ``S``: candidate signatures), so each candidate costs one linear least squares.
A candidate joins only if all three hold (:meth:`Evidence.accepted`, the one acceptance rule: the backward
confirmation below applies its fit-data part, the diagnosis's confirmation on the held-out data all of it):

1. the BIC on all fit data drops by more than ``-bic_threshold``;
2. the nested F-test against the current set rejects at ``f_alpha``;
3. the held-out residual improves beyond noise: with blocked cross-validation (contiguous runs of clusters,
   so neither a cluster nor a stretch of time is split between fit and check) the per-cluster drop of the
   held-out squared error has a z-score above ``z_min``, or above ``z_extend`` for one more joint or link of a
   kind already selected (the physics is established; the question left is where it acts).

After the forward pass each selected kind is confirmed by the nested tests (1 and 2) of the final set against
the final set without it; a kind that fails is dropped. Warm-up thermal candidates have their time constant
refined here, against the columns already chosen (:func:`refine_warmup`).
"""

from __future__ import annotations

from collections.abc import Callable, Collection
from dataclasses import dataclass
from typing import cast

import numpy as np
from scipy import special

from calibration.diagnosis.candidates import Candidate
from calibration.kinematics.arrays import FloatArray
from calibration.physics.base import Effect
from calibration.physics.thermal import ThermalDrift


@dataclass(frozen=True)
class SelectionOptions:
    """Thresholds of the selection.

    Attributes:
        bic_threshold: a candidate must change the BIC by less than this (negative).
        f_alpha: significance level of the nested F-test.
        z_min: minimum z-score of the held-out improvement (one-sided).
        z_extend: minimum z-score for one more joint or link of a kind already selected.
        folds: cross-validation folds.
        visible_min: candidates whose visible fraction (see :func:`candidates.visibility`) is below this are
            not identifiable from the data.
        max_steps: at most this many candidates are added.
        fallback_kinds: generic kinds (many parameters, able to mimic specific physics: the structural
            deflection takes up joint compliance and first gear harmonics of joints 2-3) that are tried only
            when no other candidate passes, so a specific effect keeps its name.
    """

    bic_threshold: float = -10.0
    f_alpha: float = 1e-3
    z_min: float = 3.0
    z_extend: float = 2.0
    folds: int = 5
    visible_min: float = 0.05
    max_steps: int = 12
    fallback_kinds: tuple[str, ...] = ("structural_deflection",)


@dataclass(frozen=True)
class Evidence:
    """What the acceptance rule reads about adding effects to a model (:meth:`accepted` is the rule).

    Attributes:
        delta_bic: BIC with the effects minus without them, on the fit data.
        f_pvalue: p-value of the nested F-test of the same comparison.
        heldout_z: z-score of the improvement on data the fit did not see (cross-validated during the
            selection; the held-out recording in the diagnosis's confirmation); None judges the fit data alone
            (the backward confirmation of the selection).
        rms_mm_before, rms_mm_after: position RMS on that unseen data without and with the effects [mm].
        loss_before, loss_after: mean squared error of both channels on that unseen data, each weighed by its
            noise (the residual's own units, mm^2), without and with the effects; when given, the rule reads
            them instead of the position RMS, so an effect seen mainly in the orientation can be confirmed.
    """

    delta_bic: float
    f_pvalue: float
    heldout_z: float | None = None
    rms_mm_before: float = float("nan")
    rms_mm_after: float = float("nan")
    loss_before: float = float("nan")
    loss_after: float = float("nan")

    def accepted(self, options: SelectionOptions, extends: bool = False) -> bool:
        """The one acceptance rule: the BIC drops by more than ``-bic_threshold``, the F-test rejects at
        ``f_alpha`` and, unless only the fit data are judged, the unseen data improve: ``heldout_z`` above
        ``z_min`` (``z_extend`` when ``extends``: one more joint or link of a kind already selected) and a lower
        weighed loss of both channels (the position RMS when no loss is given)."""
        fits = self.delta_bic < options.bic_threshold and self.f_pvalue < options.f_alpha
        if self.heldout_z is None or not fits:
            return fits
        if np.isfinite(self.loss_before) and np.isfinite(self.loss_after):
            lower = self.loss_after < self.loss_before
        else:
            lower = self.rms_mm_after < self.rms_mm_before
        return self.heldout_z > (options.z_extend if extends else options.z_min) and lower


#: Kinds that are another kind's physics under another load: the compliance under the payload is the joints' own-weight
#: compliance carrying the payload's torque. Once the other kind is established, such a kind only asks where it acts
#: and how strongly, so it is held to ``z_extend`` like one more joint of a kind already selected.
SAME_PHYSICS = {"payload_compliance": "joint_compliance"}


def extends(kind: str, established: Collection[str]) -> bool:
    """Whether ``kind`` extends physics already ``established`` (the same kind, or :data:`SAME_PHYSICS`)."""
    return kind in established or SAME_PHYSICS.get(kind) in established


@dataclass(frozen=True)
class Step:
    """One accepted candidate with the evidence that admitted it.

    Attributes:
        candidate: the candidate (settings refined, e.g. the warm-up time constant).
        evidence: its evidence against the steps before it (``heldout_z``: cross-validated; the RMS
            cross-validated position RMS [mm]).
    """

    candidate: Candidate
    evidence: Evidence


@dataclass(frozen=True)
class Selection:
    """The accepted steps in order and the column indices of each in the :class:`LinearSelection`."""

    steps: tuple[Step, ...] = ()
    columns: tuple[np.ndarray, ...] = ()

    def kinds(self) -> list[str]:
        """The selected kinds in the order they were first selected."""
        return list(dict.fromkeys(s.candidate.kind for s in self.steps))

    def of_kind(self, kind: str) -> list[Candidate]:
        return [s.candidate for s in self.steps if s.candidate.kind == kind]

    def without(self, kind: str) -> Selection:
        keep = [i for i, s in enumerate(self.steps) if s.candidate.kind != kind]
        return Selection(tuple(self.steps[i] for i in keep), tuple(self.columns[i] for i in keep))

    def fit_evidence(self, problem: LinearSelection, kind: str, given: Collection[str]) -> Evidence:
        """Nested tests on the fit data of adding the steps of ``kind`` to the steps of the kinds ``given``."""
        base = [i for i, s in enumerate(self.steps) if s.candidate.kind in given]
        extra = [i for i, s in enumerate(self.steps) if s.candidate.kind == kind]
        return problem.fit_evidence([self.columns[i] for i in base], sum(self.steps[i].candidate.extra_dof for i in base),
                                    [self.columns[i] for i in extra],
                                    sum(self.steps[i].candidate.extra_dof for i in extra))

def blocked_folds(groups: np.ndarray, k: int, blocks_per_fold: int = 4) -> np.ndarray:
    """Fold index (N,) of every sample: contiguous runs of clusters (in recording order) dealt round robin."""
    _, first = np.unique(groups, return_index=True)
    order = np.unique(groups)[np.argsort(first)]
    n_blocks = max(k, min(len(order), k * blocks_per_fold))
    block_of = {g: min(i * n_blocks // len(order), n_blocks - 1) for i, g in enumerate(order)}
    return np.array([block_of[g] % k for g in groups])


class LinearSelection:
    """The linearised selection problem, built once; every model is a set of column indices.

    All fits work on Gram matrices accumulated per cluster (columns normalised to unit norm), so a
    candidate's fit, its cross-validation and its per-cluster held-out errors cost a few small solves.

    Args:
        A: baseline columns (geometry, and effects already in the model), shape (6N, k).
        r0: baseline weighted residual, shape (N, 6).
        groups: cluster id per sample (N,).
        options: thresholds.
    """

    def __init__(self, A: np.ndarray, r0: np.ndarray, groups: np.ndarray, options: SelectionOptions) -> None:
        self.options = options
        r0 = np.asarray(r0, dtype=float)
        self.N = r0.shape[0]
        self.n_res = r0.size
        self.order = np.argsort(np.asarray(groups), kind="stable")
        g = np.asarray(groups)[self.order]
        _, starts, counts = np.unique(g, return_index=True, return_counts=True)
        self.bounds = list(zip(starts, starts + counts))
        fold = blocked_folds(np.asarray(groups), options.folds)[self.order]
        self.cluster_fold = fold[starts]
        self.r = r0[self.order]
        self.rr = np.array([np.sum(self.r[a:b] ** 2) for a, b in self.bounds])
        self.rr_pos = np.array([np.sum(self.r[a:b, :3] ** 2) for a, b in self.bounds])
        self.Z = np.zeros((self.N, 6, 0))
        C = len(self.bounds)
        self.G, self.Gp = np.zeros((C, 0, 0)), np.zeros((C, 0, 0))
        self.z, self.zp = np.zeros((C, 0)), np.zeros((C, 0))
        self.base = self.add(A)

    def add(self, S: np.ndarray) -> np.ndarray:
        """Add columns (6N, m) (normalised to unit norm); returns their indices."""
        if np.asarray(S).shape[-1] == 0:
            return np.zeros(0, dtype=int)
        S = np.asarray(S, dtype=float).reshape(self.N, 6, -1)[self.order]
        S = S / np.maximum(np.sqrt(np.sum(S**2, axis=(0, 1))), 1e-300)
        P0, m = self.Z.shape[2], S.shape[2]
        Z = np.concatenate([self.Z, S], axis=2)
        C = len(self.bounds)
        G, Gp = np.zeros((C, P0 + m, P0 + m)), np.zeros((C, P0 + m, P0 + m))
        G[:, :P0, :P0], Gp[:, :P0, :P0] = self.G, self.Gp
        z = np.concatenate([self.z, np.zeros((C, m))], axis=1)
        zp = np.concatenate([self.zp, np.zeros((C, m))], axis=1)
        for c, (a, b) in enumerate(self.bounds):
            Zc, Sc = Z[a:b], S[a:b]
            nc = b - a
            cross = Zc.reshape(nc * 6, P0 + m).T @ Sc.reshape(nc * 6, m)
            crossp = Zc[:, :3].reshape(nc * 3, P0 + m).T @ Sc[:, :3].reshape(nc * 3, m)
            G[c, :, P0:], G[c, P0:, :] = cross, cross.T
            Gp[c, :, P0:], Gp[c, P0:, :] = crossp, crossp.T
            z[c, P0:] = Sc.reshape(-1, m).T @ self.r[a:b].ravel()
            zp[c, P0:] = Sc[:, :3].reshape(-1, m).T @ self.r[a:b, :3].ravel()
        self.Z, self.G, self.Gp, self.z, self.zp = Z, G, Gp, z, zp
        return np.arange(P0, P0 + m)

    @staticmethod
    def _solve(G: np.ndarray, b: np.ndarray) -> np.ndarray:
        try:
            return np.linalg.solve(G + 1e-12 * np.eye(len(b)), b)
        except np.linalg.LinAlgError:
            solution: FloatArray = np.linalg.lstsq(G, b, rcond=None)[0]
            return solution

    def _idx(self, sets: list[np.ndarray]) -> np.ndarray:
        return np.concatenate([self.base] + list(sets)).astype(int)

    def rss(self, sets: list[np.ndarray], extra: np.ndarray | None = None) -> float:
        """Residual sum of squares on all fit data after fitting the baseline, ``sets`` of columns and
        optionally temporary columns ``extra`` (6N, m) that are not added."""
        idx = self._idx(sets)
        G = self.G[:, idx][:, :, idx].sum(axis=0)
        z = self.z[:, idx].sum(axis=0)
        if extra is not None:
            X = self.Z[:, :, idx].reshape(self.N * 6, idx.size)
            S = np.asarray(extra, dtype=float).reshape(self.N, 6, -1)[self.order].reshape(-1, extra.shape[-1])
            S = S / np.maximum(np.linalg.norm(S, axis=0), 1e-300)
            G = np.block([[G, X.T @ S], [S.T @ X, S.T @ S]])
            z = np.concatenate([z, S.T @ self.r.ravel()])
        beta = self._solve(G, z)
        return float(max(self.rr.sum() - 2 * beta @ z + beta @ G @ beta, 1e-300))

    def cv(self, sets: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """Cross-validated squared residual per cluster, all components and position only, each (C,)."""
        idx = self._idx(sets)
        G, Gp = self.G[:, idx][:, :, idx], self.Gp[:, idx][:, :, idx]
        z, zp = self.z[:, idx], self.zp[:, idx]
        Gt, zt = G.sum(axis=0), z.sum(axis=0)
        ss, ssp = self.rr.copy(), self.rr_pos.copy()
        for f in range(self.options.folds):
            m = self.cluster_fold == f
            if not m.any():
                continue
            beta = self._solve(Gt - G[m].sum(axis=0), zt - z[m].sum(axis=0))
            ss[m] += -2 * z[m] @ beta + np.einsum("i,cij,j->c", beta, G[m], beta)
            ssp[m] += -2 * zp[m] @ beta + np.einsum("i,cij,j->c", beta, Gp[m], beta)
        return ss, ssp

    def bic(self, rss: float, p: int) -> float:
        bic: float = self.n_res * np.log(rss / self.n_res) + p * np.log(self.n_res)
        return bic

    def fit_evidence(self, base: list[np.ndarray], base_dof: int, extra: list[np.ndarray], extra_dof: int
                     ) -> Evidence:
        """Evidence of the fit data for adding column sets ``extra`` to ``base``: BIC change and F-test p-value
        (``*_dof``: settings chosen from the data, counted as parameters)."""
        rss0, rss1 = self.rss(base), self.rss(base + extra)
        m = int(sum(len(e) for e in extra))
        p0 = self.base.size + sum(len(b) for b in base) + base_dof
        p1 = p0 + m + extra_dof
        d_bic = self.bic(rss1, p1) - self.bic(rss0, p0)
        dof2 = self.n_res - p1
        F = ((rss0 - rss1) / max(m, 1)) / max(rss1 / dof2, 1e-300)
        pval = float(special.fdtrc(max(m, 1), dof2, F))  # F survival function if rss1 < rss0 else 1.0
        return Evidence(float(d_bic), pval)

    def compare(self, base: list[np.ndarray], base_dof: int, extra: list[np.ndarray], extra_dof: int,
                cv_base: tuple[np.ndarray, np.ndarray] | None = None) -> Evidence:
        """:meth:`fit_evidence` plus the cross-validated evidence: z-score of the per-cluster drop of the
        held-out squared error, and the cross-validated position RMS [mm] before and after."""
        fit = self.fit_evidence(base, base_dof, extra, extra_dof)
        ss0, ssp0 = self.cv(base) if cv_base is None else cv_base
        ss1, ssp1 = self.cv(base + extra)
        d = ss0 - ss1
        se = d.std(ddof=1) / np.sqrt(d.size) if d.size > 1 else np.inf
        z = float(d.mean() / se) if se > 0 else 0.0
        return Evidence(fit.delta_bic, fit.f_pvalue, z, float(np.sqrt(ssp0.sum() / self.N)),
                        float(np.sqrt(ssp1.sum() / self.N)), float(ss0.sum() / self.N), float(ss1.sum() / self.N))


#: The first-order residual signature (6N, m) of an effect on the fit data.
Signature = Callable[[Effect], np.ndarray]


def refine_warmup(effect: ThermalDrift, problem: LinearSelection, sets: list[np.ndarray], signature: Signature
                  ) -> ThermalDrift:
    """The warm-up effect with the time constant, within a factor ``e^1.2`` of its own, that fits best with the
    column sets ``sets``."""
    from scipy.optimize import (
        minimize_scalar,  # here: scipy.optimize costs ~0.3 s to import, and only this kind needs it
    )

    lt0 = np.log(effect.tau_s)
    res = minimize_scalar(_warmup_rss, bounds=(lt0 - 1.2, lt0 + 1.2), args=(effect, problem, sets, signature),
                          method="bounded", options={"xatol": 1e-3})
    return _with_tau(effect, float(np.exp(res.x)))


def _with_tau(effect: ThermalDrift, tau_s: float) -> ThermalDrift:
    return ThermalDrift(effect.links, effect.values, "warmup", tau_s)


def _warmup_rss(log_tau: float, effect: ThermalDrift, problem: LinearSelection, sets: list[np.ndarray],
                signature: Signature) -> float:
    return problem.rss(sets, signature(_with_tau(effect, float(np.exp(log_tau)))))


def _is_warmup(c: Candidate) -> bool:
    return c.kind == "thermal_drift" and getattr(c.effect, "mode", "") == "warmup"


def tune_warmup(pool: list[tuple[Candidate, np.ndarray]], problem: LinearSelection, signature: Signature
                ) -> list[tuple[Candidate, np.ndarray]]:
    """One warm-up thermal candidate per link, its time constant refined from the best of the grid; the
    other candidates first, in order."""
    out: list[tuple[Candidate, np.ndarray]] = []
    best: dict[str, tuple[float, Candidate]] = {}
    for c, S in pool:
        if _is_warmup(c):
            cost = problem.rss([], signature(c.effect))
            if c.label not in best or cost < best[c.label][0]:
                best[c.label] = (cost, c)
        else:
            out.append((c, S))
    for _, c in best.values():
        e = refine_warmup(cast(ThermalDrift, c.effect), problem, [], signature)  # _is_warmup: a thermal drift
        out.append((Candidate(c.kind, c.label, c.joints, e, c.extra_dof), signature(e)))
    return out


def forward_select(problem: LinearSelection, pool: list[tuple[Candidate, np.ndarray]], signature: Signature,
                   flexible: dict[str, np.ndarray] | None = None,
                   flexible_joints: dict[str, tuple[int, ...]] | None = None) -> Selection:
    """Greedy forward selection (fallback kinds only when nothing else passes), then backward confirmation
    per kind.

    Args:
        problem: the linearised problem.
        pool: identifiable candidates with the indices of their columns in ``problem``.
        signature: an effect's signature on the fit data (columns for refined warm-up candidates).
        flexible: per kind, the column indices (in ``problem``) of its most flexible form (``joint_compliance``:
            the lumped form of joints 2-3, whose gravity shape is the data's rather than the robot YAML's). Once a
            kind with a flexible form is selected, a candidate of another kind joins (and stays) only if it is
            accepted on top of that flexible form too: a shape the named kind's flexible form explains is not a
            second kind.
        flexible_joints: per kind, the joints its flexible form acts on: a candidate of that kind on other joints
            (a YAML-shaped compliance of joint 5) is held to the same test.

    Returns:
        The accepted steps in order and their column indices.
    """
    flexible = flexible or {}
    steps: list[Step] = []
    columns: list[np.ndarray] = []
    while pool and len(steps) < problem.options.max_steps:
        dof = sum(s.candidate.extra_dof for s in steps)
        found_kinds = {s.candidate.kind for s in steps}
        cv_base = problem.cv(columns)
        geometry = [S for c, S in pool if c.kind in GEOMETRIC_KINDS]
        shape = _shape_check(problem, columns, dof, found_kinds, flexible, flexible_joints or {}, geometry)
        best = _best(problem, pool, columns, dof, found_kinds, cv_base, shape)
        if best is None:
            break
        cand, S = _refine(problem, signature, best[0], best[1], columns)
        ev = problem.compare(columns, dof, [S], cand.extra_dof, cv_base)
        if not ev.accepted(problem.options, extends(cand.kind, found_kinds)):
            cand, S, ev = best
        steps.append(Step(cand, ev))
        columns.append(S)
        pool = _rebuild_pool(problem, signature, pool, [s.candidate for s in steps])
    return _confirm(problem, Selection(tuple(steps), tuple(columns)), flexible)


#: ``(candidate, columns) -> accepted``: whether a candidate is accepted beyond the flexible forms of the kinds
#: already selected (always True when none has one).
ShapeCheck = Callable[[Candidate, np.ndarray], bool]


#: Kinds that are geometric parameters by another name (a joint's zero, the tool marker's registration).
GEOMETRIC_KINDS = ("joint_offset", "tool_frame")


def _shape_check(problem: LinearSelection, columns: list[np.ndarray], dof: int, found_kinds: set[str],
                 flexible: dict[str, np.ndarray], flexible_joints: dict[str, tuple[int, ...]],
                 geometry: list[np.ndarray] | None = None) -> ShapeCheck:
    """The test a candidate of another kind (or of that kind on other joints) passes on top of the flexible forms of
    the selected kinds, and a candidate of a non-geometric kind on top of the geometric candidates not yet selected
    (``geometry``: a tool marker's registration the model has not yet taken up is not a gear error of joint 2, which
    took its place on the family's switching-payload twins)."""
    flex = [flexible[k] for k in sorted(found_kinds) if k in flexible]
    geometry = geometry or []
    if not flex and not geometry:
        return lambda cand, S: True
    cv_flex: list[tuple[np.ndarray, np.ndarray]] = []

    def check(cand: Candidate, S: np.ndarray) -> bool:
        if cand.kind in GEOMETRIC_KINDS:
            return True
        if cand.kind in flexible and set(cand.joints) <= set(flexible_joints.get(cand.kind, cand.joints)):
            return True
        if not cv_flex:
            cv_flex.append(problem.cv(columns + flex + geometry))
        ev = problem.compare(columns + flex + geometry, dof, [S], cand.extra_dof, cv_flex[0])
        return ev.accepted(problem.options, extends(cand.kind, found_kinds))

    return check


def _best(problem: LinearSelection, pool: list[tuple[Candidate, np.ndarray]], columns: list[np.ndarray], dof: int,
          found_kinds: set[str], cv_base: tuple[np.ndarray, np.ndarray], shape: ShapeCheck | None = None
          ) -> tuple[Candidate, np.ndarray, Evidence] | None:
    """The accepted candidate with the lowest BIC; fallback kinds only when no other is accepted. ``shape``: the
    further test beyond the flexible forms of the selected kinds (:func:`_shape_check`)."""
    best = None
    for tier in (False, True):
        for cand, S in pool:
            if (cand.kind in problem.options.fallback_kinds) != tier:
                continue
            ev = problem.compare(columns, dof, [S], cand.extra_dof, cv_base)
            if (ev.accepted(problem.options, extends(cand.kind, found_kinds))
                    and (best is None or ev.delta_bic < best[2].delta_bic)
                    and (shape is None or shape(cand, S))):
                best = (cand, S, ev)
        if best is not None:
            break
    return best


def _refine(problem: LinearSelection, signature: Signature, c: Candidate, S: np.ndarray, columns: list[np.ndarray]
            ) -> tuple[Candidate, np.ndarray]:
    """A winning warm-up candidate with its time constant refined given the chosen columns (new columns)."""
    if not _is_warmup(c) or c.extra_dof == 0:
        return c, S
    e = refine_warmup(cast(ThermalDrift, c.effect), problem, columns, signature)  # _is_warmup: a thermal drift
    return Candidate(c.kind, c.label, c.joints, e, c.extra_dof), problem.add(signature(e))


def _rebuild(problem: LinearSelection, signature: Signature, c: Candidate, S: np.ndarray, chosen: list[Candidate]
             ) -> tuple[Candidate, np.ndarray] | None:
    """A pool entry in its version compatible with the chosen candidates (thermal: the chosen mode and time
    constant), or None when it can no longer join."""
    if any(o.kind == c.kind and (o.label == c.label or set(o.joints) & set(c.joints)) for o in chosen):
        return None  # chosen already, or on a joint a chosen candidate of its kind acts on
    if c.kind != "thermal_drift":
        return c, S
    th = [o for o in chosen if o.kind == "thermal_drift"]
    if not th:
        return c, S
    e, t0 = cast(ThermalDrift, c.effect), cast(ThermalDrift, th[0].effect)  # both of kind thermal_drift
    if e.mode != t0.mode:
        return None
    if e.mode == "warmup" and e.tau_s != t0.tau_s:
        e = _with_tau(e, t0.tau_s)
        return Candidate(c.kind, c.label, c.joints, e, 0), problem.add(signature(e))
    return Candidate(c.kind, c.label, c.joints, e, 0), S


def _rebuild_pool(problem: LinearSelection, signature: Signature, pool: list[tuple[Candidate, np.ndarray]],
                  chosen: list[Candidate]) -> list[tuple[Candidate, np.ndarray]]:
    new_pool, seen = [], set()
    for c, s in pool:
        r = _rebuild(problem, signature, c, s, chosen)
        if r is not None and r[0].key() not in seen:
            seen.add(r[0].key())
            new_pool.append(r)
    return _as_joint_sets(new_pool, chosen)


def _as_joint_sets(pool: list[tuple[Candidate, np.ndarray]], chosen: list[Candidate]
                   ) -> list[tuple[Candidate, np.ndarray]]:
    """Once the own-weight compliance of some joints is established, a kind of the same physics under another load
    (:data:`SAME_PHYSICS`: the payload's deflection is those joints' compliance carrying the payload's torque) is
    tested on those joints as one set: a candidate of it on a subset of them gives way to the pool's largest candidate
    within them. One joint alone would otherwise win on the BIC's parameter count whenever the other joint's share of
    the payload's deflection is small (the elbow's beside the shoulder's), and the set would never be tested."""
    out = []
    for c, S in pool:
        base = SAME_PHYSICS.get(c.kind)
        compliant = {j for o in chosen if o.kind == base for j in o.joints}
        inside = set(c.joints) <= compliant
        larger = any(o.kind == c.kind and set(c.joints) < set(o.joints) <= compliant for o, _ in pool)
        if base is None or not inside or not larger:
            out.append((c, S))
    return out


def _confirm(problem: LinearSelection, sel: Selection, flexible: dict[str, np.ndarray] | None = None) -> Selection:
    """Drop, weakest first, every kind whose removal from the final set the nested tests do not reject; a kind is
    judged with the flexible forms of the other kinds in the set (``flexible``, see :func:`forward_select`)."""
    flexible = flexible or {}
    while sel.steps:
        worst = None
        kinds = {s.candidate.kind for s in sel.steps}
        for kind in kinds:
            flex = [flexible[k] for k in sorted(kinds) if k in flexible and k != kind]
            ev = _removal_evidence(problem, sel, kind, kinds - {kind}, flex)
            if not ev.accepted(problem.options) and (worst is None or ev.delta_bic > worst[1]):
                worst = (kind, ev.delta_bic)
        if worst is None:
            break
        sel = sel.without(worst[0])
    return sel


def _removal_evidence(problem: LinearSelection, sel: Selection, kind: str, given: Collection[str],
                      flex: list[np.ndarray]) -> Evidence:
    """Nested tests on the fit data of adding the steps of ``kind`` to those of ``given`` and the columns ``flex``."""
    if not flex:
        return sel.fit_evidence(problem, kind, given)
    base = [i for i, s in enumerate(sel.steps) if s.candidate.kind in given]
    extra = [i for i, s in enumerate(sel.steps) if s.candidate.kind == kind]
    return problem.fit_evidence([sel.columns[i] for i in base] + flex,
                                sum(sel.steps[i].candidate.extra_dof for i in base),
                                [sel.columns[i] for i in extra], sum(sel.steps[i].candidate.extra_dof for i in extra))
