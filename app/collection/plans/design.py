"""An observability-optimal collection plan: a budget of pose clusters chosen by :mod:`calibration.identification.design`.

Candidates are anchors drawn (seeded) with q2 over the paper's q2 range and q3 inside its q2-dependent band (so the
configuration-dependent fits interpolate over the region the paper's design covers), while joints 1, 4, 5 and 6 move
widely (``DesignSpec.wide_deg``, within the joint
limits): the paper's grid holds them within 2 deg and cannot identify their axes. Each candidate is the anchor and
the anchor with ``perturb_deg`` on joint 1..6 in turn (the paper's cluster of 7, which the CDC local fits need);
every one of its 7 poses must pass the cell's safety checks (limits, floor, the other arms parked) or the candidate is
dropped. The D-optimal + space-filling selection (:func:`calibration.identification.design.select`) picks ``budget // 7``
clusters, they are visited in a short nearest-neighbour tour, and the whole plan (targets and the joint-space paths
between them) is checked by :meth:`app.collection.safety.CellSafety.check_plan` before it is returned.

Not modelled: whether the mocap cameras see the tool marker at the wide wrist angles (the safety model knows
limits, the floor and the other arm only); check a new design with ``collect --dry-run`` and a short trial.

``--for rebase`` (``DesignSpec.for_rebase``): the same candidates and selection, but the information is that of the
parameters a rebase refits (the base and tool-marker frames and the joint offsets of joints 4 and 5,
:func:`calibration.frames.rebase_design.rebase_candidates`), with no spread term (a rebase interpolates nothing) and clusters that
step each joint by ``REBASE_PERTURB_DEG`` (20 deg). Chosen in the simulated cell (``scripts/benchmarks/bench_rebase_design.py``'s
day change, seed 0; no real recording): from noiseless poses of day B, a rebase on 3 clusters with 1 / 5 / 10 / 20 /
30 deg steps is off by 0.096 / 0.089 / 0.080 / 0.050 / 0.051 mm mean over the workspace (condition numbers 82 / 65 /
50 / 40 / 41; B's own 196-pose calibration 0.051): wider steps keep the 14 parameters from soaking up the old
model's local errors. The paper's grid column is then the grid's own
information about the same 14 directions: its still wrist cannot see the wrist offsets.

:func:`compare_designs` gives the figures of the chosen design and of the paper's grid on the same identifiable
directions (those of all candidates together), so the two are comparable.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from app.collection.plans.collection import Plan, Target
from app.collection.plans.poses import build_plan, paper_q3_bounds, plan_anchor_grid
from app.collection.plans.session import Q2_RANGE_DEG
from app.collection.safety import CellSafety
from calibration.errors import CellCalError, ConfigError
from calibration.frames import rebase, rebase_design
from calibration.identification import design
from calibration.kinematics.parameterisation import MinimalParameterisation
from calibration.methods.cdc import expand_anchors
from calibration.methods.topup import TopupPrior, choose, predicted_sigma
from calibration.models import ConstantModel

CLUSTER_SIZE = 7
#: What a design is for: identifying the geometry (the default) or rebasing a fitted model onto a new day.
TARGETS = ("identification", "rebase")
#: Per-joint step of the paper's clusters [deg].
PAPER_PERTURB_DEG = 1.0
#: Per-joint step of a rebase design's clusters [deg].
REBASE_PERTURB_DEG = 20.0
#: Smallest number of clusters: a CDC interpolation over (q2, q3) needs d + 1 = 3 anchors.
MIN_CLUSTERS = 3


@dataclass(frozen=True)
class DesignSpec:
    """How the optimal design is drawn and chosen.

    Attributes:
        budget: poses to measure; ``budget // 7`` clusters of 7.
        n_candidates: candidate anchors drawn.
        wide_deg: half-range [deg] of q1, q4, q5, q6 around 0 in which candidate anchors are drawn (clipped to the
            joint limits minus ``perturb_deg``).
        perturb_deg: the per-joint step of a cluster [deg].
        spread_weight: lambda of the space-filling term (see :mod:`calibration.identification.design`).
        noise_mm: measurement noise assumed for the predicted uncertainty [mm].
        seed: seed of the candidates.
        target: ``identification`` (the geometry, see :mod:`calibration.identification.design`) or ``rebase`` (the rebase's
            frames and joint offsets).
    """

    budget: int = 196
    n_candidates: int = 1500
    wide_deg: tuple[float, float, float, float] = (45.0, 90.0, 60.0, 90.0)
    perturb_deg: float = 1.0
    spread_weight: float = design.DEFAULT_SPREAD_WEIGHT
    noise_mm: float = 0.05
    seed: int = 0
    target: str = "identification"

    def __post_init__(self) -> None:
        if self.target not in TARGETS:
            raise ConfigError("DesignSpec", "target", f"expected one of {', '.join(TARGETS)}, got {self.target!r}")

    @classmethod
    def for_rebase(cls, budget: int, noise_mm: float = 0.05, seed: int = 0) -> DesignSpec:
        """The rebase design: no spread term, ``REBASE_PERTURB_DEG`` steps."""
        return cls(budget=budget, perturb_deg=REBASE_PERTURB_DEG, spread_weight=0.0, noise_mm=noise_mm, seed=seed,
                   target="rebase")

    @property
    def n_clusters(self) -> int:
        return self.budget // CLUSTER_SIZE


def check_budget(budget: int, limit: int | None = None, unit: str = "poses") -> None:
    """CellCalError unless ``budget`` ([poses] in clusters of 7, or [clusters]) holds at least MIN_CLUSTERS clusters
    and at most ``limit``."""
    least = MIN_CLUSTERS * (CLUSTER_SIZE if unit == "poses" else 1)
    ok = (not isinstance(budget, bool) and isinstance(budget, int) and budget >= least
          and (limit is None or budget <= limit))
    if not ok:
        what = f"{least} poses ({MIN_CLUSTERS} clusters of {CLUSTER_SIZE})" if unit == "poses" else f"{least} clusters"
        most = f" and at most {limit} (the recording's clusters)" if limit is not None else ""
        raise CellCalError(f"--budget: expected an integer of at least {what}{most}, got {budget!r}")


def candidate_anchors(robot: str, safety: CellSafety, others: Mapping[str, np.ndarray], spec: DesignSpec
                      ) -> np.ndarray:
    """Safe candidate anchors [rad], shape (K, 6): every pose of each one's cluster passes the safety checks."""
    rng = np.random.default_rng(spec.seed)
    lo, hi = safety.limits(robot)
    step = math.radians(spec.perturb_deg)
    n = spec.n_candidates
    q = np.zeros((n, 6))
    q[:, 1] = np.radians(rng.uniform(*Q2_RANGE_DEG, n))
    for i in range(n):
        lo3, hi3 = paper_q3_bounds(math.degrees(q[i, 1]))
        q[i, 2] = math.radians(rng.uniform(lo3, hi3))
    for j, w in zip((0, 3, 4, 5), spec.wide_deg):
        a, b = max(-math.radians(w), lo[j]), min(math.radians(w), hi[j] - step)
        q[:, j] = rng.uniform(a, b, n)
    keep = _safe(robot, safety, others, q, step, np.arange(n))
    if len(keep) < spec.n_clusters:
        raise CellCalError(f"--budget {spec.budget} asks for {spec.n_clusters} clusters of {CLUSTER_SIZE} but only "
                           f"{len(keep)} of the {n} candidate clusters drawn are safe; give --budget "
                           f"{len(keep) * CLUSTER_SIZE} or less")
    return q[keep]


