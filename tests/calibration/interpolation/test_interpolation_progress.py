"""The epoch callback of the neural interpolators reports every epoch and leaves the trained network unchanged."""

import numpy as np
import pytest

pytest.importorskip("sklearn")

from calibration.interpolation import make_interpolator  # noqa: E402


@pytest.mark.parametrize("kind", ["nn", "ae"])
def test_progress_reports_each_epoch_and_changes_nothing(kind):
    rng = np.random.default_rng(0)
    x, y = rng.uniform(-1, 1, (40, 2)), rng.normal(size=(40, 5))
    options = {"hidden": (16, 16), "max_iter": 12, "random_state": 4}
    calls = []
    plain = make_interpolator(kind, **options).fit(x, y)
    reported = make_interpolator(kind, progress=lambda e, n: calls.append((e, n)), **options).fit(x, y)
    assert calls == [(e, 12) for e in range(1, 13)]
    probe = rng.uniform(-1, 1, (25, 2))
    np.testing.assert_array_equal(plain.predict(probe), reported.predict(probe))
    assert plain.to_dict() == reported.to_dict()  # the callback is not saved with the model
