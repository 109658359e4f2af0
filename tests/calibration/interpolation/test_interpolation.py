"""Properties of the interpolation family on synthetic data with fixed seeds.

The anchors mimic the real CDC campaign: (q2, q3) on a 5 deg grid, q2 in -55..50 deg, q3 in a
q2-dependent range (a non-rectangular support), K = 248.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from calibration.errors import ModelError
from calibration.interpolation import (
    FBF13_TERMS,
    KINDS,
    AutoencoderInterpolator,
    Fourier13Interpolator,
    FourierReducedInterpolator,
    Interpolator,
    fbf13_basis,
    interpolator_from_dict,
    make_interpolator,
)

FAST_KINDS = ("nearest", "linear", "cubic", "rbf", "fbf13", "fbf7")
EXACT_KINDS = ("nearest", "linear", "cubic", "rbf")
#: Epoch budgets for the trained kinds in tests (the defaults are larger); keeps the file under ~30 s.
NN_OPTIONS = {"nn": {"max_iter": 200}, "ae": {"max_iter": 200}}


def anchor_grid() -> np.ndarray:
    """(q2, q3) anchors [rad], shape (248, 2): 5 deg steps, q3 range depending on q2."""
    rows = []
    for i, q2 in enumerate(range(-55, 51, 5)):
        q3_lo = -70 + 5 * min(i, 11)          # rises with q2 like the real campaign's lower bound
        n = 9 + min(i, 11) // 3 + (i < 10) - (i > 13)  # 10..13 points per column
        rows += [(q2, q3_lo + 5 * j) for j in range(n)]
    return np.radians(np.array(rows, dtype=float))


def smooth_values(x: np.ndarray, m: int = 24, seed: int = 0) -> np.ndarray:
    """m smooth functions of (q2, q3) of the sin(q2) cos(q3) type, shape (N, m), values ~ O(1)."""
    rng = np.random.default_rng(seed)
    amp = rng.normal(size=(4, m))
    freq = rng.uniform(0.5, 1.5, size=(2, m))
    phase = rng.uniform(0.0, np.pi, size=(2, m))
    q2, q3 = x[:, :1], x[:, 1:2]
    return (amp[0] * np.sin(freq[0] * q2 + phase[0]) * np.cos(freq[1] * q3 + phase[1])
            + amp[1] * q2 * q3 + amp[2] * np.cos(q2 + q3) + amp[3])


@pytest.fixture(scope="module")
def anchors() -> np.ndarray:
    x = anchor_grid()
    assert x.shape == (248, 2)
    return x


@pytest.fixture(scope="module")
def values(anchors: np.ndarray) -> np.ndarray:
    return smooth_values(anchors)


@pytest.fixture(scope="module")
def inside(anchors: np.ndarray) -> np.ndarray:
    """Queries strictly inside the support: centres of the grid cells whose 4 corners are anchors."""
    keys = {tuple(np.round(np.degrees(a)).astype(int)) for a in anchors}
    centres = [(q2 + 2.5, q3 + 2.5) for q2, q3 in keys
               if {(q2 + 5, q3), (q2, q3 + 5), (q2 + 5, q3 + 5)} <= keys]
    return np.radians(np.array(sorted(centres), dtype=float))


@pytest.fixture(scope="module")
def outside(anchors: np.ndarray) -> np.ndarray:
    """Queries outside the convex hull: beyond each end of q2, and far below/above in q3."""
    lo, hi = anchors.min(axis=0), anchors.max(axis=0)
    mid = 0.5 * (lo + hi)
    d = np.radians(10.0)
    return np.array([[lo[0] - d, mid[1]], [hi[0] + d, mid[1]], [mid[0], lo[1] - d], [mid[0], hi[1] + d],
                     [lo[0] - d, lo[1] - d], [hi[0] + d, hi[1] + d]])


@pytest.fixture(scope="module")
def fitted(anchors: np.ndarray, values: np.ndarray) -> dict[str, Interpolator]:
    """Every kind fitted once on the smooth 24-output data (nn and ae take most of the file's time)."""
    return {k: make_interpolator(k, **NN_OPTIONS.get(k, {})).fit(anchors, values) for k in KINDS}


def rms(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean((a - b) ** 2)))