def _safe(robot: str, safety: CellSafety, others: Mapping[str, np.ndarray], anchors_q: np.ndarray, step_rad: float,
          index: np.ndarray) -> list[int]:
    """The anchors of ``index`` whose whole cluster passes ``safety.check_configs`` (bisecting failing batches)."""
    cluster_q, _ = expand_anchors(anchors_q[index], step_rad)
    try:
        safety.check_configs(robot, cluster_q, others)
        return [int(i) for i in index]
    except CellCalError:
        if len(index) == 1:
            return []
    half = len(index) // 2
    return (_safe(robot, safety, others, anchors_q, step_rad, index[:half])
            + _safe(robot, safety, others, anchors_q, step_rad, index[half:]))


def _candidates(par: MinimalParameterisation, anchors_q: np.ndarray, perturb_deg: float,
                reference_q: np.ndarray | None = None, target: str = "identification", robot: str = "R1"
                ) -> design.Candidates:
    q, cluster = expand_anchors(anchors_q, math.radians(perturb_deg))
    if target == "rebase":

        nominal = ConstantModel(robot, "nominal", par.nominal)
        return rebase_design.rebase_candidates(nominal, q, cluster, anchors_q[:, 1:3], reference_q=reference_q)
    return design.candidates(par, q, cluster, anchors_q[:, 1:3], reference_q=reference_q)


