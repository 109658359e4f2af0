"""Observability of identification parameters on a given data set.

The identification Jacobian is scaled so every parameter is in millimetres of tool motion (tilts times a
characteristic reach), then decomposed by SVD. Directions whose singular value is a small fraction of the
largest cannot be seen by the data; fits keep them at their reference instead of letting them drift,
which is what stops a global fit from extrapolating worse than the nominal model.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calibration.errors import ModelError
from calibration.identification.geometric import DEFAULT_ORIENTATION_WEIGHT, Kinematics, rotation_residual_scale
from calibration.kinematics.arrays import FloatArray

DEFAULT_REACH_MM = 1000.0
DEFAULT_RELATIVE_TOLERANCE = 1e-2


@dataclass(frozen=True)
class Observability:
    """Singular-value analysis of the scaled identification Jacobian.

    Attributes:
        singular_values: descending, shape (m,) [mm of residual per mm-equivalent parameter change].
        condition_number: largest over smallest singular value (inf when rank deficient).
        scale: column scaling (parameter units per mm-equivalent), shape (m,).
        V: right singular vectors in scaled coordinates, columns, shape (m, m).
        rank: number of directions kept (relative singular value >= tolerance).
        tolerance: relative singular-value threshold used.
        names: parameter names.
    """

    singular_values: np.ndarray
    condition_number: float
    scale: np.ndarray
    V: np.ndarray
    rank: int
    tolerance: float
    names: tuple[str, ...]

    @property
    def basis(self) -> np.ndarray:
        """(m, rank) matrix whose columns span the observable parameter directions (unscaled units)."""
        basis: FloatArray = self.scale[:, None] * self.V[:, : self.rank]
        return basis

    def unobservable(self, top: int = 3) -> list[str]:
        """Each hidden direction described by its largest parameter contributions."""
        out = []
        for i in range(self.rank, len(self.singular_values)):
            v = self.V[:, i]
            order = np.argsort(-np.abs(v))[:top]
            terms = " ".join(f"{v[j]:+.2f}*{self.names[j]}" for j in order)
            rel = self.singular_values[i] / self.singular_values[0]
            out.append(f"{terms} (relative singular value {rel:.1e})")
        return out

    def hidden_joints(self) -> list[int]:
        """Joints (1-based) whose parameters dominate the hidden directions."""
        joints: set[int] = set()
        for i in range(self.rank, len(self.singular_values)):
            for j in np.argsort(-np.abs(self.V[:, i]))[:2]:
                head = self.names[j].split("_")[0]
                if head[-1].isdigit():
                    joints.add(int(head[-1]))
        return sorted(joints)

    def summary(self, damped: bool = False) -> str:
        """A plain-language warning for users, empty when everything is observable.

        Args:
            damped: the fit damps hidden directions toward nominal (Tikhonov filter) instead of holding them.
        """
        hidden = len(self.singular_values) - self.rank
        if hidden == 0:
            return ""
        how = "damped toward" if damped else "kept at"
        return (f"The data cannot see {hidden} of {len(self.singular_values)} parameter directions "
                f"(condition number {self.condition_number:.3g}); they mostly involve joints "
                f"{', '.join(map(str, self.hidden_joints()))}. These are {how} their reference values, so the "
                "model is only as good as the nominal one along them: to calibrate them, collect poses that move "
                "those joints over a wider range.")


def analyse(kin: Kinematics, q: np.ndarray, x: np.ndarray | None = None,
            a: float = DEFAULT_ORIENTATION_WEIGHT, tolerance: float = DEFAULT_RELATIVE_TOLERANCE,
            reach_mm: float = DEFAULT_REACH_MM) -> Observability:
    """Observability of ``kin``'s parameters on joint samples ``q`` (N, n) around ``x`` (default nominal).

    ``kin`` provides ``size``, ``jacobian(q, x)``, ``names()`` and ``scale(reach_mm)`` (parameter units per
    millimetre of tool motion).
    """
    x = np.zeros(kin.size) if x is None else np.asarray(x, dtype=float)
    _, _, J = kin.jacobian(q, x)
    return analyse_jacobian(J, kin.scale(reach_mm), tuple(kin.names()), a, tolerance)


def analyse_jacobian(J: np.ndarray, scale: np.ndarray, names: tuple[str, ...], a: float = DEFAULT_ORIENTATION_WEIGHT,
                     tolerance: float = DEFAULT_RELATIVE_TOLERANCE) -> Observability:
    """Observability from a pose Jacobian ``d[p; theta] / d params`` (N, 6, m) and the column scaling (m,)."""
    Js = scaled_rows(J, scale, a).reshape(-1, np.shape(J)[-1])
    m = Js.shape[1]
    # fewer equations than parameters (one pose, or none): the directions past the rows are unseen, singular value 0
    # (they were missing from V, and a caller naming them, a one-row recording's frame check, raised IndexError)
    _, s, Vt = np.linalg.svd(Js, full_matrices=Js.shape[0] < m)
    s = np.concatenate([s, np.zeros(m - len(s))])
    if not s.size or s[0] == 0:
        raise ModelError(f"no information in the data: the pose Jacobian is zero ({Js.shape[0] // 6} poses)")
    rank = int(np.sum(s >= tolerance * s[0]))
    cond = float(s[0] / s[-1]) if s[-1] > 0 else float("inf")
    return Observability(s, cond, np.asarray(scale, dtype=float), Vt.T, rank, tolerance, tuple(names))


def scaled_rows(J: np.ndarray, scale: np.ndarray, a: float = DEFAULT_ORIENTATION_WEIGHT) -> np.ndarray:
    """The pose Jacobian (N, 6, m) as the fits weight it: rotation rows times ``sqrt(2 a)``, columns in
    millimetre-equivalent units (times ``scale``), shape (N, 6, m)."""
    J = np.array(J, dtype=float)
    J[:, 3:] *= rotation_residual_scale(a)
    J_scaled: FloatArray = J * np.asarray(scale, dtype=float)
    return J_scaled


def filter_weights(obs: Observability) -> np.ndarray:
    """Prior weights (m,) of the Tikhonov filter at the truncation cutoff: ``tolerance * s_max / scale``.

    Used as ``prior_weight`` of a least-squares fit, directions whose scaled singular value is well above the
    cutoff are fitted as without a prior; those below it are damped smoothly toward the prior's reference
    (nominal) instead of being cut off.
    """
    weights: FloatArray = obs.tolerance * obs.singular_values[0] / obs.scale
    return weights


def base_free_prior(weights: np.ndarray, B: np.ndarray) -> np.ndarray:
    """The prior matrix (m, m) of the diagonal prior ``|w * x|^2`` made blind to the rigid motions ``B`` (m, 6) of
    the arm: ``|W P x|^2`` with ``P = I - B (B^T W^2 B)^-1 B^T W^2``, i.e. the prior of ``x`` less its best rigid
    motion, so a base-frame error costs the fit nothing and the damping acts on what is left."""
    W2B = (weights ** 2)[:, None] * B
    P = np.eye(len(weights)) - B @ np.linalg.solve(B.T @ W2B, W2B.T)
    W: FloatArray = weights[:, None] * P
    return W