# -- exactness ------------------------------------------------------------------------------------


@pytest.mark.parametrize("kind", EXACT_KINDS)
def test_exact_at_anchors(kind: str, fitted: dict, anchors: np.ndarray, values: np.ndarray) -> None:
    np.testing.assert_allclose(fitted[kind].predict(anchors), values, rtol=0, atol=1e-9)
    assert not fitted[kind].out_of_range(anchors).any()


def test_fbf13_exact_in_span(anchors: np.ndarray) -> None:
    rng = np.random.default_rng(1)
    A = rng.normal(size=(24, 13))
    interp = make_interpolator("fbf13").fit(anchors, fbf13_basis(anchors) @ A.T)
    np.testing.assert_allclose(interp.coefficients, A, atol=1e-8)
    xq = rng.uniform(anchors.min(axis=0), anchors.max(axis=0), size=(500, 2))
    np.testing.assert_allclose(interp.predict(xq), fbf13_basis(xq) @ A.T, atol=1e-9)
    assert interp.basis(xq).shape == (500, 13) and len(FBF13_TERMS) == 13


def test_fbf13_singular_vectors(fitted: dict) -> None:
    interp = fitted["fbf13"]
    s, V = interp.singular_values(), interp.right_singular_vectors()
    assert s.shape == (13,) and V.shape == (13, 13)
    assert np.all(np.diff(s) <= 0)
    np.testing.assert_allclose(V.T @ V, np.eye(13), atol=1e-12)
    U = interp.coefficients @ V / s  # A V = U S
    np.testing.assert_allclose((U * s) @ V.T, interp.coefficients, atol=1e-10)


def test_fbf7_full_rank_equals_fbf13(fitted: dict, anchors: np.ndarray, values: np.ndarray,
                                     inside: np.ndarray) -> None:
    full = make_interpolator("fbf7", rank=13).fit(anchors, values)
    np.testing.assert_allclose(full.predict(inside), fitted["fbf13"].predict(inside), atol=1e-8)


@pytest.mark.parametrize("rank", [1, 4, 7])
def test_fbf7_reproduces_rank_r_coefficients(rank: int, anchors: np.ndarray) -> None:
    rng = np.random.default_rng(rank)
    A = rng.normal(size=(24, rank)) @ rng.normal(size=(rank, 13))  # rank-r coefficient matrix
    reduced = make_interpolator("fbf7", rank=rank).fit(anchors, fbf13_basis(anchors) @ A.T)
    xq = rng.uniform(anchors.min(axis=0), anchors.max(axis=0), size=(300, 2))
    np.testing.assert_allclose(reduced.predict(xq), fbf13_basis(xq) @ A.T, atol=1e-8)
    assert reduced.reduced_basis.shape == (13, rank) and reduced.coefficients.shape == (24, rank)


def test_fbf7_default_rank_is_seven(fitted: dict) -> None:
    assert fitted["fbf7"].rank == 7 and fitted["fbf7"].coefficients.shape == (24, 7)


# -- accuracy between anchors ---------------------------------------------------------------------

#: RMS error bound at the 204 grid-cell centres for the smooth values (std 1.6) on the 5 deg grid.
#: Measured: nearest 0.056, linear 2.7e-3, cubic 3.6e-4, rbf 4.2e-4, fbf13 5.1e-3, fbf7 8.0e-3,
#: nn 5.8e-3, ae 5.6e-3 (200 epochs each).
BETWEEN_TOL = {"nearest": 0.15, "linear": 0.01, "cubic": 1.5e-3, "rbf": 1.5e-3, "fbf13": 0.02, "fbf7": 0.03,
               "nn": 0.02, "ae": 0.03}


