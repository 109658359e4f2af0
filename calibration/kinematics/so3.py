"""Rotation utilities, vectorised over leading dimensions.

Rotation vectors are in radians; quaternions are scalar first (w, x, y, z), as in the recording format.
"""

from __future__ import annotations

import numpy as np

from calibration.kinematics.arrays import FloatArray


def make_T(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Homogeneous transform (4, 4) from a rotation (3, 3) and a translation (3,) [mm]."""
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, p
    return T



_EPS = 1e-12


def hat(v: np.ndarray) -> np.ndarray:
    """Skew-symmetric matrices of vectors.

    Args:
        v: vectors, shape (..., 3).

    Returns:
        Matrices with ``hat(v) @ w == cross(v, w)``, shape (..., 3, 3).
    """
    v = np.asarray(v, dtype=float)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1] = -v[..., 2]
    out[..., 0, 2] = v[..., 1]
    out[..., 1, 0] = v[..., 2]
    out[..., 1, 2] = -v[..., 0]
    out[..., 2, 0] = -v[..., 1]
    out[..., 2, 1] = v[..., 0]
    return out


def vee(m: np.ndarray) -> np.ndarray:
    """Inverse of :func:`hat` (antisymmetric part), shape (..., 3, 3) -> (..., 3)."""
    return 0.5 * np.stack(
        [m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]], axis=-1
    )


def rot(h: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Rodrigues rotation about unit axes.

    Args:
        h: unit axes, shape (..., 3) (broadcast against ``q``).
        q: angles [rad], shape (...).

    Returns:
        Rotation matrices, shape (..., 3, 3).
    """
    h = np.asarray(h, dtype=float)
    q = np.asarray(q, dtype=float)
    x, y, z = h[..., 0], h[..., 1], h[..., 2]
    s = np.sin(q)
    c = np.cos(q)
    v = 1.0 - c
    shape = np.broadcast_shapes(x.shape, q.shape)
    out = np.empty(shape + (3, 3))
    # R = c I + s [h]x + (1 - c) h h^T for unit h, written out entry by entry (no temporaries of (..., 3, 3)).
    xv, yv, zv = x * v, y * v, z * v
    xs, ys, zs = x * s, y * s, z * s
    out[..., 0, 0] = c + x * xv
    out[..., 0, 1] = x * yv - zs
    out[..., 0, 2] = x * zv + ys
    out[..., 1, 0] = y * xv + zs
    out[..., 1, 1] = c + y * yv
    out[..., 1, 2] = y * zv - xs
    out[..., 2, 0] = z * xv - ys
    out[..., 2, 1] = z * yv + xs
    out[..., 2, 2] = c + z * zv
    return out


def exp(phi: np.ndarray) -> np.ndarray:
    """Rotation matrices from rotation vectors [rad], shape (..., 3) -> (..., 3, 3)."""
    phi = np.asarray(phi, dtype=float)
    theta = np.linalg.norm(phi, axis=-1)
    small = theta < 1e-9
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(theta) / safe)
    b = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(theta)) / safe**2)
    K = hat(phi)
    R: FloatArray = np.eye(3) + a[..., None, None] * K + b[..., None, None] * (K @ K)
    return R


