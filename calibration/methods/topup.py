"""Top-up design: the few poses an existing calibration is missing, chosen for the task the cell will run.

Given the joint angles of the training poses (TRAIN), of candidate poses and of the task, choose k candidates
that most reduce the model's **predicted position variance over the task's configurations**. Only joint angles
are read: a choice is made before anything is measured.

The error model behind the prediction is a Bayesian linear model with two parts, one per thing a fit can learn:

- **the parametric part** ``J(q) delta``: the scaled identification Jacobian of the model's global parameters
  (``kind="pi"``: the geometric block and the pi blocks, tool rotation, gravity compliance and structural
  deflection, :class:`~calibration.physics.extended.ExtendedKinematics`; ``kind="geometric"``: the minimal POE
  geometry alone, what nls1 fits), each scaled parameter with a weak prior ``param_sd`` [mm-equivalent];
- **the configuration-dependent part** ``f(q)``: what no global parameter explains and a CDC or neural method
  interpolates, as a Gaussian-process prior over joint space per position coordinate (squared-exponential kernel,
  scale ``gp_scale_mm``, length ``length_rad`` in joint space), made finite by a Nystroem feature map on
  ``n_inducing`` centres spread by farthest-point sampling over every configuration known (training, candidates,
  task). A training pose only informs it near itself: a task configuration far from the training data keeps its
  prior variance until a candidate near it is measured.

Every measured pose adds its 6 rows (position, and orientation as the fits weigh it, ``sqrt(2 a)``; the
configuration-dependent part acts on position only) with noise ``noise_mm``. The posterior covariance ``C`` of all
weights gives each task pose's predicted position variance ``v_t = tr(Phi_t C Phi_t^T)`` (the expected squared
norm of the position error there).

**Criterion** (minimised): ``mean_t v_t + tail_weight * mean of the worst tail fraction of v_t``. The first term
is I-optimality (the mean over the task); the second a smooth stand-in for G-optimality (the worst task pose): the
conditional mean of the worst 10 % rather than the single maximum, which a greedy step can lower steadily (the
maximum moves from pose to pose and a greedy step on it alone chases one pose at a time). Why variance over the
task rather than D on the parameters (:mod:`calibration.identification.design`): D spreads information over every parameter
alike; the task needs only the directions its configurations see, and the configuration-dependent part has no
finite parameter set for D to count.

**How it covers each model kind**: nls1 is the parametric part with ``kind="geometric"``; pi the parametric part
with ``kind="pi"``; a CDC or neural method the configuration-dependent part on top of its reference (its local fits
need clusters, which stand-alone top-up poses are not, so it gains from them through its pi reference: the GP part
here stands for whatever error the global fit leaves that varies over joint space).

**Selection**: sequential greedy, exact: each step adds the candidate whose rank-6 update lowers the criterion
most, with every candidate's effect on every task pose kept up to date by rank-6 downdates (no refactorisation).
Greedy is nested: the first k of a K-pose choice are the k-pose choice.

**Defaults and what they were chosen on.** noise 0.05 mm (the recordings' position noise is 0.02-0.05 mm), GP
length 0.5 rad, parameter prior 1 mm-equivalent, 150 Nystroem centres and at most 400 task poses read (cost) were set
before any run. The GP scale and the tail weight were compared on the top-up protocol's task figures of two tuning
days only, 0725 and 0620 after (pi fitted with 21 chosen poses at weight 7, interleaved and halves splits; task mean
[mm] 0725 int / 0725 halves / 0620 int / 0620 halves): GP scale 0.05: 0.144 / 0.196 / 0.153 / 0.148; 0.15: 0.141 /
0.202 / 0.149 / 0.152; 0.4: 0.143 / 0.200 / 0.155 / 0.150 (flat: 0.15 kept); tail weight 0 (I-optimal alone): 0.141
/ 0.211 / 0.149 / 0.162; 1: as GP 0.15; 3: 0.146 / 0.196 / 0.153 / 0.151 (1 kept: the G term guards the halves
split, where the task lies beyond every candidate). The other five days were not looked at for these choices.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from calibration.errors import ModelError
from calibration.identification.geometric import DEFAULT_ORIENTATION_WEIGHT
from calibration.identification.observability import DEFAULT_REACH_MM, scaled_rows
from calibration.kinematics.arrays import FloatArray
from calibration.kinematics.parameterisation import MinimalParameterisation
from calibration.physics.extended import ExtendedKinematics

#: Measurement noise per row [mm, mm-equivalent]: the recordings' position noise is 0.02-0.05 mm.
DEFAULT_NOISE_MM = 0.05
#: Prior standard deviation of the configuration-dependent error per position coordinate [mm].
DEFAULT_GP_SCALE_MM = 0.15
#: Length scale of the configuration-dependent error in joint space [rad].
DEFAULT_LENGTH_RAD = 0.5
#: Prior standard deviation of each scaled global parameter [mm-equivalent].
DEFAULT_PARAM_SD_MM = 1.0
#: The worst fraction of task poses the G term averages, and its weight against the mean.
DEFAULT_TAIL = 0.1
DEFAULT_TAIL_WEIGHT = 1.0
#: Nystroem centres of the configuration-dependent part.
DEFAULT_INDUCING = 150
#: Task poses the criterion reads at most (evenly spaced along the task when it has more).
DEFAULT_MAX_TASK = 400
KINDS = ("pi", "geometric")


@dataclass(frozen=True)
class TopupPrior:
    """The error model's settings (module docstring); defaults chosen as :mod:`scripts.benchmarks.bench_topup` says."""

    kind: str = "pi"
    noise_mm: float = DEFAULT_NOISE_MM
    gp_scale_mm: float = DEFAULT_GP_SCALE_MM
    length_rad: float = DEFAULT_LENGTH_RAD
    param_sd_mm: float = DEFAULT_PARAM_SD_MM
    tail: float = DEFAULT_TAIL
    tail_weight: float = DEFAULT_TAIL_WEIGHT
    n_inducing: int = DEFAULT_INDUCING
    max_task: int = DEFAULT_MAX_TASK
    a: float = DEFAULT_ORIENTATION_WEIGHT

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ModelError(f"top-up design: unknown model kind {self.kind!r}; valid: {', '.join(KINDS)}")
        for name in ("noise_mm", "length_rad", "param_sd_mm"):
            if not np.isfinite(getattr(self, name)) or getattr(self, name) <= 0:
                raise ModelError(f"top-up design: {name} must be a positive number, got {getattr(self, name)!r}")
        if not (np.isfinite(self.gp_scale_mm) and self.gp_scale_mm >= 0):
            raise ModelError(f"top-up design: gp_scale_mm must be >= 0, got {self.gp_scale_mm!r}")
        if not 0 < self.tail <= 1 or not self.tail_weight >= 0:
            raise ModelError(f"top-up design: tail must be in (0, 1] and tail_weight >= 0, got {self.tail!r}, "
                             f"{self.tail_weight!r}")