@pytest.mark.parametrize("kind", KINDS)
def test_smooth_function_between_anchors(kind: str, fitted: dict, inside: np.ndarray) -> None:
    interp = fitted[kind]
    assert not interp.out_of_range(inside).any()
    error = rms(interp.predict(inside), smooth_values(inside))
    assert error < BETWEEN_TOL[kind], f"{kind}: RMS {error:.2e} >= {BETWEEN_TOL[kind]:.0e}"


def test_nn_and_ae_fit_the_anchors(fitted: dict, anchors: np.ndarray, values: np.ndarray) -> None:
    # values have std 1.6; measured RMS at the anchors: nn 7.3e-3, ae 5.9e-3 (200 epochs)
    assert rms(fitted["nn"].predict(anchors), values) < 0.02
    assert rms(fitted["ae"].predict(anchors), values) < 0.02


@pytest.mark.parametrize("kind", ["nearest", "linear", "rbf", "nn"])
def test_three_inputs(kind: str) -> None:
    rng = np.random.default_rng(3)
    x = rng.uniform(-1.0, 1.0, size=(60, 3))
    y = np.column_stack([np.sin(x).sum(axis=1), x[:, 0] * x[:, 2]])
    options = {"hidden": (32, 32), "max_iter": 50} if kind == "nn" else {}
    interp = make_interpolator(kind, **options).fit(x, y)
    if kind != "nn":
        np.testing.assert_allclose(interp.predict(x), y, atol=1e-9)
    assert interp.out_of_range(np.array([[2.0, 0.0, 0.0]])).all()
    assert not interp.out_of_range(x).any()
    xq = rng.uniform(-1.2, 1.2, size=(50, 3))
    loaded = interpolator_from_dict(json.loads(json.dumps(interp.to_dict())))
    assert np.array_equal(loaded.predict(xq), interp.predict(xq))


def test_one_input() -> None:
    x = np.linspace(0.0, 1.0, 11)[:, None]
    y = np.column_stack([np.sin(3 * x[:, 0]), x[:, 0] ** 2])
    for kind in ("nearest", "rbf"):
        interp = make_interpolator(kind).fit(x, y)
        np.testing.assert_allclose(interp.predict(x), y, atol=1e-9)
        np.testing.assert_array_equal(interp.out_of_range(np.array([[-0.1], [0.0], [0.5], [1.0], [1.1]])),
                                      [True, False, False, False, True])
    with pytest.raises(ModelError, match="at least 2 columns"):
        make_interpolator("linear").fit(x, y)


# -- outside the support --------------------------------------------------------------------------


@pytest.mark.parametrize("kind", KINDS)
def test_out_of_range_flagged_and_finite(kind: str, fitted: dict, anchors: np.ndarray,
                                         outside: np.ndarray, inside: np.ndarray) -> None:
    interp = fitted[kind]
    assert interp.out_of_range(outside).all()
    assert not interp.out_of_range(np.vstack([anchors, inside])).any()
    pred = interp.predict(np.vstack([outside, inside]))
    assert pred.shape == (len(outside) + len(inside), 24) and np.isfinite(pred).all()


@pytest.mark.parametrize("kind", ["nearest", "linear", "cubic"])
def test_nearest_anchor_value_outside_hull(kind: str, fitted: dict, anchors: np.ndarray,
                                           values: np.ndarray, outside: np.ndarray) -> None:
    nearest = np.argmin(((outside[:, None, :] - anchors[None]) ** 2).sum(axis=2), axis=1)
    np.testing.assert_array_equal(fitted[kind].predict(outside), values[nearest])


def test_ae_nearest_anchor_outside_hull(fitted: dict, anchors: np.ndarray, outside: np.ndarray) -> None:
    ae = fitted["ae"]
    nearest = np.argmin(((outside[:, None, :] - anchors[None]) ** 2).sum(axis=2), axis=1)
    np.testing.assert_allclose(ae.predict(outside), ae.predict(anchors[nearest]), rtol=0, atol=1e-12)


def test_empty_query(fitted: dict) -> None:
    for kind, interp in fitted.items():
        assert interp.predict(np.zeros((0, 2))).shape == (0, 24), kind
        assert interp.out_of_range(np.zeros((0, 2))).shape == (0,), kind