def optimal_plan(robot: str, par: MinimalParameterisation, safety: CellSafety, others: Mapping[str, np.ndarray],
                 spec: DesignSpec = DesignSpec(), q_start: np.ndarray | None = None
                 ) -> tuple[Plan, dict[str, design.DesignFigures]]:
    """The optimal design as a plan, and the figures of it and of the paper's grid (``optimal``, ``paper_grid``).

    Raises:
        CellCalError: a budget below 3 clusters.
        CellCalError: too few safe candidates, or the chosen design does not see every identifiable direction.
        UnsafeTarget: the plan's targets or paths fail the whole-plan check.
    """
    check_budget(spec.budget)
    anchors_q = candidate_anchors(robot, safety, others, spec)
    cands = _candidates(par, anchors_q, spec.perturb_deg, target=spec.target, robot=robot)
    chosen = design.select(cands, spec.n_clusters, spread_weight=spec.spread_weight)
    figs = design.figures(cands, chosen, spec.noise_mm, CLUSTER_SIZE)
    if figs.rank < figs.n_identifiable:
        raise CellCalError(f"--budget {spec.budget}: {spec.n_clusters} clusters of {CLUSTER_SIZE} see {figs.rank} of "
                           f"{figs.n_identifiable} identifiable {'rebase' if spec.target == 'rebase' else 'parameter'} "
                           f"directions; give a larger --budget (each cluster adds {CLUSTER_SIZE} poses)")
    picked = anchors_q[chosen]
    order = design.visiting_order(picked, q_start)
    targets = []
    for k, i in enumerate(order):
        cluster_q, _ = expand_anchors(picked[i:i + 1], math.radians(spec.perturb_deg))
        targets.append(Target(robot, cluster_q[0], k, "anchor"))
        targets += [Target(robot, qq, k, "perturb") for qq in cluster_q[1:]]
    plan = build_plan(targets, robot=robot, design="optimal", budget=spec.budget, clusters=spec.n_clusters,
                      candidates=len(anchors_q), wide_deg=list(spec.wide_deg), spread_weight=spec.spread_weight,
                      seed=spec.seed, **({"for": "rebase", "perturb_deg": spec.perturb_deg}
                                         if spec.target == "rebase" else {}))
    safety.check_plan(robot, plan.q, others, q_start)
    grid = paper_grid_figures(par, spec, anchors_q, robot)
    return plan, {"optimal": figs, "paper_grid": grid}


