"""Optimal experiment design for kinematic identification: which pose clusters to measure.

Criterion: **D-optimality** on the scaled identification Jacobian of the minimal POE parameters
(:class:`~calibration.kinematics.parameterisation.MinimalParameterisation`, flange shift included), evaluated at the
nominal arm, restricted to the parameter directions a rich design can identify at all. A design's information
matrix is ``M = sum_c J_c^T J_c`` over its clusters c (rows: position [mm] and orientation scaled by
``sqrt(2 a)`` as the fits weight them; columns: parameters in millimetres of tool motion, tilts times a reach).
D maximises ``log det M``. Why D rather than E/A or an observability index O1..O5 (Borm & Menq 1991; Sun &
Hollerbach 2008): det M is the inverse volume of the parameters' confidence ellipsoid, so it bounds every
parameter at once, it is invariant to any rescaling or reparameterisation of the identifiable directions
(A- and O3/E-type criteria are not: they change with the units chosen for tilts), it is smooth and concave in the
design weights, and its greedy gain has a closed form (the matrix determinant lemma), which makes greedy and
exchange algorithms exact and fast. O1 (Borm & Menq) is the root-mean of the singular values, i.e. the same
criterion up to the power 1/m; the condition number (O2, E-like) is reported, not optimised, because one bad
direction can hide the rest.

Configuration-dependent (CDC) fits interpolate per-cluster fits over the anchors' (q2, q3), so the anchors must
also spread over that plane; D alone happily stacks clusters where the Jacobian is largest. The selection
maximises the **compound criterion**

    (1/r) log det(M_r + eps I) + lambda * sum_k log min(1, d_k / d_ref)

where ``M_r`` is M in the r identifiable directions, ``d_k`` is the distance in (q2, q3) from the k-th chosen
anchor to the nearest anchor chosen before it, and ``d_ref = sqrt(area / N)`` the spacing N anchors would have
if they tiled the candidates' (q2, q3) box. The first term is the log of the geometric mean eigenvalue
(D-efficiency); the second only penalises anchors closer than the space-filling spacing (a maximin design,
Johnson, Moore & Ylvisaker 1990), by the log of how much closer. Both are log-efficiency ratios, hence
``lambda = 1`` by default: halving the spacing below d_ref costs as much as halving the geometric-mean
information. ``eps`` (``1e-9`` of the candidates' mean information per cluster) keeps the first steps defined.
Checked on training data only (``scripts/benchmarks/bench_design.py --spread-check``: pi on 16 selected clusters of each R1
training recording, scored on the clusters left out): lambda = 1 has a lower mean error than D alone (lambda = 0) on
every day and ties or beats lambda = 3.

Selection is greedy (each step adds the cluster with the largest compound gain; the D gain of every candidate in
one batched ``slogdet``) followed by Fedorov exchange passes (swap a chosen cluster for an unchosen one while the
criterion improves), both exact.

A **rebase design** (:func:`rebase_candidates`) applies the same D criterion to the parameters a rebase refits
(:mod:`calibration.frames.rebase`: the base and tool-marker frames and the joint offsets ``REBASE_OFFSETS``) instead of the
geometry; it needs no spread over (q2, q3) (a rebase interpolates nothing), so it is chosen with ``lambda = 0``.

Predicted parameter uncertainty: ``sigma = noise * sqrt(diag(B (B^T M B)^-1 B^T))`` with B the identifiable
directions, in each parameter's own unit (mm, rad), for a measurement noise ``noise`` [mm, mm-equivalent for
orientation] on every row.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from calibration.data.recording import Recording
from calibration.errors import ModelError
from calibration.identification.geometric import DEFAULT_ORIENTATION_WEIGHT
from calibration.identification.observability import DEFAULT_REACH_MM, DEFAULT_RELATIVE_TOLERANCE, scaled_rows
from calibration.kinematics.arrays import FloatArray
from calibration.kinematics.parameterisation import MinimalParameterisation

#: Relative singular value below which a direction of the reference design counts as not identifiable.
IDENTIFIABLE_TOLERANCE = 1e-6
#: Weight of the space-filling term against the D term (both log-efficiency ratios).
DEFAULT_SPREAD_WEIGHT = 1.0
#: Prior information per direction, as a fraction of the candidates' mean information per cluster.
PRIOR_FRACTION = 1e-9
#: Exchange passes after the greedy selection.
DEFAULT_EXCHANGE_PASSES = 2


@dataclass(frozen=True)
class Candidates:
    """Candidate clusters and their information.

    Attributes:
        info: per cluster, ``J_c^T J_c`` in the identifiable directions, shape (K, r, r).
        anchors: (q2, q3) of each cluster's anchor [rad], shape (K, 2).
        basis: identifiable directions in scaled parameter coordinates, orthonormal columns, shape (m, r).
        scale: parameter units per mm-equivalent, shape (m,).
        names: parameter names.
    """

    info: np.ndarray
    anchors: np.ndarray
    basis: np.ndarray
    scale: np.ndarray
    names: tuple[str, ...]

    def __len__(self) -> int:
        return len(self.info)


@dataclass(frozen=True)
class DesignFigures:
    """What a design predicts about the identification.

    Attributes:
        n_clusters, n_poses: size of the design.
        rank: identifiable directions the design lets the fits see: relative singular value at least the fits'
            truncation tolerance (``DEFAULT_RELATIVE_TOLERANCE``, 1e-2; nls holds the others at their reference).
        n_identifiable: identifiable directions of the reference (rich) design.
        condition_number: of the scaled Jacobian in the identifiable directions (inf when singular).
        log_det: ``(1/r) log det`` of the information in the identifiable directions.
        sigma: predicted standard deviation of each parameter [its unit], shape (m,) (inf where not seen).
        names: parameter names.
        noise_mm: the noise level assumed.
    """

    n_clusters: int
    n_poses: int
    rank: int
    n_identifiable: int
    condition_number: float
    log_det: float
    sigma: np.ndarray
    names: tuple[str, ...]
    noise_mm: float

    def to_json(self) -> dict[str, object]:
        def num(v: float) -> float | None:
            return float(v) if np.isfinite(v) else None

        return {"clusters": self.n_clusters, "poses": self.n_poses, "rank": self.rank,
                "identifiable": self.n_identifiable, "condition_number": num(self.condition_number),
                "log_det_per_direction": num(self.log_det), "noise_mm": self.noise_mm,
                "sigma": {n: num(s) for n, s in zip(self.names, self.sigma)},
                "sigma_units": {n: sigma_unit(n) for n in self.names}}


def sigma_unit(name: str) -> str:
    """The unit of a parameter's ``sigma``: ``rad`` for an angle (a tilt, a frame rotation, a joint offset), ``mm``
    otherwise. The identification names carry it (``tilt1_a_rad``); the rebase directions' names do not
    (``base rotation about x``, ``joint 4 offset``)."""
    return "rad" if name.endswith("_rad") or "rotation" in name or "offset" in name else "mm"


def cluster_rows(par: MinimalParameterisation, q: np.ndarray, a: float = DEFAULT_ORIENTATION_WEIGHT,
                 reach_mm: float = DEFAULT_REACH_MM) -> np.ndarray:
    """Scaled identification Jacobian rows of each pose at the nominal arm, shape (N, 6, m).

    Args:
        par: the minimal parameterisation.
        q: joint angles [rad], shape (N, n).
        a: orientation weight of the fits.
        reach_mm: characteristic reach turning tilts into millimetres.
    """
    _, _, J = par.jacobian(q, np.zeros(par.size))
    return scaled_rows(J, par.scale(reach_mm), a)


def candidates(par: MinimalParameterisation, q: np.ndarray, cluster: np.ndarray, anchors: np.ndarray,
               a: float = DEFAULT_ORIENTATION_WEIGHT, reach_mm: float = DEFAULT_REACH_MM,
               reference_q: np.ndarray | None = None) -> Candidates:
    """The candidate clusters' information in the identifiable directions.

    Args:
        par: the minimal parameterisation.
        q: every candidate pose [rad], shape (N, n).
        cluster: index 0..K-1 of each pose's cluster, shape (N,).
        anchors: (q2, q3) of each cluster's anchor [rad], shape (K, 2).
        a, reach_mm: see :func:`cluster_rows`.
        reference_q: poses whose Jacobian defines the identifiable directions (default: all candidates).
    """
    rows = cluster_rows(par, np.asarray(q, dtype=float), a, reach_mm)
    ref = None if reference_q is None else cluster_rows(par, reference_q, a, reach_mm)
    return candidates_from_rows(rows, cluster, anchors, par.scale(reach_mm), tuple(par.names()), ref)


def candidates_from_rows(rows: np.ndarray, cluster: np.ndarray, anchors: np.ndarray, scale: np.ndarray,
                         names: tuple[str, ...], reference_rows: np.ndarray | None = None) -> Candidates:
    """Candidates from scaled Jacobian rows (N, 6, m) of any parameter set (see :func:`candidates`)."""
    cluster = np.asarray(cluster, dtype=int)
    K = len(anchors)
    if len(rows) != len(cluster) or cluster.min(initial=0) < 0 or cluster.max(initial=-1) >= K:
        raise ModelError(f"design: {len(rows)} poses need {len(rows)} cluster indices in 0..{K - 1}")
    m = rows.shape[-1]
    flat = (rows if reference_rows is None else reference_rows).reshape(-1, m)
    eig, V = np.linalg.eigh(flat.T @ flat)  # ascending; singular values squared
    basis = V[:, eig >= IDENTIFIABLE_TOLERANCE ** 2 * eig[-1]][:, ::-1]
    proj = rows @ basis  # (N, 6, r)
    per_pose = np.matmul(proj.transpose(0, 2, 1), proj)
    info = np.zeros((K, basis.shape[1], basis.shape[1]))
    np.add.at(info, cluster, per_pose)
    return Candidates(info, np.asarray(anchors, dtype=float), basis, np.asarray(scale, dtype=float), tuple(names))


class _Spread:
    """The space-filling term: log min(1, d / d_ref) of each anchor against those chosen before it."""

    def __init__(self, anchors: np.ndarray, budget: int) -> None:
        span = np.ptp(anchors, axis=0)
        area = float(np.prod(np.maximum(span, 1e-9)))
        self.anchors = anchors
        self.d_ref = float(np.sqrt(area / max(budget, 1)))

    def gains(self, chosen: list[int]) -> np.ndarray:
        """The term each candidate would add to ``chosen``, shape (K,) (0 for the first)."""
        if not chosen:
            return np.zeros(len(self.anchors))
        d = np.min(np.linalg.norm(self.anchors[:, None] - self.anchors[chosen][None], axis=2), axis=1)
        gain: FloatArray = np.log(np.clip(d / self.d_ref, 1e-12, 1.0))
        return gain

    def total(self, order: list[int]) -> float:
        """The term summed over ``order`` (each anchor against those before it)."""
        a = self.anchors[order]
        d = np.linalg.norm(a[:, None] - a[None], axis=2)
        d[np.triu_indices(len(order))] = np.inf  # row k: distances to the anchors chosen before k
        nearest = d[1:].min(axis=1)
        return float(np.sum(np.log(np.clip(nearest / self.d_ref, 1e-12, 1.0))))


def _logdet(M: np.ndarray) -> np.ndarray:
    sign, value = np.linalg.slogdet(M)
    return np.where(sign > 0, value, -np.inf)


def select(cands: Candidates, budget: int, spread_weight: float = DEFAULT_SPREAD_WEIGHT,
           exchange_passes: int = DEFAULT_EXCHANGE_PASSES) -> list[int]:
    """Indices of ``budget`` clusters maximising the compound D + space-filling criterion (module docstring).

    Args:
        cands: the candidates.
        budget: number of clusters to choose, 1..K.
        spread_weight: lambda (0: D-optimal alone).
        exchange_passes: Fedorov exchange passes after the greedy selection.

    Returns:
        Chosen cluster indices in the order they were chosen.
    """
    K = len(cands)
    if isinstance(budget, bool) or not isinstance(budget, (int, np.integer)) or not 1 <= budget <= K:
        raise ModelError(f"design: budget must be an integer in 1..{K} (the candidate clusters), got {budget!r}")
    r = cands.info.shape[1]
    prior = PRIOR_FRACTION * float(np.trace(cands.info.mean(axis=0))) / max(r, 1) * np.eye(r)
    spread = _Spread(cands.anchors, int(budget))
    chosen: list[int] = []
    M = prior.copy()
    while len(chosen) < budget:
        gain = _logdet(M[None] + cands.info) / r + spread_weight * spread.gains(chosen)
        gain[chosen] = -np.inf
        best = int(np.argmax(gain))
        chosen.append(best)
        M = M + cands.info[best]

    def criterion(order: list[int]) -> float:
        value: float = float(_logdet(prior + cands.info[order].sum(axis=0))) / r + spread_weight * spread.total(order)
        return value

    current = criterion(chosen)
    for _ in range(exchange_passes):
        improved = False
        for pos in range(len(chosen)):
            rest = chosen[:pos] + chosen[pos + 1:]
            M_rest = prior + cands.info[rest].sum(axis=0)
            d_gain = _logdet(M_rest[None] + cands.info) / r
            d_gain[rest] = -np.inf
            for c in np.argsort(-d_gain)[:20]:  # the best D candidates, then the exact compound criterion
                if c in chosen:
                    continue
                trial = rest[:pos] + [int(c)] + rest[pos:]
                value = criterion(trial)
                if value > current + 1e-9:
                    chosen, current, improved = trial, value, True
                    break
        if not improved:
            break
    return chosen


def figures(cands: Candidates, chosen: list[int] | np.ndarray, noise_mm: float, poses_per_cluster: int = 7
            ) -> DesignFigures:
    """Condition number, rank and predicted parameter uncertainty of the design ``chosen``."""
    if not noise_mm > 0:
        raise ModelError(f"design: noise must be > 0 mm, got {noise_mm!r}")
    chosen = list(chosen)
    M = cands.info[chosen].sum(axis=0)
    r = M.shape[0]
    eig = np.clip(np.linalg.eigvalsh(M), 0.0, None)
    top = eig.max()
    invertible = top > 0 and bool(np.all(eig >= IDENTIFIABLE_TOLERANCE ** 2 * top))
    rank = int(np.sum(eig >= DEFAULT_RELATIVE_TOLERANCE ** 2 * top)) if top > 0 else 0
    cond = float(np.sqrt(top / eig.min())) if invertible else float("inf")
    logdet = float(np.sum(np.log(eig)) / r) if invertible else float("-inf")
    if invertible:
        cov_scaled = cands.basis @ np.linalg.inv(M) @ cands.basis.T
        sigma = noise_mm * np.sqrt(np.clip(np.diag(cov_scaled), 0.0, None)) * cands.scale
    else:
        sigma = np.full(len(cands.scale), np.inf)
    seen = np.linalg.norm(cands.basis, axis=1) > 1e-9
    sigma = np.where(seen, sigma, np.inf)
    return DesignFigures(len(chosen), len(chosen) * poses_per_cluster, rank, r, cond, logdet, sigma, cands.names,
                         float(noise_mm))


def visiting_order(anchors_q: np.ndarray, start_q: np.ndarray | None = None) -> list[int]:
    """A short tour over anchor configurations (nearest neighbour in joint space, from ``start_q``)."""
    left = list(range(len(anchors_q)))
    here = anchors_q[0] if start_q is None else np.asarray(start_q, dtype=float)
    order = []
    while left:
        k = min(left, key=lambda i: float(np.max(np.abs(anchors_q[i] - here))))
        order.append(k)
        left.remove(k)
        here = anchors_q[k]
    return order


@dataclass(frozen=True)
class RecordingSelection:
    """Clusters of a recording chosen by :func:`select_recording`.

    Attributes:
        rows: sample indices of the chosen clusters, in the recording's order, shape (n,).
        clusters: cluster ids chosen (the recording's ids), in the order they were chosen.
        selected: figures of the chosen clusters.
        every: figures of the whole recording.
    """

    rows: np.ndarray
    clusters: tuple[int, ...]
    selected: DesignFigures
    every: DesignFigures


def select_recording(par: MinimalParameterisation, rec: Recording, budget: int, noise_mm: float,
                     cluster_size: int = 7, a: float = DEFAULT_ORIENTATION_WEIGHT,
                     spread_weight: float = DEFAULT_SPREAD_WEIGHT
                     ) -> RecordingSelection:
    """The ``budget`` clusters of ``rec`` (as :meth:`Recording.clusters` defines them) the compound criterion
    picks; identifiable directions are those of the whole recording. (The clusters for a rebase instead:
    :func:`calibration.frames.rebase_design.select_rebase_recording`.)"""
    ids = rec.clusters(cluster_size)
    uniq, first, index = np.unique(ids, return_index=True, return_inverse=True)
    cands = candidates(par, rec.q, index, rec.q[first][:, 1:3], a=a)
    return recording_selection(cands, rec, uniq, index, budget, noise_mm, spread_weight)


def recording_selection(cands: Candidates, rec: Recording, uniq: np.ndarray, index: np.ndarray, budget: int,
                        noise_mm: float, spread_weight: float) -> RecordingSelection:
    """The ``budget`` clusters :func:`select` picks among ``cands`` (one per cluster of ``rec``: ``uniq`` their
    ids, ``index`` each sample's cluster), with the figures of the choice and of the whole recording."""
    chosen = select(cands, budget, spread_weight=spread_weight)
    rows = np.flatnonzero(np.isin(index, chosen))
    sizes = np.bincount(index)
    per = int(round(float(np.mean(sizes))))
    selected = replace(figures(cands, chosen, noise_mm, per), n_poses=len(rows))
    every = replace(figures(cands, list(range(len(cands))), noise_mm, per), n_poses=len(rec))
    return RecordingSelection(rows, tuple(int(uniq[c]) for c in chosen), selected, every)
