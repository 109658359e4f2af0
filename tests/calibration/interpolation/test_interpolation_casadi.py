"""Every interpolator kind's declared casadi form (``Interpolator.casadi_predict``) against its numpy predict.

Queries are drawn inside and outside the anchors' convex hull (outside, nearest/linear/ae fall back to the
nearest anchor and rbf/nn/Fourier extrapolate: the casadi forms must do the same). Every kind has one; a
kind that does not override the base method must say so with a ModelError, which ``interpolator_sx`` turns
into frozen parameters.
"""

from __future__ import annotations

import numpy as np
import pytest

from calibration.errors import ModelError
from calibration.interpolation import KINDS, RBF_KERNELS, Interpolator, LinearInterpolator, make_interpolator
from calibration.kinematics.casadi_expr import interpolator_sx

ca = pytest.importorskip("casadi")

EXACT = ("nearest", "linear", "cubic", "rbf", "fbf13", "fbf7", "nn", "ae")
OPTIONS = {"nn": {"hidden": (32, 32), "max_iter": 100}, "ae": {"latent": 4, "hidden": (32,), "max_iter": 100}}
EPSILON = {"gaussian": 1.0, "multiquadric": 2.0, "inverse_multiquadric": 1.0, "inverse_quadratic": 1.0}


def test_every_kind_is_classified():
    assert sorted(EXACT) == sorted(KINDS)


@pytest.fixture(scope="module")
def data():
    rng = np.random.default_rng(11)
    x = rng.uniform(-1.0, 1.0, (40, 2))
    y = np.column_stack([np.sin(x[:, 0] * k) * np.cos(x[:, 1]) + 0.1 * k for k in range(1, 6)]) * 1e-3
    q = rng.uniform(-1.6, 1.6, (300, 2))
    return x, y, q


def _casadi_values(interp, q):
    u = ca.SX.sym("u", 2)
    f = ca.Function("f", [u], [interp.casadi_predict(u)])
    return np.array([np.asarray(f(qi)).ravel() for qi in q])


@pytest.mark.parametrize("kind", EXACT)
def test_casadi_predict_matches_predict_inside_and_outside_the_hull(kind, data):
    x, y, q = data
    interp = make_interpolator(kind, **OPTIONS.get(kind, {})).fit(x, y)
    out = interp.out_of_range(q)
    assert 20 < out.sum() < q.shape[0] - 20  # both regions are exercised
    np.testing.assert_allclose(_casadi_values(interp, q), interp.predict(q), rtol=0, atol=1e-15)
    assert interpolator_sx(interp, ca.SX.sym("u", 2), y.shape[1]) is not None


@pytest.mark.parametrize("kernel", RBF_KERNELS)
def test_rbf_casadi_matches_every_kernel_with_exact_derivatives(kernel, data):
    x, y, q = data
    interp = make_interpolator("rbf", kernel=kernel, epsilon=EPSILON.get(kernel)).fit(x, y)
    scale = float(np.abs(interp.predict(q)).max())
    # Rounding only: the kernel sums cancel (quintic terms grow as r^5 outside the anchors), so numpy's and
    # casadi's orders of summation differ by ~1e-12 of the output on some builds; a wrong kernel is off by O(scale).
    np.testing.assert_allclose(_casadi_values(interp, q), interp.predict(q), rtol=0, atol=1e-10 * scale)
    u = ca.SX.sym("u", 2)
    J = ca.Function("J", [u], [ca.jacobian(interp.casadi_predict(u), u)])
    h = 1e-6
    for qi in q[:10]:
        fd = np.column_stack([(interp.predict((qi + h * e)[None])[0] - interp.predict((qi - h * e)[None])[0]) / (2 * h)
                              for e in np.eye(2)])
        np.testing.assert_allclose(np.asarray(J(qi)), fd, rtol=0, atol=1e-6 * max(scale, 1e-3))


def test_nearest_is_the_nearest_anchor_value_and_flat(data):
    x, y, q = data
    interp = make_interpolator("nearest").fit(x, y)
    u = ca.SX.sym("u", 2)
    J = ca.Function("J", [u], [ca.jacobian(interp.casadi_predict(u), u)])
    np.testing.assert_array_equal(_casadi_values(interp, x), y)
    assert all(np.all(np.asarray(J(qi)) == 0.0) for qi in q[:20])


def test_cubic_derivative_matches_finite_differences(data):
    x, y, q = data
    interp = make_interpolator("cubic").fit(x, y)
    u = ca.SX.sym("u", 2)
    J = ca.Function("J", [u], [ca.jacobian(interp.casadi_predict(u), u)])
    h = 1e-6
    for qi in q[~interp.out_of_range(q)][:20]:
        fd = np.column_stack([(interp.predict((qi + h * e)[None])[0] - interp.predict((qi - h * e)[None])[0]) / (2 * h)
                              for e in np.eye(2)])
        np.testing.assert_allclose(np.asarray(J(qi)), fd, rtol=0, atol=1e-8)


def test_linear_derivative_is_the_simplex_gradient(data):
    x, y, q = data
    interp = make_interpolator("linear").fit(x, y)
    u = ca.SX.sym("u", 2)
    J = ca.Function("J", [u], [ca.jacobian(interp.casadi_predict(u), u)])
    h = 1e-7
    for qi in q[~interp.out_of_range(q)][:20]:
        fd = np.column_stack([(interp.predict((qi + h * e)[None])[0] - interp.predict((qi - h * e)[None])[0]) / (2 * h)
                              for e in np.eye(2)])
        np.testing.assert_allclose(np.asarray(J(qi)), fd, rtol=0, atol=1e-9)


class _NoCasadiForm(LinearInterpolator):
    """A kind that keeps the base class's casadi_predict (declines)."""

    casadi_predict = Interpolator.casadi_predict


def test_kinds_without_a_casadi_form_say_so(data):
    x, y, _ = data
    interp = _NoCasadiForm().fit(x, y)
    with pytest.raises(ModelError, match="no exact casadi form"):
        interp.casadi_predict(ca.SX.sym("u", 2))
    assert interpolator_sx(interp, ca.SX.sym("u", 2), y.shape[1]) is None


@pytest.mark.parametrize("kind", EXACT)
def test_unfitted_casadi_predict_refuses(kind):
    with pytest.raises(ModelError, match="not fitted"):
        make_interpolator(kind, **OPTIONS.get(kind, {})).casadi_predict(ca.SX.sym("u", 2))