def paper_grid_figures(par: MinimalParameterisation, spec: DesignSpec, anchors_q: np.ndarray | None = None,
                       robot: str = "R1") -> design.DesignFigures:
    """Figures of the paper's 248-anchor grid (the default ``plan``), on the identifiable directions of
    ``anchors_q``'s clusters when given (else its own)."""
    grid = plan_anchor_grid("grid", perturb_deg=PAPER_PERTURB_DEG)
    anchors = np.array([t.q for t in grid if t.kind == "anchor"])
    ref = None
    if anchors_q is not None:
        ref, _ = expand_anchors(anchors_q, math.radians(spec.perturb_deg))
    cands = _candidates(par, anchors, PAPER_PERTURB_DEG, reference_q=ref, target=spec.target, robot=robot)
    return design.figures(cands, list(range(len(cands))), spec.noise_mm, CLUSTER_SIZE)


def figures_table(figs: Mapping[str, design.DesignFigures]) -> str:
    """Designs side by side: size, rank, condition number and the predicted uncertainty per joint."""
    names = list(figs)
    first = figs[names[0]]
    for_rebase = first.names[:12] == rebase.DIRECTION_NAMES  # one row per frame direction and joint offset
    n = 0 if for_rebase else len(first.names) // 4  # 4 per joint, plus at most 3 for the flange shift
    width = max(12, *(len(k) for k in names)) + 2
    head = f"{'':34s}" + "".join(f"{k:>{width}s}" for k in names)
    lines = [head]

    def row(label: str, values: list[str]) -> None:
        lines.append(f"{label:34s}" + "".join(f"{v:>{width}s}" for v in values))

    def g(v: float, fmt: str) -> str:
        return format(v, fmt) if np.isfinite(v) else "inf"

    row("clusters / poses", [f"{f.n_clusters} / {f.n_poses}" for f in figs.values()])
    row("directions seen / identifiable", [f"{f.rank} / {f.n_identifiable}" for f in figs.values()])
    row("condition number", [g(f.condition_number, ".4g") for f in figs.values()])
    if for_rebase:
        for i, name in enumerate(first.names):
            angle = design.sigma_unit(name) == "rad"
            row(f"sigma {name} [{'mdeg' if angle else 'mm'}]",
                [g(1e3 * math.degrees(float(f.sigma[i])) if angle else float(f.sigma[i]), ".4f")
                 for f in figs.values()])
    for j in range(n):
        row(f"sigma joint {j + 1} origin [mm]", [g(float(np.max(f.sigma[2 * j:2 * j + 2])), ".4f")
                                                 for f in figs.values()])
    for j in range(n):
        tilt = slice(2 * n + 2 * j, 2 * n + 2 * j + 2)
        row(f"sigma joint {j + 1} tilt [mdeg]", [g(1e3 * math.degrees(float(np.max(f.sigma[tilt]))), ".3f")
                                                 for f in figs.values()])
    if n and len(first.names) > 4 * n:
        row("sigma flange shift [mm]", [g(float(np.max(f.sigma[4 * n:])), ".4f") for f in figs.values()])
    lines.append(f"(sigma: predicted standard deviation for {first.noise_mm:g} mm of noise per measured coordinate)")
    return "\n".join(lines)


#: Candidate configurations a top-up plan draws, half next to the task's configurations, half over the workspace.
TOPUP_CANDIDATES = 1500
#: Standard deviation of the jitter around a task configuration [deg] of the candidates drawn next to the task.
TOPUP_JITTER_DEG = 5.0


@dataclass(frozen=True)
class TopupPlan:
    """A top-up collection plan and what the design predicts for the task.

    Attributes:
        plan: the poses to measure next (kind ``anchor``, each its own cluster id: they stand alone).
        sigma_before_mm, sigma_after_mm: predicted position error (RMS norm) of a global fit at every task
            configuration (:func:`calibration.methods.topup.predicted_sigma`), with the given poses alone and after the
            plan's, shape (T,).
        n_candidates: safe candidates the poses were chosen from.
    """

    plan: Plan
    sigma_before_mm: np.ndarray
    sigma_after_mm: np.ndarray
    n_candidates: int


