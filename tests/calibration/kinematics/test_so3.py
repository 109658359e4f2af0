import numpy as np

from calibration.kinematics import so3


def test_quaternion_round_trip_and_sign():
    rng = np.random.default_rng(0)
    R = so3.exp(rng.normal(size=(200, 3)))
    quat = so3.R_to_quat(R)
    np.testing.assert_allclose(np.linalg.norm(quat, axis=1), 1.0, atol=1e-12)
    assert np.all(quat[:, 0] >= 0)
    np.testing.assert_allclose(so3.quat_to_R(quat), R, atol=1e-12)


def test_log_inverts_exp():
    rng = np.random.default_rng(1)
    phi = rng.normal(size=(100, 3))
    phi *= (np.pi - 1e-3) * np.minimum(1, 1 / np.linalg.norm(phi, axis=1))[:, None]
    np.testing.assert_allclose(so3.log(so3.exp(phi)), phi, atol=1e-9)
    np.testing.assert_allclose(so3.log(np.eye(3)[None]), 0.0, atol=1e-15)


def test_rot_matches_exp():
    rng = np.random.default_rng(2)
    h = rng.normal(size=(50, 3))
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    q = rng.uniform(-3, 3, 50)
    np.testing.assert_allclose(so3.rot(h, q), so3.exp(h * q[:, None]), atol=1e-12)


def test_right_jacobian_inverse_against_finite_differences():
    rng = np.random.default_rng(3)
    e = rng.normal(size=3) * 0.7
    Jinv = so3.right_jacobian_inv(e)
    eps = 1e-7
    num = np.zeros((3, 3))
    for i in range(3):
        d = np.zeros(3)
        d[i] = eps
        num[:, i] = (so3.log(so3.exp(e) @ so3.exp(d)) - so3.log(so3.exp(e) @ so3.exp(-d))) / (2 * eps)
    np.testing.assert_allclose(Jinv, num, atol=1e-6)
