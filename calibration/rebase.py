"""Rebase a fitted model of any kind onto a new day: refit only its base and tool-marker frames.

Model, for a few poses i of the new day (poses in millimetres)::

    T_meas_i ~= T_base @ T_model(q_i) @ T_tool

``T_model`` is the fitted model's pose (kept fixed, evaluated once), ``T_base`` a rigid correction of the base
(mocap-to-base registration) and ``T_tool`` of the tool marker (marker-to-flange), 6 parameters each:
``delta = [dp_base, dtheta_base, dp_tool, dtheta_tool]`` (12,), ``p = dp``, ``R = exp(dtheta)`` (the convention of
:func:`calibration.registration.retract` about the identity). The residuals and their Jacobian are those of
:class:`~calibration.registration.RegistrationProblem` around the model's poses.

A few poses of one region do not see all 12 directions (one cluster barely rotates the tool, so a base and a
tool translation look alike). The weighted Jacobian at ``delta = 0`` is scaled (rotations to millimetres at a
1 m reach) and decomposed by SVD, as :mod:`calibration.identification.observability` does for the geometry;
directions whose singular value is below ``tolerance`` times the largest are held at zero and reported in
plain words, and Levenberg-Marquardt (:mod:`calibration.identification.lm`) fits the rest.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from calibration import so3
from calibration.errors import ModelError
from calibration.identification import DEFAULT_ORIENTATION_WEIGHT
from calibration.identification.lm import Groups, Linearisation, LMSettings, Residuals, StopReason, solve
from calibration.identification.observability import (DEFAULT_REACH_MM, DEFAULT_RELATIVE_TOLERANCE, Observability,
                                                      analyse_jacobian)
from calibration.models.base import KinematicModel
from calibration.models.rebased import RebasedModel, make_T
from calibration.poe import pose_error
from calibration.recording import Recording
from calibration.registration import RegistrationProblem

#: Plain-word names of the 12 correction directions, in ``delta`` order.
DIRECTION_NAMES = tuple(f"{frame} {what}" for frame in ("base", "tool") for what in (
    "x shift", "y shift", "z shift", "rotation about x", "rotation about y", "rotation about z"))
#: The rotation directions of ``delta`` (held when ``rotations=False``).
ROTATION_INDEX = np.array([3, 4, 5, 9, 10, 11])
#: The directions of each frame in ``delta`` (the others are held when ``frames`` leaves that frame out).
FRAME_INDEX = {"base": np.arange(0, 6), "tool": np.arange(6, 12)}


@dataclass(frozen=True)
class RebaseResult:
    """Outcome of :meth:`RebaseProblem.solve`.

    Attributes:
        T_base_correction: left correction (4, 4) [mm] (new base from the model's base frame).
        T_tool_correction: right correction (4, 4) [mm] (new marker in the model's marker frame).
        delta: the 12 correction parameters ``[dp_base mm, dtheta_base rad, dp_tool mm, dtheta_tool rad]``.
        fitted: number of directions fitted (the rest held at zero).
        held: each held direction in plain words (its largest components), empty when all 12 were fitted.
        observability: the SVD analysis of the 12 scaled columns.
        residual_before_mm, residual_after_mm: position error per pose (N,) with the model as is / rebased.
        orientation_before_deg, orientation_after_deg: orientation error per pose (N,).
        converged: LM met a stopping criterion on the cost or the step (never a damping blow-up or the cap).
        reason: why LM stopped.
        iterations: LM iterations.
        seconds: wall time of the solve.
        n_samples: N.
    """

    T_base_correction: np.ndarray
    T_tool_correction: np.ndarray
    delta: np.ndarray
    fitted: int
    held: tuple[str, ...]
    observability: Observability
    residual_before_mm: np.ndarray
    residual_after_mm: np.ndarray
    orientation_before_deg: np.ndarray
    orientation_after_deg: np.ndarray
    converged: bool
    reason: StopReason
    iterations: int
    seconds: float
    n_samples: int

    @property
    def mean_before_mm(self) -> float:
        return float(np.mean(self.residual_before_mm))

    @property
    def mean_after_mm(self) -> float:
        return float(np.mean(self.residual_after_mm))

    def summary(self) -> str:
        """One plain-language paragraph: what moved, what was held and why."""
        dp_b, dp_t = np.linalg.norm(self.delta[0:3]), np.linalg.norm(self.delta[6:9])
        th_b, th_t = np.degrees(np.linalg.norm(self.delta[3:6])), np.degrees(np.linalg.norm(self.delta[9:12]))
        text = (f"Rebased on {self.n_samples} poses: base moved {dp_b:.3f} mm / {th_b:.4f} deg, tool marker "
                f"{dp_t:.3f} mm / {th_t:.4f} deg; position error mean {self.mean_before_mm:.3f} -> "
                f"{self.mean_after_mm:.3f} mm.")
        if self.held:
            text += (f" {12 - self.fitted} of 12 frame directions were held at zero (the poses cannot see them, "
                     f"or they were excluded): {'; '.join(self.held)}. Collect poses that rotate the tool more "
                     "widely to determine them.")
        if not self.converged:
            text += f" The solver did not converge ({self.reason.value})."
        return text

    def model(self, inner: KinematicModel) -> RebasedModel:
        """``inner`` with these corrections (kind ``rebased``), the rebase recorded in its info."""
        info = {"rebase": {"n_samples": self.n_samples, "held": list(self.held), "fitted": self.fitted,
                           "mean_before_mm": self.mean_before_mm, "mean_after_mm": self.mean_after_mm,
                           "converged": self.converged}}
        return RebasedModel(inner.robot, inner.method, inner, self.T_base_correction, self.T_tool_correction,
                            self.fitted, info)


def corrections(delta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(T_base, T_tool)`` (4, 4) from ``delta`` (12,) about the identity."""
    d = np.asarray(delta, dtype=float)
    return make_T(so3.exp(d[3:6]), d[0:3]), make_T(so3.exp(d[9:12]), d[6:9])


class RebaseProblem:
    """Base and tool corrections of a fitted model on a few poses of a new day, built once and then solved.

    Args:
        model: the fitted model (any kind); its pose is evaluated once at ``q``.
        q: joint angles [rad], shape (N, 6).
        R_meas: measured marker orientations, shape (N, 3, 3).
        p_meas: measured marker positions [mm], shape (N, 3).
        a: orientation weight (1641: 1 deg weighs as 1 mm).
        tolerance: relative singular value below which a direction is held at zero.
        reach_mm: length that turns rotation columns into millimetres for the SVD.
        rotations: False holds the six rotation directions (a translation-only rebase).
        frames: the frames to fit, a subset of ``("base", "tool")`` (the other frame's six directions are held).

    Raises:
        ModelError: shapes do not match, values are not finite or a frame name is unknown.
    """

    def __init__(self, model: KinematicModel, q: np.ndarray, R_meas: np.ndarray, p_meas: np.ndarray,
                 a: float = DEFAULT_ORIENTATION_WEIGHT, tolerance: float = DEFAULT_RELATIVE_TOLERANCE,
                 reach_mm: float = DEFAULT_REACH_MM, rotations: bool = True,
                 frames: tuple[str, ...] = ("base", "tool")) -> None:
        self.model = model
        self.q = np.atleast_2d(np.asarray(q, dtype=float))
        if self.q.ndim != 2 or self.q.shape[0] == 0:
            raise ModelError(f"q must be (N, 6) with N >= 1, got {self.q.shape}")
        R_model, p_model = model.fk(self.q)
        self.frames = RegistrationProblem.from_poses(R_model, p_model, R_meas, p_meas, np.eye(4), a,
                                                     check_motion=False)
        self.n_samples = self.frames.n_samples
        J = self.frames.jacobian(np.eye(4), np.eye(4), 1.0)
        unknown = [f for f in frames if f not in FRAME_INDEX]
        if unknown or not frames:
            raise ModelError(f"unknown frame {unknown[0] if unknown else frames!r}; valid: base, tool")
        free = np.zeros(12, dtype=bool)
        for frame in frames:
            free[FRAME_INDEX[frame]] = True
        if not rotations:
            free[ROTATION_INDEX] = False
        scale = np.tile([1.0] * 3 + [1.0 / reach_mm] * 3, 2)
        self.free = free
        self.observability = analyse_jacobian(J[:, :, free], scale[free],
                                              tuple(n for n, f in zip(DIRECTION_NAMES, free) if f), a, tolerance)
        basis = np.zeros((12, self.observability.rank))
        basis[free] = self.observability.basis
        self.basis = basis
        self.held = tuple(f"{name} (excluded)" for name, f in zip(DIRECTION_NAMES, free) if not f) + tuple(
            _describe_free(self.observability, i, free) for i in range(self.observability.rank, int(free.sum())))

    @classmethod
    def from_recording(cls, model: KinematicModel, rec: Recording, **options: Any) -> "RebaseProblem":
        """The problem on a recording's poses (``options`` as in the constructor)."""
        return cls(model, rec.q, rec.R, rec.p, **options)  # type: ignore[arg-type]

    # -- the least-squares problem of calibration.identification.lm, in the coordinates z of the basis --

    @property
    def shape(self) -> tuple[int, int]:
        return 1, self.basis.shape[1]

    @property
    def groups(self) -> Groups:
        return Groups.single(self.n_samples)

    def residuals(self, z: np.ndarray) -> Residuals:
        T_b, T_t = corrections(self.basis @ z[0])
        return Residuals(self.frames.residuals(T_b, T_t))

    def linearise(self, z: np.ndarray, at: Residuals | None) -> Linearisation:
        """Exact Jacobian in z: the registration's (left perturbations) times the left Jacobians of the
        rotation vectors, times the basis."""
        delta = self.basis @ z[0]
        T_b, T_t = corrections(delta)
        chart = np.eye(12)
        chart[3:6, 3:6] = so3.left_jacobian(delta[3:6])
        chart[9:12, 9:12] = so3.left_jacobian(delta[9:12])
        J = self.frames.jacobian(T_b, T_t) @ (chart @ self.basis)
        return Linearisation(at if at is not None else Residuals(self.frames.residuals(T_b, T_t)), J)

    def solve(self, settings: LMSettings = LMSettings(max_iter=100, cost_rtol=1e-12, step_atol=1e-12)
              ) -> RebaseResult:
        """LM from the identity along the observable directions; the held ones stay at zero."""
        start = time.perf_counter()
        res = solve(self, None, settings)
        delta = self.basis @ res.z[0]
        T_b, T_t = corrections(delta)
        R0, p0 = self.frames.R_bf, self.frames.p_bf
        R1, p1 = self.frames.predict(T_b, T_t)
        R_meas, p_meas = self.frames.R_meas, self.frames.p_meas
        before, after = pose_error(R_meas, p_meas, R0, p0), pose_error(R_meas, p_meas, R1, p1)
        return RebaseResult(T_b, T_t, delta, self.observability.rank, self.held, self.observability,
                            before[0], after[0], before[1], after[1], bool(res.converged[0]), res.reason[0],
                            int(res.iterations[0]), time.perf_counter() - start, self.n_samples)


def _describe_free(obs: Observability, index: int, free: np.ndarray) -> str:
    """A held direction of the free columns, in plain words."""
    v = np.zeros(12)
    v[free] = obs.V[:, index]
    order = [j for j in np.argsort(-np.abs(v))[:3] if abs(v[j]) > 0.2]
    terms = " and ".join(f"{DIRECTION_NAMES[j]} ({v[j]:+.2f})" for j in order)
    rel = obs.singular_values[index] / obs.singular_values[0]
    return f"{terms} together (relative singular value {rel:.1e})"


def rebase(model: KinematicModel, rec: Recording, **options: Any) -> tuple[RebasedModel, RebaseResult]:
    """Refit ``model``'s base and tool-marker frames on ``rec`` (a few poses of the new day).

    Returns:
        The rebased model (kind ``rebased``) and the result (corrections, residuals, held directions).
    """
    result = RebaseProblem.from_recording(model, rec, **options).solve()
    return result.model(model), result


#: The candidates of :func:`choose_directions`, fewest parameters first.
CHOICES = ("translations", "frames")


def choose_directions(model: KinematicModel, rec: Recording, cluster_size: int = 7, **options: Any
                      ) -> tuple[str, dict[str, float]]:
    """Both frames (12 directions) or their translations only (6), chosen on ``rec`` itself.

    Each cluster is held out in turn from a rebase on the others; the translations win unless the full frames'
    held-out mean position error is lower by more than its standard error over the held-out poses (the
    fewest-parameters-within-one-standard-error rule). With fewer than 2 clusters (or poses without a cluster
    column whose count is not a multiple of ``cluster_size``): the full frames. On the shared
    days' cross-day pairs, a translation-only rebase on 3 clusters is tied with the full one on the new day's other
    training clusters (median 0.214 against 0.215 mm; ``scripts/bench_rebase_variants.py``).

    Returns:
        ``"translations"`` or ``"frames"``, and each candidate's held-out mean [mm] (empty with < 2 clusters).
    """
    if "cluster" not in rec.extra and len(rec) % cluster_size:
        return "frames", {}  # no clusters to hold out (poses that are not the 7-pose design): as before the choice
    cluster = rec.clusters(cluster_size)
    ids = np.unique(cluster)
    if ids.size < 2:
        return "frames", {}
    errs = {}
    for choice in CHOICES:
        parts = []
        for c in ids:
            fitted = RebaseProblem.from_recording(model, rec.subset(cluster != c), rotations=choice == "frames",
                                                  **options).solve()
            held = rec.subset(cluster == c)
            parts.append(pose_error(held.R, held.p, *fitted.model(model).fk(held.q))[0])
        errs[choice] = np.concatenate(parts)
    means = {k: float(np.mean(v)) for k, v in errs.items()}
    best = min(means, key=means.get)
    limit = means[best] + float(np.std(errs[best], ddof=1) / np.sqrt(errs[best].size))
    return next(k for k in CHOICES if means[k] <= limit), means


def rebase_auto(model: KinematicModel, rec: Recording, cluster_size: int = 7, **options: Any
                ) -> tuple[RebasedModel, RebaseResult, str]:
    """:func:`rebase` along the directions :func:`choose_directions` picks; also returns the choice."""
    choice, _ = choose_directions(model, rec, cluster_size, **options)
    rebased, result = rebase(model, rec, rotations=choice == "frames", **options)
    return rebased, result, choice