@dataclass(frozen=True)
class TopupChoice:
    """What :func:`choose` returns.

    Attributes:
        order: chosen candidate indices, in the order chosen (the first k are the k-pose choice).
        sigma_before_mm: predicted position error (RMS norm) at each task pose with TRAIN alone, shape (T,).
        sigma_after_mm: the same after the chosen poses, shape (T,).
        criterion_mm2: the criterion after each step (entry 0: TRAIN alone), shape (k + 1,).
        task_rows: which task poses the criterion read (all, or an even subsample), shape (T,).
    """

    order: tuple[int, ...]
    sigma_before_mm: np.ndarray
    sigma_after_mm: np.ndarray
    criterion_mm2: np.ndarray
    task_rows: np.ndarray


def farthest_points(x: np.ndarray, n: int, start: int = 0) -> np.ndarray:
    """Indices of ``n`` rows of ``x`` (N, d) spread by farthest-point sampling (Euclidean), from row ``start``."""
    n = min(int(n), len(x))
    chosen = [start]
    d = np.linalg.norm(x - x[start], axis=1)
    for _ in range(n - 1):
        i = int(np.argmax(d))
        chosen.append(i)
        d = np.minimum(d, np.linalg.norm(x - x[i], axis=1))
    return np.asarray(chosen, dtype=int)


