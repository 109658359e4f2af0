"""Forward selection of candidate effects with held-out evidence, an information criterion and nested tests.

Selection works on the residual of the model in use linearised around its fit, ``r0 ~ A z + S theta``
(``A``: geometric columns, ``S``: candidate signatures), so each candidate costs one linear least squares.
A candidate joins only if all three hold:

1. the BIC on all fit data drops by more than ``-bic_threshold``;
2. the nested F-test against the current set rejects at ``f_alpha``;
3. the held-out residual improves beyond noise: with blocked cross-validation (contiguous runs of clusters,
   so neither a cluster nor a stretch of time is split between fit and check) the per-cluster drop of the
   held-out squared error has a z-score above ``z_min``, or above ``z_extend`` for one more joint or link of a
   kind already selected (the physics is established; the question left is where it acts).

After the forward pass each selected kind is confirmed by the nested test of the final set against the
final set without it; a kind that fails is dropped.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy import stats

from calibration.diagnosis.candidates import Candidate


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
class Step:
    """One accepted candidate with the evidence that admitted it.

    Attributes:
        candidate: the candidate (settings refined, e.g. the warm-up time constant).
        delta_bic: BIC change on the fit data.
        f_pvalue: nested F-test p-value.
        cv_rms_mm_before, cv_rms_mm_after: cross-validated position RMS before and after [mm].
        cv_z: z-score of the held-out improvement.
    """

    candidate: Candidate
    delta_bic: float
    f_pvalue: float
    cv_rms_mm_before: float
    cv_rms_mm_after: float
    cv_z: float


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
            return np.linalg.lstsq(G, b, rcond=None)[0]

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
        return self.n_res * np.log(rss / self.n_res) + p * np.log(self.n_res)

    def compare(self, base: list[np.ndarray], base_dof: int, extra: list[np.ndarray], extra_dof: int,
                cv_base: tuple[np.ndarray, np.ndarray] | None = None) -> dict[str, float]:
        """Evidence for adding column sets ``extra`` to ``base``: delta_bic, f_pvalue, cv RMS [mm], cv_z."""
        rss0, rss1 = self.rss(base), self.rss(base + extra)
        m = int(sum(len(e) for e in extra))
        p0 = self.base.size + sum(len(b) for b in base) + base_dof
        p1 = p0 + m + extra_dof
        d_bic = self.bic(rss1, p1) - self.bic(rss0, p0)
        dof2 = self.n_res - p1
        F = ((rss0 - rss1) / max(m, 1)) / max(rss1 / dof2, 1e-300)
        pval = float(stats.f.sf(F, max(m, 1), dof2)) if rss1 < rss0 else 1.0
        ss0, ssp0 = self.cv(base) if cv_base is None else cv_base
        ss1, ssp1 = self.cv(base + extra)
        d = ss0 - ss1
        se = d.std(ddof=1) / np.sqrt(d.size) if d.size > 1 else np.inf
        z = float(d.mean() / se) if se > 0 else 0.0
        return {"delta_bic": float(d_bic), "f_pvalue": pval, "cv_rms_mm_before": float(np.sqrt(ssp0.sum() / self.N)),
                "cv_rms_mm_after": float(np.sqrt(ssp1.sum() / self.N)), "cv_z": z}

    def accepts(self, ev: dict[str, float], extends: bool = False) -> bool:
        """Whether the evidence admits a candidate (``extends``: its kind is already selected)."""
        o = self.options
        return (ev["delta_bic"] < o.bic_threshold and ev["f_pvalue"] < o.f_alpha
                and ev["cv_z"] > (o.z_extend if extends else o.z_min) and ev["cv_rms_mm_after"] < ev["cv_rms_mm_before"])


Refiner = Callable[[Candidate, np.ndarray, list[np.ndarray]], tuple[Candidate, np.ndarray]]
Rebuilder = Callable[[Candidate, np.ndarray, list[Candidate]], "tuple[Candidate, np.ndarray] | None"]


def forward_select(problem: LinearSelection, pool: list[tuple[Candidate, np.ndarray]], refine: Refiner,
                   rebuild: Rebuilder) -> tuple[list[Step], list[np.ndarray]]:
    """Greedy forward selection (fallback kinds only when nothing else passes), then backward confirmation
    per kind.

    Args:
        problem: the linearised problem.
        pool: identifiable candidates with the indices of their columns in ``problem``.
        refine: improves the settings of a winning candidate (a warm-up time constant) given the chosen
            column sets, and returns it with its (new) column indices.
        rebuild: after each acceptance, maps a pool entry to its version compatible with the chosen
            candidates (same settings for one kind), or None when it can no longer join.

    Returns:
        The accepted steps in order and their column indices.
    """
    chosen: list[Candidate] = []
    chosen_S: list[np.ndarray] = []
    steps: list[Step] = []
    while pool and len(steps) < problem.options.max_steps:
        dof = sum(c.extra_dof for c in chosen)
        found_kinds = {c.kind for c in chosen}
        cv_base = problem.cv(chosen_S)
        best = None
        for tier in (False, True):
            for cand, S in pool:
                if (cand.kind in problem.options.fallback_kinds) != tier:
                    continue
                ev = problem.compare(chosen_S, dof, [S], cand.extra_dof, cv_base)
                if problem.accepts(ev, cand.kind in found_kinds) and (best is None or ev["delta_bic"] < best[2]["delta_bic"]):
                    best = (cand, S, ev)
            if best is not None:
                break
        if best is None:
            break
        cand, S = refine(best[0], best[1], chosen_S)
        ev = problem.compare(chosen_S, dof, [S], cand.extra_dof, cv_base)
        if not problem.accepts(ev, cand.kind in found_kinds):
            cand, S, ev = best
        chosen.append(cand)
        chosen_S.append(S)
        steps.append(Step(cand, **ev))
        new_pool, seen = [], set()
        for c, s in pool:
            r = rebuild(c, s, chosen)
            if r is not None and r[0].key() not in seen:
                seen.add(r[0].key())
                new_pool.append(r)
        pool = new_pool
    return _confirm(problem, steps, chosen_S)


def _confirm(problem: LinearSelection, steps: list[Step], sigs: list[np.ndarray]) -> tuple[list[Step], list[np.ndarray]]:
    """Drop, weakest first, every kind whose removal from the final set the nested tests do not reject."""
    while steps:
        worst = None
        for kind in {s.candidate.kind for s in steps}:
            keep = [i for i, s in enumerate(steps) if s.candidate.kind != kind]
            drop = [i for i, s in enumerate(steps) if s.candidate.kind == kind]
            ev = problem.compare([sigs[i] for i in keep], sum(steps[i].candidate.extra_dof for i in keep),
                                 [sigs[i] for i in drop], sum(steps[i].candidate.extra_dof for i in drop))
            if not (ev["delta_bic"] < problem.options.bic_threshold and ev["f_pvalue"] < problem.options.f_alpha):
                if worst is None or ev["delta_bic"] > worst[1]:
                    worst = (kind, ev["delta_bic"])
        if worst is None:
            break
        keep = [i for i, s in enumerate(steps) if s.candidate.kind != worst[0]]
        steps, sigs = [steps[i] for i in keep], [sigs[i] for i in keep]
    return steps, sigs