# -- serialisation --------------------------------------------------------------------------------


@pytest.mark.parametrize("kind", KINDS)
def test_json_round_trip_bit_identical(kind: str, fitted: dict, inside: np.ndarray,
                                       outside: np.ndarray) -> None:
    interp = fitted[kind]
    xq = np.vstack([inside, outside, np.random.default_rng(2).uniform(-1.5, 1.5, size=(200, 2))])
    loaded = interpolator_from_dict(json.loads(json.dumps(interp.to_dict())))
    assert type(loaded) is type(interp) and loaded.kind == kind
    assert np.array_equal(loaded.predict(xq), interp.predict(xq))
    assert np.array_equal(loaded.out_of_range(xq), interp.out_of_range(xq))


def test_yaml_round_trip_bit_identical(fitted: dict, inside: np.ndarray) -> None:
    interp = fitted["fbf7"]  # small dict: pure-Python YAML takes ~2 s per 6000 floats
    loaded = interpolator_from_dict(yaml.safe_load(yaml.safe_dump(interp.to_dict())))
    assert np.array_equal(loaded.predict(inside), interp.predict(inside))


def test_options_survive_round_trip(anchors: np.ndarray, values: np.ndarray) -> None:
    rbf = make_interpolator("rbf", kernel="cubic", smoothing=1e-3).fit(anchors, values)
    loaded = interpolator_from_dict(json.loads(json.dumps(rbf.to_dict())))
    assert (loaded.kernel, loaded.smoothing) == ("cubic", 1e-3)


def test_training_is_deterministic(anchors: np.ndarray, values: np.ndarray) -> None:
    small = {"hidden": (16, 16), "max_iter": 20}
    a = make_interpolator("nn", **small).fit(anchors, values).to_dict()
    b = make_interpolator("nn", **small).fit(anchors, values).to_dict()
    assert a == b
    small_ae = {"hidden": (16,), "latent": 3, "max_iter": 20}
    assert (make_interpolator("ae", **small_ae).fit(anchors, values).to_dict()
            == make_interpolator("ae", **small_ae).fit(anchors, values).to_dict())


# -- bad input ------------------------------------------------------------------------------------


def test_unknown_kind_names_valid_kinds() -> None:
    with pytest.raises(ModelError, match="valid kinds: nearest, linear, cubic, rbf, fbf13, fbf7, nn, ae"):
        make_interpolator("spline")
    with pytest.raises(ModelError, match="valid kinds"):
        interpolator_from_dict({"kind": "spline"})
    with pytest.raises(ModelError, match="valid kinds"):
        interpolator_from_dict({})


def test_unknown_option_names_valid_options() -> None:
    with pytest.raises(ModelError, match="valid options: rank"):
        make_interpolator("fbf7", order=7)
    with pytest.raises(ModelError, match="valid options: none"):
        make_interpolator("linear", smoothing=1.0)


@pytest.mark.parametrize("kind", KINDS)
def test_mismatched_anchor_count(kind: str, anchors: np.ndarray, values: np.ndarray) -> None:
    interp = make_interpolator(kind)
    with pytest.raises(ModelError, match="248 anchors but y has 247 rows"):
        interp.fit(anchors, values[:-1])
    assert not interp.is_fitted
    with pytest.raises(ModelError, match="not fitted"):
        interp.predict(anchors)


@pytest.mark.parametrize("kind", ["fbf13", "fbf7", "cubic"])
def test_wrong_input_dimension_for_2d_kinds(kind: str, anchors: np.ndarray, values: np.ndarray) -> None:
    x3 = np.column_stack([anchors, np.zeros(len(anchors))])
    with pytest.raises(ModelError, match=r"needs x with 2 columns \(q2, q3\)"):
        make_interpolator(kind).fit(x3, values)