def log(R: np.ndarray) -> np.ndarray:
    """Rotation vectors [rad] of rotation matrices, shape (..., 3, 3) -> (..., 3); valid for angles < pi."""
    R = np.asarray(R, dtype=float)
    cos_t = np.clip((np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    theta = np.arccos(cos_t)
    w = vee(R)  # = sin(theta) * axis
    sin_t = np.sin(theta)
    small = sin_t < 1e-9
    scale = np.where(small, 1.0 + theta**2 / 6.0, theta / np.where(small, 1.0, sin_t))
    phi: FloatArray = w * scale[..., None]
    return phi


def right_jacobian_inv(e: np.ndarray) -> np.ndarray:
    """Inverse right Jacobian of SO(3) at rotation vectors ``e``, shape (..., 3) -> (..., 3, 3).

    ``log(exp(e) @ exp(d)) ~= e + right_jacobian_inv(e) @ d`` for small ``d``.
    """
    e = np.asarray(e, dtype=float)
    theta = np.linalg.norm(e, axis=-1)
    small = theta < 1e-6
    t = np.where(small, 1.0, theta)
    coef = np.where(small, 1.0 / 12.0, 1.0 / t**2 - (1.0 + np.cos(t)) / (2.0 * t * np.sin(t)))
    K = hat(e)
    J_inv: FloatArray = np.eye(3) + 0.5 * K + coef[..., None, None] * (K @ K)
    return J_inv


def left_jacobian(phi: np.ndarray) -> np.ndarray:
    """Left Jacobian of SO(3): ``exp(phi + d) ~= exp(left_jacobian(phi) @ d) @ exp(phi)``, (..., 3) -> (..., 3, 3)."""
    phi = np.asarray(phi, dtype=float)
    theta = np.linalg.norm(phi, axis=-1)
    small = theta < 1e-6
    t = np.where(small, 1.0, theta)
    a = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(t)) / t**2)
    b = np.where(small, 1.0 / 6.0 - theta**2 / 120.0, (t - np.sin(t)) / t**3)
    K = hat(phi)
    J: FloatArray = np.eye(3) + a[..., None, None] * K + b[..., None, None] * (K @ K)
    return J


def quat_to_R(quat: np.ndarray) -> np.ndarray:
    """Rotation matrices from unit quaternions (w, x, y, z), shape (..., 4) -> (..., 3, 3)."""
    quat = np.asarray(quat, dtype=float)
    quat = quat / np.linalg.norm(quat, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(quat, -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=-1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=-1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1),
        ],
        axis=-2,
    )


def R_to_quat(R: np.ndarray) -> np.ndarray:
    """Unit quaternions (w, x, y, z) with w >= 0 from rotation matrices, shape (..., 3, 3) -> (..., 4)."""
    R = np.asarray(R, dtype=float)
    m = R
    t = np.trace(m, axis1=-2, axis2=-1)
    # Four candidate formulas; pick the numerically best per element (Shepperd's method).
    cands = np.stack(
        [
            np.stack([1 + t, m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]], -1),
            np.stack([m[..., 2, 1] - m[..., 1, 2], 1 + 2 * m[..., 0, 0] - t, m[..., 0, 1] + m[..., 1, 0],
                      m[..., 0, 2] + m[..., 2, 0]], -1),
            np.stack([m[..., 0, 2] - m[..., 2, 0], m[..., 0, 1] + m[..., 1, 0], 1 + 2 * m[..., 1, 1] - t,
                      m[..., 1, 2] + m[..., 2, 1]], -1),
            np.stack([m[..., 1, 0] - m[..., 0, 1], m[..., 0, 2] + m[..., 2, 0], m[..., 1, 2] + m[..., 2, 1],
                      1 + 2 * m[..., 2, 2] - t], -1),
        ],
        axis=-2,
    )
    diag = np.stack([t, m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]], -1)
    k = np.argmax(diag, axis=-1)
    q = np.take_along_axis(cands, k[..., None, None], axis=-2)[..., 0, :]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    wxyz: FloatArray = q * np.where(q[..., :1] < 0, -1.0, 1.0)
    return wxyz


def orthonormal_complement(h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors k1, k2 with (k1, k2, h) a right-handed orthonormal frame.

    Args:
        h: unit axis, shape (3,).
    """
    h = np.asarray(h, dtype=float) / np.linalg.norm(h)
    seed = np.eye(3)[int(np.argmin(np.abs(h)))]
    k1 = np.cross(h, seed)
    k1 /= np.linalg.norm(k1)
    k2 = np.cross(h, k1)
    return k1, k2
