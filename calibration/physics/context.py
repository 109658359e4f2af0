"""The context an effect reads besides the joint angles (a :data:`Context` mapping of named arrays: the joint
directions and velocities among them), its checks and the fitted span of a channel, at the bottom of ``physics``."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from calibration.errors import ModelError
from calibration.kinematics.poe import PoeModel

Context = Mapping[str, Any]


#: Past which edges of the training range an effect's fitted shape in a context entry is a guess (see
#: :meth:`Effect.fitted_context`): both, or only above (a warm-up curve is pinned at zero at ``t = 0`` by its formula).
Sides = Literal["both", "above"]


@dataclass(frozen=True)
class FittedSpan:
    """How an effect's fitted shape depends on a context entry: ``span`` over which the shape shows itself (in the
    entry's unit; a warm-up's time constant [s], the span of an exponential approach to its asymptote) and the
    ``sides`` of the training range past which it is a guess."""

    span: float
    sides: Sides = "both"


def check_q(model: PoeModel, q: np.ndarray) -> np.ndarray:
    """Joint angles as a float array (N, n), or ModelError naming the expected shape."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    if q.ndim != 2 or q.shape[1] != model.n_joints:
        raise ModelError(f"q must have shape (N, {model.n_joints}), got {q.shape}")
    return q


def context_array(context: Context | None, key: str, N: int, default: float = 0.0) -> np.ndarray:
    """One per-sample context entry broadcast to shape (N,).

    Args:
        context: the context mapping (may be None).
        key: entry name (``t``, ``temp_c``, ``payload_kg``, ``dir3``).
        N: number of samples.
        default: value used when the key is absent.
    """
    if context is None or key not in context or context[key] is None:
        return np.full(N, float(default))
    a = np.asarray(context[key], dtype=float)
    if a.ndim > 1 or (a.ndim == 1 and a.shape[0] not in (1, N)):
        raise ModelError(f"context[{key!r}] must be a scalar or have shape ({N},), got {a.shape}")
    return np.broadcast_to(a, (N,)).astype(float)


def context_dirs(context: Context | None, N: int, n: int) -> np.ndarray:
    """Approach directions ``dir1..dirn`` stacked to shape (N, n), entries in {-1, 0, 1}."""
    d = np.stack([context_array(context, f"dir{i + 1}", N) for i in range(n)], axis=1)
    if not np.all(np.isin(d, (-1.0, 0.0, 1.0))):
        raise ModelError("context dir1..dir6 must contain only -1, 0 or 1")
    return d


def context_qd(context: Context | None, N: int, n: int) -> np.ndarray:
    """Joint velocities ``qd`` [rad/s] as shape (N, n) (zeros when absent)."""
    if context is None or context.get("qd") is None:
        return np.zeros((N, n))
    qd = np.asarray(context["qd"], dtype=float)
    if qd.shape != (N, n):
        raise ModelError(f"context['qd'] must have shape ({N}, {n}), got {qd.shape}")
    return qd


def check_joints(joints: tuple[int, ...], n: int = 6) -> tuple[int, ...]:
    """Validate 1-based joint numbers."""
    joints = tuple(int(j) for j in joints)
    if not joints or any(j < 1 or j > n for j in joints) or len(set(joints)) != len(joints):
        raise ModelError(f"joints must be distinct numbers in 1..{n}, got {list(joints)}")
    return joints