def test_other_bad_inputs(fitted: dict, anchors: np.ndarray, values: np.ndarray) -> None:
    with pytest.raises(ModelError, match="expected shape \\(rows, columns\\)"):
        make_interpolator("linear").fit(anchors, values[:, 0])
    bad = values.copy()
    bad[3, 4] = np.nan
    with pytest.raises(ModelError, match="NaN"):
        make_interpolator("rbf").fit(anchors, bad)
    with pytest.raises(ModelError, match="query x has 3 columns, the anchors had 2"):
        fitted["linear"].predict(np.zeros((5, 3)))
    with pytest.raises(ModelError, match="repeated anchor"):
        make_interpolator("linear").fit(np.vstack([anchors, anchors[:1]]), np.vstack([values, values[:1]]))
    with pytest.raises(ModelError, match="valid choices: thin_plate_spline, cubic"):
        make_interpolator("rbf", kernel="tps")
    with pytest.raises(ModelError, match="rank must be an int in 1..13"):
        FourierReducedInterpolator(rank=14)
    with pytest.raises(ModelError, match="latent must be a positive int"):
        AutoencoderInterpolator(latent=0)
    with pytest.raises(ModelError, match="kind is 'fbf7', expected 'fbf13'"):
        Fourier13Interpolator.from_dict(fitted["fbf7"].to_dict())
    broken = fitted["fbf13"].to_dict()
    del broken["coefficients"]
    with pytest.raises(ModelError, match="missing key 'coefficients'"):
        interpolator_from_dict(broken)


@pytest.mark.parametrize("precision", ["float64", "float32"])
@pytest.mark.parametrize("n, hidden, epochs", [(230, (12, 12), 15), (40, (8, 3, 8), 30)])
def test_mlp_training_gives_the_bits_of_scikit_learns_adam(n: int, hidden: tuple[int, ...], epochs: int,
                                                           precision: str) -> None:
    """train_mlp replays MLPRegressor's Adam (init, shuffles, batches of 200 then the rest) to the last bit, in
    float64 (so models trained before it keep their figures) and in float32 (scikit-learn given float32 data)."""
    import warnings

    neural = pytest.importorskip("sklearn.neural_network")
    from calibration.interpolation.mlp import train_mlp

    rng = np.random.default_rng(n)
    x, y = rng.normal(size=(n, 3)).astype(precision), rng.normal(size=(n, 4)).astype(precision)
    net = neural.MLPRegressor(hidden_layer_sizes=hidden, activation="relu", solver="adam", alpha=1e-3,
                              learning_rate_init=3e-3, max_iter=epochs, tol=0.0, n_iter_no_change=epochs + 1,
                              random_state=7, shuffle=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the full epoch budget always "fails to converge"
        net.fit(x, y)
    weights, biases = train_mlp(x, y, hidden, epochs, 3e-3, 1e-3, 7, precision=precision)
    for ours, theirs in zip(weights + biases, net.coefs_ + net.intercepts_):
        assert theirs.dtype == precision and ours.dtype == np.float64
        assert np.array_equal(ours, theirs)


@pytest.mark.parametrize("kind", ["nn", "ae"])
def test_networks_train_in_float32_and_files_name_their_precision(kind: str) -> None:
    rng = np.random.default_rng(3)
    x, y = rng.uniform(-1, 1, (30, 2)), rng.normal(size=(30, 3))
    options = {"hidden": (8, 8), "max_iter": 20}
    f32 = make_interpolator(kind, **options).fit(x, y)
    f64 = make_interpolator(kind, precision="float64", **options).fit(x, y)
    d = f32.to_dict()
    assert d["options"]["precision"] == "float32" and f64.to_dict()["options"]["precision"] == "float64"
    assert not np.array_equal(f32.predict(x), f64.predict(x))  # the precision is the training's arithmetic
    np.testing.assert_allclose(f32.predict(x), f64.predict(x), atol=1e-3 * np.abs(y).max())
    assert np.array_equal(interpolator_from_dict(d).predict(x), f32.predict(x))
    old = f64.to_dict()
    del old["options"]["precision"]  # a file saved before the option: trained in float64
    assert interpolator_from_dict(old).to_dict()["options"]["precision"] == "float64"
    with pytest.raises(ModelError, match="precision must be one of"):
        make_interpolator(kind, precision="float16", **options)
