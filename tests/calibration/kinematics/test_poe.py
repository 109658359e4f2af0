"""POE kinematics against an independent homogeneous-transform implementation."""

import numpy as np
from scipy.spatial.transform import Rotation

from calibration.kinematics.poe import pose_error


def reference_fk(model, q):
    """Product of 4x4 exponentials of twists, one sample at a time (independent of calibration.kinematics.poe)."""
    out = []
    origins = np.cumsum(model.P, axis=1)
    for qi in q:
        T = np.eye(4)
        for j in range(model.n_joints):
            h, o = model.H[:, j], origins[:, j]
            E = np.eye(4)
            E[:3, :3] = Rotation.from_rotvec(h * qi[j]).as_matrix()
            E[:3, 3] = o - E[:3, :3] @ o
            T = T @ E
        M = np.eye(4)
        M[:3, :3] = model.R_flange @ model.R_flange_tool
        M[:3, 3] = origins[:, -1] + model.R_flange @ model.p_flange_tool
        out.append(T @ M)
    return np.array(out)


def test_fk_matches_twist_exponentials(synthetic_arm):
    _, _, truth = synthetic_arm
    q = np.random.default_rng(0).uniform(-2, 2, (40, 6))
    R, p = truth.fk(q)
    T = reference_fk(truth, q)
    np.testing.assert_allclose(p, T[:, :3, 3], atol=1e-9)
    np.testing.assert_allclose(R, T[:, :3, :3], atol=1e-12)


def test_nominal_zero_pose(r1_nominal):
    R, p = r1_nominal.fk(np.zeros((1, 6)))
    flange = np.array([150 + 1082 + 100, 0, 760 + 200])
    np.testing.assert_allclose(p[0], flange + r1_nominal.R_flange @ r1_nominal.p_flange_tool, atol=1e-9)


def test_joint_jacobian_against_finite_differences(synthetic_arm):
    _, _, truth = synthetic_arm
    q = np.random.default_rng(1).uniform(-2, 2, (10, 6))
    J = truth.jacobian_q(q)
    eps = 1e-6
    for j in range(6):
        dq = np.zeros(6)
        dq[j] = eps
        Rp, pp = truth.fk(q + dq)
        Rm, pm = truth.fk(q - dq)
        np.testing.assert_allclose(J[:, :3, j], (pp - pm) / (2 * eps), atol=1e-5)
        w = Rotation.from_matrix(Rp @ np.swapaxes(Rm, 1, 2)).as_rotvec() / (2 * eps)
        np.testing.assert_allclose(J[:, 3:, j], w, atol=1e-8)


def test_pose_error_units():
    R = np.eye(3)[None]
    Ry = Rotation.from_euler("z", 1.0, degrees=True).as_matrix()[None]
    dp, dR = pose_error(Ry, np.array([[3.0, 4.0, 0.0]]), R, np.zeros((1, 3)))
    np.testing.assert_allclose(dp, [5.0])
    np.testing.assert_allclose(dR, [1.0], atol=1e-12)
