"""The one Levenberg-Marquardt solver of the package: damping, acceptance, stopping and an honest result.

A problem (:class:`LeastSquaresProblem`) is ``G`` independent nonlinear least-squares problems in ``k``
variables each, solved at once (G = 1 for a single problem). It supplies its weighted residual rows, stored
contiguously per problem, an optional prior (Tikhonov) residual per problem, and their Jacobians; the cost of
problem ``g`` is ``sum |r_i|^2 + |r_prior_g|^2``. The solver owns everything else: the normal equations per
problem, the Marquardt-scaled damped step, acceptance (a step is taken only if it lowers the cost), the damping
schedule and the stopping rules. It reports per problem why it stopped (:class:`StopReason`); only a stopping
criterion on the cost or the step counts as converged, never a damping that exceeded its cap nor the
iteration cap.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from enum import Enum
from typing import Any, Literal, Protocol, cast

import numpy as np

from calibration.errors import ModelError
from calibration.kinematics.arrays import FloatArray


class StopReason(str, Enum):
    """Why the solver stopped one problem."""

    COST = "cost"  # an accepted step lowered the cost by less than cost_rtol (relative): converged
    STEP = "step"  # the step norm fell below step_atol (or there is nothing to fit): converged
    DAMPING = "damping"  # no step lowered the cost until the damping exceeded damping_max: not converged
    ITERATIONS = "iterations"  # max_iter iterations ran without a stopping criterion: not converged

    @property
    def converged(self) -> bool:
        return self in (StopReason.COST, StopReason.STEP)


@dataclass(frozen=True)
class LMSettings:
    """Damping schedule, stopping rules and linear solver.

    Attributes:
        max_iter: iteration cap.
        cost_rtol: an accepted step whose relative cost decrease is below this stops the problem (converged).
        step_atol: a step whose norm (in the problem's variables) is below this stops the problem (converged);
            0 disables the rule.
        damping0: initial damping ``lambda``.
        damping_min: floor of ``lambda`` after accepted steps.
        damping_max: a rejected step that raises ``lambda`` above this stops the problem (not converged).
        damping_up: factor on ``lambda`` after a rejected step.
        damping_down: divisor of ``lambda`` after an accepted step.
        diag_floor: added to ``diag(J^T J)`` in the Marquardt scaling (keeps a zero column regular).
        linear_solver: ``lu``: one batched LU solve for all problems (needs a regular damped system: positive
            ``diag_floor``); ``lstsq``: minimum-norm least squares per problem (rank-deficient systems).
    """

    max_iter: int = 50
    cost_rtol: float = 1e-6
    step_atol: float = 0.0
    damping0: float = 1e-3
    damping_min: float = 1e-9
    damping_max: float = 1e8
    damping_up: float = 4.0
    damping_down: float = 3.0
    diag_floor: float = 1e-12
    linear_solver: Literal["lu", "lstsq"] = "lu"

    def __post_init__(self) -> None:
        if self.max_iter < 0 or self.cost_rtol < 0 or self.step_atol < 0 or self.diag_floor < 0:
            raise ModelError("max_iter, cost_rtol, step_atol and diag_floor must be >= 0")
        if not 0 < self.damping_min <= self.damping0 <= self.damping_max:
            raise ModelError(f"need 0 < damping_min <= damping0 <= damping_max, got {self.damping_min}, "
                             f"{self.damping0}, {self.damping_max}")
        if self.damping_up <= 1 or self.damping_down <= 1:
            raise ModelError("damping_up and damping_down must be > 1")
        if self.linear_solver not in ("lu", "lstsq"):
            raise ModelError(f"linear_solver must be 'lu' or 'lstsq', got {self.linear_solver!r}")


@dataclass(frozen=True)
class Groups:
    """Which residual rows belong to which problem: rows of problem g are ``starts[g] : starts[g] + counts[g]``."""

    starts: np.ndarray
    counts: np.ndarray

    @classmethod
    def single(cls, n_rows: int) -> Groups:
        return cls(np.array([0]), np.array([n_rows]))

    @classmethod
    def sorted_from_index(cls, index: np.ndarray) -> tuple[np.ndarray, Groups]:
        """Row order that makes each problem's rows contiguous, and the groups of the reordered rows.

        Args:
            index: problem index of each row, shape (N,), values 0..G-1, each present.
        """
        counts = np.bincount(index)
        if np.any(counts == 0):
            raise ModelError("every group index 0..G-1 must have at least one sample")
        return np.argsort(index, kind="stable"), cls(np.concatenate([[0], np.cumsum(counts)[:-1]]), counts)

    @property
    def n(self) -> int:
        return len(self.counts)

    @property
    def equal(self) -> bool:
        return bool(np.all(self.counts == self.counts[0]))

    def sum(self, values: np.ndarray) -> np.ndarray:
        """Per-problem sums of per-row values (N, ...) -> (G, ...)."""
        return np.add.reduceat(values, self.starts, axis=0)


@dataclass(frozen=True)
class Residuals:
    """Residuals of all problems at one point.

    Attributes:
        r: weighted residual rows, shape (N, d), each problem's rows contiguous (see :class:`Groups`).
        prior: prior residuals per problem, shape (G, p), or None.
        extra: whatever the problem wants back in :meth:`LeastSquaresProblem.linearise` (e.g. rotation errors).
    """

    r: np.ndarray
    prior: np.ndarray | None = None
    extra: Any = None


@dataclass(frozen=True)
class Linearisation:
    """Residuals and Jacobians at one point: ``J`` (N, d, k) = d r / d z, ``J_prior`` (p, k) shared by all problems."""

    residuals: Residuals
    J: np.ndarray
    J_prior: np.ndarray | None = None


class LeastSquaresProblem(Protocol):
    """What the solver needs from a problem: its size, its row groups, residuals and Jacobians."""

    @property
    def shape(self) -> tuple[int, int]: ...  # (G problems, k variables each)

    @property
    def groups(self) -> Groups: ...

    def residuals(self, z: np.ndarray) -> Residuals: ...  # z: (G, k)

    def linearise(self, z: np.ndarray, at: Residuals | None) -> Linearisation: ...  # at: residuals at z, if known


@dataclass(frozen=True)
class LMResult:
    """Outcome of one (batched) solve.

    Attributes:
        z: solution, shape (G, k).
        cost: final cost per problem, shape (G,).
        residuals: residuals at ``z``.
        iterations: iterations each problem ran before it stopped, shape (G,).
        reason: why each problem stopped.
        seconds: wall time of the solve.
        evaluation_seconds: part of it spent in the problem's residuals and Jacobians.
    """

    z: np.ndarray
    cost: np.ndarray
    residuals: Residuals
    iterations: np.ndarray
    reason: tuple[StopReason, ...]
    seconds: float
    evaluation_seconds: float

    @property
    def converged(self) -> np.ndarray:
        """Per problem: a stopping criterion on the cost or the step was met, shape (G,)."""
        return np.array([r.converged for r in self.reason], dtype=bool)


def cost(groups: Groups, res: Residuals) -> np.ndarray:
    """Cost per problem (G,): ``sum |r_i|^2 + |r_prior|^2``."""
    c = groups.sum(np.sum(res.r * res.r, axis=1))
    if res.prior is not None:
        c = c + np.sum(res.prior * res.prior, axis=1)
    return c


def normal_equations(groups: Groups, lin: Linearisation) -> tuple[np.ndarray, np.ndarray]:
    """Per-problem ``J^T J`` (G, k, k) and ``J^T r`` (G, k), prior included."""
    J, r = lin.J, lin.residuals.r
    G, k = groups.n, J.shape[-1]
    if groups.equal:  # equal problems: one batched product
        Jg = J.reshape(G, -1, k)
        JgT = np.swapaxes(Jg, 1, 2)
        A, g = JgT @ Jg, (JgT @ r.reshape(G, -1, 1))[..., 0]
    else:
        JT = np.swapaxes(J, 1, 2)
        A, g = groups.sum(JT @ J), groups.sum((JT @ r[:, :, None])[..., 0])
    if lin.J_prior is not None and lin.residuals.prior is not None:
        A = A + lin.J_prior.T @ lin.J_prior
        g = g + lin.residuals.prior @ lin.J_prior
    return A, g


def damped_step(A: np.ndarray, g: np.ndarray, lam: np.ndarray, settings: LMSettings) -> np.ndarray:
    """Solve ``(A + lam diag(diag(A) + floor)) step = -g`` per problem; shape (G, k)."""
    diag = np.einsum("gii->gi", A) + settings.diag_floor
    if settings.linear_solver == "lu":
        k = A.shape[-1]
        return np.linalg.solve(A + lam[:, None, None] * (diag[:, :, None] * np.eye(k)), -g[:, :, None])[..., 0]
    return np.stack([np.linalg.lstsq(A[i] + lam[i] * np.diag(diag[i]), -g[i], rcond=None)[0] for i in range(len(A))])


class _Clock:
    """Wall time spent in the problem's callbacks."""

    def __init__(self, problem: LeastSquaresProblem) -> None:
        self.problem, self.seconds = problem, 0.0

    def residuals(self, z: np.ndarray) -> Residuals:
        t = time.perf_counter()
        out = self.problem.residuals(z)
        self.seconds += time.perf_counter() - t
        return out

    def linearise(self, z: np.ndarray, at: Residuals | None) -> Linearisation:
        t = time.perf_counter()
        out = self.problem.linearise(z, at)
        self.seconds += time.perf_counter() - t
        return out


def solve(problem: LeastSquaresProblem, z0: np.ndarray | None = None, settings: LMSettings = LMSettings()
          ) -> LMResult:
    """Levenberg-Marquardt on every problem at once, from ``z0`` (default zeros).

    Each iteration solves the damped normal equations of the problems still running, evaluates the cost at the
    trial point and accepts the step of each problem whose cost it lowers (damping / ``damping_down``) or
    rejects it (damping * ``damping_up``). A problem stops when an accepted step changed its cost by less than
    ``cost_rtol`` or its step is shorter than ``step_atol`` (converged), or when its damping exceeds
    ``damping_max`` (not converged); the rest stop at ``max_iter`` (not converged).
    """
    start = time.perf_counter()
    G, k = problem.shape
    groups, clock = problem.groups, _Clock(problem)
    z = np.zeros((G, k)) if z0 is None else np.broadcast_to(np.asarray(z0, dtype=float), (G, k)).copy()
    reason = [StopReason.ITERATIONS] * G
    iterations = np.full(G, settings.max_iter)
    done = np.zeros(G, dtype=bool)
    if k == 0:  # nothing to fit: the step is identically zero
        reason, iterations[:], done[:] = [StopReason.STEP] * G, 0, True
    lam = np.full(G, settings.damping0)
    lin = clock.linearise(z, None) if not done.all() else None
    current = cost(groups, lin.residuals) if lin is not None else None
    known = lin.residuals if lin is not None else None  # residuals at z, when the solver has them
    for it in range(1, settings.max_iter + 1):
        if done.all():
            break
        # lin and current are None only when every problem was done before the first iteration (then it broke above)
        lin_z, cost_z = cast(Linearisation, lin), cast(FloatArray, current)
        step = damped_step(*normal_equations(groups, lin_z), lam, settings)
        step[done] = 0.0
        trial = clock.residuals(z + step)
        cost_try = cost(groups, trial)
        better = cost_try < cost_z
        rel = np.abs(cost_z - cost_try) / np.maximum(cost_z, 1e-300)
        lam = np.where(better, np.maximum(lam / settings.damping_down, settings.damping_min), lam * settings.damping_up)
        stops = [(StopReason.COST, better & (rel < settings.cost_rtol)),
                 (StopReason.STEP, np.linalg.norm(step, axis=1) < settings.step_atol),
                 (StopReason.DAMPING, lam > settings.damping_max)]
        for why, hit in stops:
            hit = hit & ~done
            if hit.any():
                reason = [why if h else r for r, h in zip(reason, hit)]
                iterations[hit], done = it, done | hit
        z = np.where(better[:, None], z + step, z)
        if better.any():
            known = trial if better.all() else None
            if not done.all():
                lin = clock.linearise(z, known)
                current, known = cost(groups, lin.residuals), lin.residuals
    final = known if known is not None else clock.residuals(z)
    return LMResult(z, cost(groups, final), final, iterations, tuple(reason),
                    time.perf_counter() - start, clock.seconds)
