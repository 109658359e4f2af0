"""One-sided measurement shifts (calibration.diagnosis.shifts): planted shifts are found, symmetric errors are not."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.diagnosis.shifts import ONE_SIDED_SHARE, one_sided_shift
from calibration.errors import ModelError

N = 1736
SIGMA_MM = 0.08  # per axis: about the R1 training recordings' residual


def _noise(seed: int) -> np.ndarray:
    return np.random.default_rng(seed).normal(0.0, SIGMA_MM, (N, 3))


@pytest.mark.parametrize("seed", range(5))
def test_planted_shift_is_found_with_its_direction_and_poses(seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    v = rng.normal(size=3)
    v /= np.linalg.norm(v)
    r = _noise(seed)
    planted = rng.random(N) < 0.05
    r[planted] += 0.6 * v
    s = one_sided_shift(r)
    assert s.found
    assert s.one_sided_share >= ONE_SIDED_SHARE
    assert float(s.direction @ v) > 0.98
    found, truth = s.shifted, planted
    assert np.sum(found & truth) >= 0.9 * truth.sum()  # most planted poses are found
    assert np.sum(found & ~truth) <= 0.01 * N  # and few others
    np.testing.assert_allclose(s.mean_shift_mm, 0.6, atol=0.1)


@pytest.mark.parametrize("seed", range(5))
def test_symmetric_residual_is_not_a_shift(seed: int) -> None:
    """Gaussian noise, and noise plus a smooth error of both signs (what a model-form error leaves), give none."""
    r = _noise(seed)
    assert not one_sided_shift(r).found
    t = np.linspace(0, 4 * np.pi, N)
    smooth = r + 0.3 * np.sin(t)[:, None] * np.array([0.6, 0.0, 0.8])
    s = one_sided_shift(smooth)
    assert not s.found and s.one_sided_share < ONE_SIDED_SHARE


@pytest.mark.parametrize("seed", range(5))
def test_jumps_of_both_signs_are_not_one_sided(seed: int) -> None:
    """Outliers of both signs along one direction (heavy-tailed noise, not a shift) are left alone."""
    rng = np.random.default_rng(200 + seed)
    r = _noise(seed)
    jump = rng.random(N) < 0.05
    r[jump] += 0.6 * np.where(rng.random(jump.sum()) < 0.5, 1.0, -1.0)[:, None] * np.array([0.0, 0.6, 0.8])
    s = one_sided_shift(r)
    assert abs(s.one_sided_share - 0.5) < 0.2
    assert not s.found


def test_bad_shape_is_refused() -> None:
    with pytest.raises(ModelError, match=r"\(N >= 20, 3\)"):
        one_sided_shift(np.zeros((10, 3)))
    with pytest.raises(ModelError, match="shape"):
        one_sided_shift(np.zeros((100, 2)))


def test_equal_residuals_find_nothing() -> None:
    s = one_sided_shift(np.ones((50, 3)))
    assert not s.found and s.mean_shift_mm == 0.0
