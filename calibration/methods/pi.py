"""The physics-informed (pi) method's pieces outside the fitter: the prior that frees the base frame
(:func:`base_free_prior`)."""

from __future__ import annotations

import numpy as np


def base_free_prior(weights: np.ndarray, B: np.ndarray) -> np.ndarray:
    """The prior matrix (m, m) of the diagonal prior ``|w * x|^2`` made blind to the rigid motions ``B`` (m, 6) of
    the arm: ``|W P x|^2`` with ``P = I - B (B^T W^2 B)^-1 B^T W^2``, i.e. the prior of ``x`` less its best rigid
    motion, so a base-frame error costs the fit nothing and the damping acts on what is left."""
    W2B = (weights ** 2)[:, None] * B
    P = np.eye(len(weights)) - B @ np.linalg.solve(B.T @ W2B, W2B.T)
    return weights[:, None] * P