class Features:
    """The feature rows ``Phi(q)`` (N, 6, p) of the error model: parametric columns, then M GP weights per axis."""

    def __init__(self, nominal: object, prior: TopupPrior, centres: np.ndarray, theta: np.ndarray | None) -> None:
        par = MinimalParameterisation(nominal, fit_tool=True)  # type: ignore[arg-type]
        self.prior = prior
        self._jac: Callable[[np.ndarray], np.ndarray]  # q (N, 6) -> pose Jacobian (N, 6, m)
        if prior.kind == "pi":
            kin = ExtendedKinematics(par)
            self._jac = lambda q: kin.jacobian(q, np.zeros(kin.size) if theta is None else theta)[2]
            self._scale = kin.scale(DEFAULT_REACH_MM)
        else:
            self._jac = lambda q: par.jacobian(q, np.zeros(par.size) if theta is None else theta[: par.size])[2]
            self._scale = par.scale(DEFAULT_REACH_MM)
        self.m = len(self._scale)
        self.centres = centres
        K = self._kernel(centres, centres) + 1e-8 * np.eye(len(centres))
        w, V = np.linalg.eigh(K)
        keep = w > 1e-10 * w[-1]
        self._map = V[:, keep] / np.sqrt(w[keep])  # k(q, Z) @ map: features whose Gram is the Nystroem kernel
        self.M = int(keep.sum())
        self.p = self.m + 3 * self.M

    def _kernel(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        d2 = np.sum(a * a, 1)[:, None] + np.sum(b * b, 1)[None] - 2 * a @ b.T
        K: FloatArray = np.exp(-0.5 * np.maximum(d2, 0.0) / self.prior.length_rad ** 2)
        return K

    def rows(self, q: np.ndarray) -> np.ndarray:
        """Feature rows (N, 6, p), in mm per unit weight; every weight has a unit prior."""
        q = np.asarray(q, dtype=float).reshape(-1, 6)
        out = np.zeros((len(q), 6, self.p))
        if not len(q):
            return out
        out[:, :, : self.m] = scaled_rows(self._jac(q), self._scale, self.prior.a) * self.prior.param_sd_mm
        if self.prior.gp_scale_mm > 0:
            phi = self.prior.gp_scale_mm * (self._kernel(q, self.centres) @ self._map)  # (N, M)
            for k in range(3):
                out[:, k, self.m + k * self.M: self.m + (k + 1) * self.M] = phi
        return out


def _posterior(nominal: object, q_given: np.ndarray, known: np.ndarray, prior: TopupPrior,
               theta: np.ndarray | None) -> tuple[Features, np.ndarray]:
    """The feature map (Nystroem centres spread over ``known``) and the posterior covariance (p, p) of every weight
    after measuring ``q_given``."""
    centres = known[farthest_points(known, prior.n_inducing)]
    feats = Features(nominal, prior, centres, theta)
    F_given = feats.rows(q_given).reshape(-1, feats.p) if len(q_given) else np.zeros((0, feats.p))
    C = np.linalg.inv(np.eye(feats.p) + F_given.T @ F_given / prior.noise_mm ** 2)
    return feats, 0.5 * (C + C.T)


def _tail_mean(v: np.ndarray, tail: float) -> np.ndarray:
    """Mean of the largest ``ceil(tail * T)`` entries of each column of v (T, C), shape (C,)."""
    n = max(1, int(np.ceil(tail * v.shape[0])))
    mean: FloatArray = np.mean(np.partition(v, v.shape[0] - n, axis=0)[v.shape[0] - n:], axis=0)
    return mean


def choose(nominal: object, q_given: np.ndarray, q_candidates: np.ndarray, q_task: np.ndarray, k: int,
           prior: TopupPrior | None = None, theta: np.ndarray | None = None) -> TopupChoice:
    """Choose ``k`` candidates minimising the criterion of the module docstring.

    Args:
        nominal: the robot's nominal :class:`~calibration.kinematics.poe.PoeModel`.
        q_given: joint angles of the training poses already measured [rad], shape (N, 6) (may be empty).
        q_candidates: joint angles of the candidates [rad], shape (C, 6).
        q_task: joint angles of the task [rad], shape (T, 6).
        k: poses to choose, 0..C.
        prior: the error model's settings.
        theta: the fitted model's parameters the Jacobian is taken at (the kind's layout; default nominal).

    Raises:
        ModelError: k out of range, or no task configuration.
    """
    prior = prior or TopupPrior()
    q_given = np.asarray(q_given, dtype=float).reshape(-1, 6)
    q_cand = np.asarray(q_candidates, dtype=float).reshape(-1, 6)
    q_task_all = np.asarray(q_task, dtype=float).reshape(-1, 6)
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 0 <= k <= len(q_cand):
        raise ModelError(f"top-up design: poses to choose must be an integer in 0..{len(q_cand)} (the candidates), "
                         f"got {k!r}")
    if not len(q_task_all):
        raise ModelError("top-up design: the task has no configuration")
    task_rows = np.arange(len(q_task_all))
    if len(task_rows) > prior.max_task:
        task_rows = np.unique(np.linspace(0, len(q_task_all) - 1, prior.max_task).round().astype(int))
    q_task = q_task_all[task_rows]
    feats, C = _posterior(nominal, q_given, np.concatenate([q_given, q_cand, q_task]), prior, theta)
    s2 = prior.noise_mm ** 2
    P_task = feats.rows(q_task)[:, :3].reshape(-1, feats.p)  # (3T, p)
    P_cand = feats.rows(q_cand).reshape(-1, feats.p)  # (6C, p)
    T, nc = len(q_task), len(q_cand)
    CPc = C @ P_cand.T  # (p, 6C)
    G = P_task @ CPc  # cov(task position rows, candidate rows), (3T, 6C)
    S = np.matmul(P_cand.reshape(nc, 6, feats.p), CPc.T.reshape(nc, 6, feats.p).transpose(0, 2, 1))  # (C, 6, 6)
    v = np.einsum("ip,pq,iq->i", P_task, C, P_task).reshape(T, 3).sum(axis=1)
    v_before = v.copy()
    crit = [float(v.mean() + prior.tail_weight * _tail_mean(v[:, None], prior.tail)[0])]
    order: list[int] = []
    free = np.ones(nc, dtype=bool)
    for _ in range(k):
        Sinv = np.linalg.inv(S + s2 * np.eye(6))
        Gc = G.reshape(3 * T, nc, 6).transpose(1, 0, 2)  # (C, 3T, 6)
        red = np.sum(np.matmul(Gc, Sinv) * Gc, axis=2).reshape(nc, T, 3).sum(axis=2).T  # (T, C) variance reductions
        new_v = v[:, None] - red
        score = new_v.mean(axis=0) + prior.tail_weight * _tail_mean(new_v, prior.tail)
        score[~free] = np.inf
        c = int(np.argmin(score))
        order.append(c)
        free[c] = False
        v = np.maximum(new_v[:, c], 0.0)
        crit.append(float(score[c]))
        # rank-6 downdate of every covariance kept: C Phi_cand^T, cov(task, candidates), the candidates' own blocks
        u = CPc[:, 6 * c: 6 * c + 6].copy()  # C Phi_c^T (p, 6)
        Sc = Sinv[c]
        Pu_cand = P_cand @ u  # (6C, 6)
        G -= (P_task @ u) @ Sc @ Pu_cand.T
        Pc = Pu_cand.reshape(nc, 6, 6)
        S -= np.matmul(Pc @ Sc, Pc.transpose(0, 2, 1))
        CPc -= u @ Sc @ Pu_cand.T
    return TopupChoice(tuple(order), np.sqrt(v_before), np.sqrt(v), np.asarray(crit), task_rows)


#: The error model behind :func:`predicted_sigma` (the position error a fitted global model, pi or nls1, makes):
#: a tighter parameter prior than the design's (a pi fit damps what its data cannot see toward the nominal arm,
#: which is off by a fraction of a millimetre there, not by the design's loose 1 mm-equivalent) and the
#: configuration-dependent part counted in full (a global model does not learn it, however close its poses).
#: Both chosen on the tuning days 0725 and 0620 after only (pi fitted on the grid alone and with 21 chosen poses,
#: interleaved and halves splits: 8 cases), from parameter prior {0.1, 0.3, 1} x residual {0.05, 0.1, 0.15} mm: 0.1 /
#: 0.1 puts 25-60 % (mean 40 %) of the task poses beyond 1 sigma and 0-3 % beyond 2 sigma, against an isotropic
#: Gaussian's 39 % and 0.7 %; a residual of 0.05 mm put 11-58 % beyond 2 sigma, 0.15 mm none beyond 1.3 sigma.
SIGMA_PARAM_SD_MM = 0.1
SIGMA_RESIDUAL_MM = 0.1


def predicted_position_cov(nominal: object, q_given: np.ndarray, q_query: np.ndarray, prior: TopupPrior | None = None,
                           theta: np.ndarray | None = None, param_sd_mm: float = SIGMA_PARAM_SD_MM,
                           residual_mm: float = SIGMA_RESIDUAL_MM) -> np.ndarray:
    """Predicted covariance [mm^2] of the position error of a global model (pi, nls1) fitted on ``q_given``, at each
    query configuration, shape (Q, 3, 3): the parametric part's posterior covariance (prior ``param_sd_mm``), plus
    ``residual_mm`` per coordinate (isotropic) of configuration-dependent error a global model never learns."""
    prior = prior or TopupPrior()
    prior = TopupPrior(**{**prior.__dict__, "param_sd_mm": param_sd_mm, "gp_scale_mm": 0.0})
    q_given = np.asarray(q_given, dtype=float).reshape(-1, 6)
    q_query = np.asarray(q_query, dtype=float).reshape(-1, 6)
    feats, C = _posterior(nominal, q_given, np.concatenate([q_given, q_query]), prior, theta)
    P = feats.rows(q_query)[:, :3]  # (Q, 3, p)
    cov: FloatArray = np.einsum("nip,pq,njq->nij", P, C, P) + residual_mm ** 2 * np.eye(3)
    return cov


def predicted_sigma(nominal: object, q_given: np.ndarray, q_query: np.ndarray, prior: TopupPrior | None = None,
                    theta: np.ndarray | None = None, param_sd_mm: float = SIGMA_PARAM_SD_MM,
                    residual_mm: float = SIGMA_RESIDUAL_MM) -> np.ndarray:
    """Predicted position error (RMS of the error norm) [mm] of a global model (pi, nls1) fitted on ``q_given``, at
    each query configuration, shape (Q,): the trace of :func:`predicted_position_cov`, square-rooted."""
    cov = predicted_position_cov(nominal, q_given, q_query, prior, theta, param_sd_mm, residual_mm)
    sigma_mm: FloatArray = np.sqrt(np.trace(cov, axis1=1, axis2=2))
    return sigma_mm


#: Standard normal draws (fixed) for :func:`gaussian_share_over`: its figure is the same on every call.
_Z2 = np.random.default_rng(20261204).standard_normal((100000, 3)) ** 2


def gaussian_share_over(cov: np.ndarray, factor: float = 2.0) -> float:
    """Share of poses whose position error norm exceeds ``factor`` times its RMS (sigma of :func:`predicted_sigma`)
    if each pose's error were Gaussian with covariance ``cov`` (Q, 3, 3), averaged over the poses.

    This is the reference the measured share beyond 2 sigma is judged against. It depends on the covariance's
    shape: P(chi2_3 > 12) = 0.74 % for an isotropic error, up to P(|z| > 2) = 4.55 % for an error along one axis
    (sigma of a norm is not the sigma of one coordinate). Computed with 100000 fixed normal draws (about 0.03 % of
    sampling error at 1 %), over the shapes rounded to 0.01 of the trace.
    """
    lam = np.clip(np.linalg.eigvalsh(np.asarray(cov, dtype=float)), 0.0, None)  # (Q, 3)
    lam = lam / np.maximum(lam.sum(axis=1, keepdims=True), 1e-300)  # the share depends on the shape only
    shape, counts = np.unique(np.round(lam, 2), axis=0, return_counts=True)  # poses of one shape: one count
    over = [np.mean(_Z2 @ s > factor ** 2 * s.sum()) for s in shape]
    return float(np.dot(over, counts) / counts.sum())


#: The parameter priors [mm-equivalent] and residuals per coordinate [mm] :func:`held_out_sigma_scales` chooses
#: among by default. The prior is not chosen there: on the training recordings' held-out folds (clusters at random,
#: the q1/q4-q6 steps, the q2 and q3 edges) the likelihood rises with the prior without a maximum (0613, 0620 after:
#: 0.03 .. 10 mm-equivalent, ever flatter), since those folds lie where the other poses pin every parameter the
#: prior would free; a task 40-90 deg beyond them does not. So it stays the fixed SIGMA_PARAM_SD_MM; the residual,
#: which those folds do measure, is chosen per training recording (the 7 R1 days with a test: 0.08-0.15 mm;
#: ``scripts/bench_topup.py --sigma-k 0,21`` reports it beside the fixed one on the task poses).
SIGMA_PARAM_SD_GRID_MM = (SIGMA_PARAM_SD_MM,)
SIGMA_RESIDUAL_GRID_MM = (0.02, 0.03, 0.04, 0.05, 0.06, 0.08, 0.1, 0.12, 0.15, 0.2, 0.25, 0.3, 0.4)


@dataclass(frozen=True)
class SigmaScales:
    """The predicted sigma's two scales chosen on held-out training data (:func:`held_out_sigma_scales`).

    Attributes:
        param_sd_mm: prior of each scaled global parameter [mm-equivalent].
        residual_mm: configuration-dependent error per position coordinate [mm].
        held_out_poses: held-out predictions the choice read (a pose held out by two folds counts twice).
        share_over_2_sigma: share of those whose error exceeded 2 sigma under the chosen scales.
    """

    param_sd_mm: float
    residual_mm: float
    held_out_poses: int
    share_over_2_sigma: float

    def to_json(self) -> dict[str, float | int]:
        return {"param_sd_mm": self.param_sd_mm, "residual_mm": self.residual_mm, "held_out_poses": self.held_out_poses,
                "share_over_2_sigma": self.share_over_2_sigma}


def held_out_sigma_scales(nominal: object, q: np.ndarray, held_out: list[np.ndarray], error_mm: list[np.ndarray],
                          prior: TopupPrior | None = None, theta: np.ndarray | None = None,
                          param_grid_mm: tuple[float, ...] = SIGMA_PARAM_SD_GRID_MM,
                          residual_grid_mm: tuple[float, ...] = SIGMA_RESIDUAL_GRID_MM) -> SigmaScales:
    """Choose :func:`predicted_sigma`'s ``residual_mm`` (and ``param_sd_mm`` when ``param_grid_mm`` offers more
    than the fixed one: see :data:`SIGMA_PARAM_SD_GRID_MM` for why it does not by default) on held-out training
    poses: the pair of the grids under which the position errors of the global model refitted without each fold, at that fold's poses,
    are most likely (maximum likelihood of a Gaussian 3-D error of each pose's predicted RMS norm, over every fold).

    Folds of clusters held out at random test the residual (they sit among the poses fitted); folds that hold out
    the edges of the training range or the steps of joints the fit then never sees move test how far the global
    parameters stray where the data does not reach: the parameter prior. The test recording plays no part.

    Args:
        nominal: the robot's nominal model.
        q: the training poses' joint angles [rad], shape (N, 6).
        held_out: per fold, the poses (N,) held out of the refit.
        error_mm: per fold, the refit model's position error [mm] at the held-out poses, shape (held,).

    Raises:
        ModelError: no fold, or a fold's errors not one per held-out pose.
    """
    prior = prior or TopupPrior()
    q = np.asarray(q, dtype=float).reshape(-1, 6)
    if not held_out or len(held_out) != len(error_mm):
        raise ModelError(f"held-out sigma scales: need one error array per fold, got {len(held_out)} folds and "
                         f"{len(error_mm)} error arrays")
    base = TopupPrior(**{**prior.__dict__, "param_sd_mm": 1.0, "gp_scale_mm": 0.0})
    feats = Features(nominal, base, q[:1], theta)
    rows = feats.rows(q)[:, :, : feats.m]  # (N, 6, m): unit parameter prior
    s2 = prior.noise_mm ** 2
    v_par: dict[float, list[np.ndarray]] = {sd: [] for sd in param_grid_mm}
    errs = []
    for mask, e in zip(held_out, error_mm):
        mask = np.asarray(mask, dtype=bool)
        e = np.asarray(e, dtype=float)
        if mask.shape != (len(q),) or e.shape != (int(mask.sum()),):
            raise ModelError(f"held-out sigma scales: a fold holds out {int(mask.sum())} of {len(q)} poses but has "
                             f"{e.size} errors")
        F = rows[~mask].reshape(-1, feats.m)
        a, U = np.linalg.eigh(F.T @ F / s2)
        PU = np.einsum("nip,pk->nik", rows[mask][:, :3], U) ** 2  # (held, 3, m)
        for sd in param_grid_mm:  # posterior of sd * unit weights: sd^2 / (1 + sd^2 a) per eigen-direction
            v_par[sd].append(np.sum(PU * (sd ** 2 / (1.0 + sd ** 2 * np.clip(a, 0, None))), axis=(1, 2)))
        errs.append(e)
    e_all = np.concatenate(errs)
    best = None
    for sd in param_grid_mm:
        v = np.concatenate(v_par[sd])
        for r in residual_grid_mm:
            var = v + 3 * r ** 2  # the residual holds the measurement noise too, as on a task
            s3 = var / 3  # per coordinate of an isotropic error of that RMS norm: e^2 / s3 ~ chi2_3
            ll = float(np.sum(-1.5 * np.log(s3) - 0.5 * e_all ** 2 / s3))
            if best is None or ll > best[0]:
                best = (ll, sd, r, var)
    if best is None:
        raise ModelError("held-out sigma scales: empty grid of parameter priors or residuals")
    _, sd, r, var = best
    return SigmaScales(float(sd), float(r), int(e_all.size), float(np.mean(e_all > 2 * np.sqrt(var))))
