"""One-sided measurement shifts: a recording whose measured position jumps by one fixed vector on some poses.

Noise, and a smooth model error sampled over many configurations, leave large residuals of both signs along
any fixed direction. A measurement that, on some poses, lands a fixed vector away from where it lands on the
others (a marker of the rigid body mis-identified or partly occluded, say) leaves large residuals of one sign
along that vector. :func:`one_sided_shift` tells the two apart from a position residual alone: it takes the
principal direction of the largest residuals and counts how many of them lie on one side of it.

No smooth kinematic model can follow such a shift, and none can predict on which poses of another recording it
happens: it sets a floor under the largest error any model reaches on a recording that has it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from calibration.errors import ModelError

#: Share of the largest residuals that must lie on the +direction side for the shift to count as one-sided.
#: Symmetric residuals give about 0.5: the pi fit's residual on six of the eight R1 training recordings gives
#: 0.55-0.62, on 0613 and 0627 after 0.91 and 0.98 (``python scripts/studies/sameday_causes.py``).
ONE_SIDED_SHARE = 0.8
#: Residuals above this quantile of the error norm define the direction.
LARGE_QUANTILE = 95.0
#: A pose is shifted when its projection on the direction exceeds the median by this many (scaled) MADs.
MAD_FACTOR = 3.5


@dataclass(frozen=True)
class OneSidedShift:
    """What :func:`one_sided_shift` found.

    Attributes:
        direction: unit vector (3,) of the largest residuals, signed so that most of them lie on its + side.
        one_sided_share: share of the largest residuals with a positive projection on ``direction`` [-].
        shifted: per pose (N,), True where the projection is beyond the median + MAD_FACTOR scaled MADs; all
            False unless the share reaches ONE_SIDED_SHARE.
        mean_shift_mm: mean projection of the shifted poses minus the median projection [mm] (0 when none).
    """

    direction: np.ndarray
    one_sided_share: float
    shifted: np.ndarray
    mean_shift_mm: float

    @property
    def found(self) -> bool:
        return bool(self.shifted.any())

    def message(self, subject: str = "training recording") -> str:
        """One sentence for a warning; empty when nothing was found."""
        if not self.found:
            return ""
        d = ", ".join(f"{v:+.2f}" for v in self.direction)
        return (f"the {subject} has {int(self.shifted.sum())} of {self.shifted.size} poses whose measured position "
                f"jumps by {self.mean_shift_mm:.2f} mm along one direction ({d}, base frame) while the others do "
                "not: a measurement artefact no kinematic model can follow; the largest errors on recordings of "
                "this session include such jumps")

    def to_json(self) -> dict[str, Any]:
        return {"found": self.found, "shifted_poses": int(self.shifted.sum()), "poses": int(self.shifted.size),
                "direction": [float(v) for v in self.direction], "one_sided_share": self.one_sided_share,
                "mean_shift_mm": self.mean_shift_mm, "warning": self.message()}


def one_sided_shift(residual_mm: np.ndarray, share: float = ONE_SIDED_SHARE) -> OneSidedShift:
    """Look for a one-sided shift in a position residual (measured minus model) ``residual_mm`` (N, 3) [mm].

    Raises:
        ModelError: fewer than 20 poses (the largest 5 % would be a single pose) or not shaped (N, 3).
    """
    r = np.asarray(residual_mm, dtype=float)
    if r.ndim != 2 or r.shape[1] != 3 or r.shape[0] < 20:
        raise ModelError(f"one_sided_shift needs a residual of shape (N >= 20, 3), got {r.shape}")
    e = np.linalg.norm(r, axis=1)
    large = e > np.percentile(e, LARGE_QUANTILE)
    if not large.any():  # every residual equal: nothing stands out
        return OneSidedShift(np.zeros(3), 0.5, np.zeros(len(r), bool), 0.0)
    direction = np.linalg.svd(r[large], full_matrices=False)[2][0]
    if np.median(r[large] @ direction) < 0:
        direction = -direction
    proj = r @ direction
    one_sided = float(np.mean(proj[large] > 0))
    if one_sided < share:
        return OneSidedShift(direction, one_sided, np.zeros(len(r), bool), 0.0)
    median = float(np.median(proj))
    mad = 1.4826 * float(np.median(np.abs(proj - median)))
    shifted = proj > median + MAD_FACTOR * mad
    return OneSidedShift(direction, one_sided, shifted, float(proj[shifted].mean() - median) if shifted.any() else 0.0)
