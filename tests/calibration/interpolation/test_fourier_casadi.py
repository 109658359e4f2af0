"""casadi form of the Fourier interpolators: equal to predict, with exact derivatives."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.errors import ModelError
from calibration.interpolation.fourier import Fourier13Interpolator, FourierReducedInterpolator

ca = pytest.importorskip("casadi")


def _fitted(cls, **kw):
    rng = np.random.default_rng(4)
    x = rng.uniform(-1.0, 1.0, (40, 2))
    y = np.column_stack([np.sin(x[:, 0]) * k + np.cos(x[:, 1] + x[:, 0]) for k in range(5)])
    return cls(**kw).fit(x, y + rng.normal(0, 1e-3, y.shape))


@pytest.mark.parametrize("cls,kw", [(Fourier13Interpolator, {}), (FourierReducedInterpolator, {"rank": 7})])
@pytest.mark.parametrize("sym", ["SX", "MX"])
def test_casadi_predict_matches_predict_and_jacobian(cls, kw, sym):
    interp = _fitted(cls, **kw)
    u = getattr(ca, sym).sym("u", 2)
    expr = interp.casadi_predict(u)
    assert expr.shape == (5, 1)
    f = ca.Function("f", [u], [expr, ca.jacobian(expr, u)])
    xs = np.random.default_rng(9).uniform(-1.5, 1.5, (6, 2))
    for x in xs:
        y, J = (np.asarray(v) for v in f(x))
        np.testing.assert_allclose(y.ravel(), interp.predict(x[None])[0], rtol=0, atol=1e-12)
        h = 1e-6
        J_fd = np.column_stack([(interp.predict((x + h * e)[None])[0] - interp.predict((x - h * e)[None])[0]) / (2 * h)
                                for e in np.eye(2)])
        np.testing.assert_allclose(J, J_fd, rtol=0, atol=1e-7)


def test_casadi_predict_refuses_wrong_size_and_unfitted():
    interp = _fitted(Fourier13Interpolator)
    with pytest.raises(ModelError, match="2 entries"):
        interp.casadi_predict(ca.SX.sym("u", 3))
    with pytest.raises(ModelError, match="not fitted"):
        Fourier13Interpolator().casadi_predict(ca.SX.sym("u", 2))