def _safe_poses(robot: str, safety: CellSafety, others: Mapping[str, np.ndarray], q: np.ndarray,
                index: np.ndarray) -> list[int]:
    """The configurations of ``index`` that pass ``safety.check_configs`` (bisecting failing batches)."""
    try:
        safety.check_configs(robot, q[index], others)
        return [int(i) for i in index]
    except CellCalError:
        if len(index) == 1:
            return []
    half = len(index) // 2
    return (_safe_poses(robot, safety, others, q, index[:half])
            + _safe_poses(robot, safety, others, q, index[half:]))


def topup_candidates(robot: str, safety: CellSafety, others: Mapping[str, np.ndarray], q_task: np.ndarray,
                     n: int = TOPUP_CANDIDATES, seed: int = 0) -> np.ndarray:
    """Safe candidate configurations [rad] (K, 6): half the task's configurations jittered by
    ``TOPUP_JITTER_DEG``, half drawn as :func:`candidate_anchors` draws (q2 and q3 over the paper's band, q1 and the
    wrist wide), all within the joint limits and passing the cell's safety checks with the other arms parked."""
    rng = np.random.default_rng(seed)
    lo, hi = safety.limits(robot)
    near = q_task[rng.integers(0, len(q_task), n // 2)] + rng.normal(0, math.radians(TOPUP_JITTER_DEG), (n // 2, 6))
    wide = np.zeros((n - n // 2, 6))
    wide[:, 1] = np.radians(rng.uniform(*Q2_RANGE_DEG, len(wide)))
    for i in range(len(wide)):
        lo3, hi3 = paper_q3_bounds(math.degrees(wide[i, 1]))
        wide[i, 2] = math.radians(rng.uniform(lo3, hi3))
    for j, w in zip((0, 3, 4, 5), DesignSpec().wide_deg):
        wide[:, j] = rng.uniform(max(-math.radians(w), lo[j]), min(math.radians(w), hi[j]), len(wide))
    q = np.clip(np.concatenate([near, wide]), lo, hi)
    safe: np.ndarray = q[_safe_poses(robot, safety, others, q, np.arange(len(q)))]
    return safe


def topup_plan(robot: str, nominal: object, safety: CellSafety, others: Mapping[str, np.ndarray],
               q_given: np.ndarray, q_task: np.ndarray, budget: int, noise_mm: float = 0.05, seed: int = 0,
               q_start: np.ndarray | None = None) -> TopupPlan:
    """``budget`` poses to measure next for the task ``q_task`` given the poses ``q_given`` already measured: the
    top-up criterion (:func:`calibration.methods.topup.choose`) on safe candidates (:func:`topup_candidates`), visited in a
    short nearest-neighbour tour; the whole plan passes :meth:`CellSafety.check_plan`.

    Raises:
        CellCalError: a budget below 1 or above the safe candidates.
        UnsafeTarget: the plan's targets or paths fail the whole-plan check.
    """

    cands = topup_candidates(robot, safety, others, q_task, seed=seed)
    if not 1 <= budget <= len(cands):
        raise CellCalError(f"--budget must be in 1..{len(cands)} poses (the safe candidates drawn), got {budget}")
    prior = TopupPrior(noise_mm=noise_mm)
    res = choose(nominal, q_given, cands, q_task, budget, prior)
    picked = cands[list(res.order)]
    order = design.visiting_order(picked, q_start)
    targets = [Target(robot, picked[i], k, "anchor") for k, i in enumerate(order)]
    plan = build_plan(targets, robot=robot, design="topup", budget=budget, candidates=len(cands), seed=seed,
                      jitter_deg=TOPUP_JITTER_DEG)
    safety.check_plan(robot, plan.q, others, q_start)
    return TopupPlan(plan, predicted_sigma(nominal, q_given, q_task, prior),
                     predicted_sigma(nominal, np.concatenate([q_given, picked]), q_task, prior), len(cands))
