"""The minimal POE parameterisation: small deviations from the nominal arm.

Each joint axis is tilted by two angles about two unit vectors normal to its nominal direction, and each
joint origin (the point on the axis) moves by two offsets in the plane normal to the nominal axis through
the nominal origin: 4n parameters. Optionally 3 more move the flange point (``fit_tool``).

Layout of a parameter vector ``x``: ``[d_1a, d_1b, ..., d_na, d_nb]`` origin offsets [mm], then
``[t_1a, t_1b, ..., t_na, t_nb]`` axis tilts [rad], then (with ``fit_tool``) the flange-point shift [mm].
``x = 0`` is the nominal arm. Every function takes one vector (m,) or one per sample (N, m).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from calibration.errors import ModelError
from calibration.kinematics import so3
from calibration.kinematics.casadi_expr import rot_sx
from calibration.kinematics.poe import PoeModel


@dataclass(frozen=True)
class MinimalParameterisation:
    """Maps parameter vectors to POE geometry around a nominal model.

    Attributes:
        nominal: the arm the deviations are measured from.
        fit_tool: when True, 3 extra parameters shift the flange point.
    """

    nominal: PoeModel
    fit_tool: bool = False
    k1: np.ndarray = field(init=False, repr=False)  # (n, 3)
    k2: np.ndarray = field(init=False, repr=False)  # (n, 3)
    origins: np.ndarray = field(init=False, repr=False)  # nominal joint origins at q = 0, (n, 3)

    def __post_init__(self) -> None:
        n = self.nominal.n_joints
        pairs = [so3.orthonormal_complement(self.nominal.H[:, j]) for j in range(n)]
        object.__setattr__(self, "k1", np.array([p[0] for p in pairs]))
        object.__setattr__(self, "k2", np.array([p[1] for p in pairs]))
        object.__setattr__(self, "origins", np.cumsum(self.nominal.P, axis=1)[:, :n].T)

    @property
    def n_joints(self) -> int:
        return self.nominal.n_joints

    @property
    def size(self) -> int:
        """Number of parameters m = 4n (+3 with ``fit_tool``)."""
        return 4 * self.n_joints + (3 if self.fit_tool else 0)

    def names(self) -> list[str]:
        """Human-readable parameter names with units, in layout order."""
        n = self.n_joints
        names = [f"origin{j + 1}_{ab}_mm" for j in range(n) for ab in "ab"]
        names += [f"tilt{j + 1}_{ab}_rad" for j in range(n) for ab in "ab"]
        if self.fit_tool:
            names += ["flange_dx_mm", "flange_dy_mm", "flange_dz_mm"]
        return names

    def _split(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        x = np.asarray(x, dtype=float)
        if x.shape[-1] != self.size:
            raise ModelError(f"parameter vector must have {self.size} entries, got shape {x.shape}")
        n = self.n_joints
        d = x[..., : 2 * n].reshape(x.shape[:-1] + (n, 2))
        t = x[..., 2 * n: 4 * n].reshape(x.shape[:-1] + (n, 2))
        tool = x[..., 4 * n:] if self.fit_tool else np.zeros(x.shape[:-1] + (3,))
        return d, t, tool

    def axes(self, t: np.ndarray, derivatives: bool = False) -> tuple[np.ndarray, ...]:
        """Tilted axes, and with ``derivatives`` their derivatives with respect to the two tilt angles.

        Args:
            t: tilt angles [rad], shape (..., n, 2).

        Returns:
            ``(h,)`` or ``(h, dh/da, dh/db)``, each shape (..., n, 3).
        """
        # h = rot(k2, b) rot(k1, a) h_nom = cos a cos b h_nom + cos a sin b k1 - sin a k2, as (k1, k2, h_nom) is
        # a right-handed frame; the derivatives follow directly.
        ca, sa = np.cos(t[..., 0])[..., None], np.sin(t[..., 0])[..., None]
        cb, sb = np.cos(t[..., 1])[..., None], np.sin(t[..., 1])[..., None]
        hn = self.nominal.H.T
        h = ca * (cb * hn + sb * self.k1) - sa * self.k2
        if not derivatives:
            return (h,)
        dh_da = -sa * (cb * hn + sb * self.k1) - ca * self.k2
        dh_db = ca * (cb * self.k1 - sb * hn)
        return h, dh_da, dh_db

    def geometry(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """POE geometry for parameter vectors.

        Args:
            x: shape (m,) or (N, m).

        Returns:
            ``(H, P)`` with shapes (3, n), (3, n+1) or per sample (N, 3, n), (N, 3, n+1).
        """
        d, t, tool = self._split(x)
        (h,) = self.axes(t)
        dO = d[..., 0:1] * self.k1 + d[..., 1:2] * self.k2  # (..., n, 3)
        P = np.array(np.broadcast_to(self.nominal.P.T, dO.shape[:-2] + self.nominal.P.T.shape))
        P[..., 0, :] += dO[..., 0, :]
        P[..., 1:-1, :] += dO[..., 1:, :] - dO[..., :-1, :]
        P[..., -1, :] += tool - dO[..., -1, :]
        return np.swapaxes(h, -1, -2), np.swapaxes(P, -1, -2)

    def casadi_geometry(self, x: Any) -> tuple[Any, Any]:
        """:meth:`geometry` on casadi: ``(H (3, n), P (3, n+1))`` for one parameter vector x (m,) of symbols."""
        import casadi as ca


        n = self.n_joints
        Hn, Pn = self.nominal.H, self.nominal.P
        hs, dO = [], []
        for j in range(n):
            k1, k2 = ca.DM(self.k1[j]), ca.DM(self.k2[j])
            hs.append(rot_sx(k2, x[2 * n + 2 * j + 1]) @ (rot_sx(k1, x[2 * n + 2 * j]) @ ca.DM(Hn[:, j])))
            dO.append(x[2 * j] * k1 + x[2 * j + 1] * k2)
        tool = x[4 * n: 4 * n + 3] if self.fit_tool else ca.SX.zeros(3)
        cols = [ca.DM(Pn[:, 0]) + dO[0]]
        cols += [ca.DM(Pn[:, i]) + dO[i] - dO[i - 1] for i in range(1, n)]
        cols.append(ca.DM(Pn[:, n]) + tool - dO[n - 1])
        return ca.horzcat(*hs), ca.horzcat(*cols)

    def scale(self, reach_mm: float = 1000.0) -> np.ndarray:
        """Parameter units per millimetre of tool motion: 1 for offsets, 1/reach for tilts, shape (m,)."""
        scale = np.ones(self.size)
        scale[2 * self.n_joints: 4 * self.n_joints] = 1.0 / reach_mm
        return scale

    def pose(self, q: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Tool pose for joint angles q (N, n) and parameters x (m,) or (N, m): ``(R (N, 3, 3), p (N, 3))``."""
        return self.nominal.fk(q, *self.geometry(x))

    def model(self, x: np.ndarray) -> PoeModel:
        """A constant POE model for one parameter vector (m,)."""
        H, P = self.geometry(np.asarray(x, dtype=float))
        return self.nominal.with_geometry(H, P)

    def from_geometry(self, H: np.ndarray, P: np.ndarray) -> np.ndarray:
        """Parameters of a given geometry (3, n), (3, n+1): the inverse of :meth:`geometry`.

        Origins are slid along their (new) axes into the plane normal to the nominal axis, which leaves the
        kinematics unchanged. Without ``fit_tool`` a flange-point shift cannot be represented and is an error.
        """
        H = np.asarray(H, dtype=float)
        P = np.asarray(P, dtype=float)
        n = self.n_joints
        h = H.T
        hn = self.nominal.H.T
        a = -np.arcsin(np.clip(np.einsum("ij,ij->i", h, self.k2), -1, 1))
        b = np.arctan2(np.einsum("ij,ij->i", h, self.k1), np.einsum("ij,ij->i", h, hn))
        O = np.cumsum(P, axis=1).T  # (n+1, 3)
        dO = O[:n] - self.origins
        slide = -np.einsum("ij,ij->i", dO, hn) / np.einsum("ij,ij->i", h, hn)
        dO = dO + slide[:, None] * h
        d = np.stack([np.einsum("ij,ij->i", dO, self.k1), np.einsum("ij,ij->i", dO, self.k2)], axis=1)
        tool = O[n] - np.cumsum(self.nominal.P, axis=1)[:, n]
        x = np.concatenate([d.ravel(), np.stack([a, b], axis=1).ravel()])
        if self.fit_tool:
            return np.concatenate([x, tool])
        if np.linalg.norm(tool) > 1e-9:
            raise ModelError(f"the flange point moved by {np.round(tool, 6).tolist()} mm, which this "
                             "parameterisation cannot express; use fit_tool=True")
        return x

    def jacobian(self, q: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Tool pose and its analytic Jacobian with respect to the parameters.

        Args:
            q: joint angles [rad], shape (N, n).
            x: parameters, shape (m,) or (N, m).

        Returns:
            ``(R_base_tool (N, 3, 3), p_base_tool (N, 3), J (N, 6, m))`` where J rows are
            ``d[p (mm); theta (rad)] / dx`` in the base frame.
        """
        R, p, J, _ = self.jacobians(q, x)
        return R, p, J

    def jacobians(self, q: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Like :meth:`jacobian`, plus the joint Jacobian ``d[p; theta] / dq`` (N, 6, n) from the same pass."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        N, n = q.shape
        x = np.broadcast_to(np.asarray(x, dtype=float), (N, self.size))
        d, t, _ = self._split(x)
        h, dh_da, dh_db = self.axes(t, derivatives=True)  # (N, n, 3)
        H, P = self.geometry(x)
        c = self.nominal.chain(q, H, P)
        J = np.zeros((N, 6, self.size))
        for j in range(n):
            R_prev, R_next = c.R_base_link[j], c.R_base_link[j + 1]
            k = np.stack([self.k1[j], self.k2[j]], axis=1)  # (3, 2)
            J[:, :3, 2 * j: 2 * j + 2] = (R_prev - R_next) @ k
            s = np.sin(q[:, j])[:, None]
            one_c = (1.0 - np.cos(q[:, j]))[:, None]
            r = c.p_base_tool - c.p_base_origin[j]
            for col, dh in ((4 * n // 2 + 2 * j, dh_da[:, j]), (4 * n // 2 + 2 * j + 1, dh_db[:, j])):
                w_local = s * dh + one_c * np.cross(h[:, j], dh)
                w = np.einsum("nij,nj->ni", R_prev, w_local)
                J[:, 3:, col] = w
                J[:, :3, col] = np.cross(w, r)
        if self.fit_tool:
            J[:, :3, 4 * n:] = c.R_base_link[n]
        w = c.axes_base  # (n, N, 3)
        Jq = np.transpose(np.concatenate([np.cross(w, c.p_base_tool[None] - c.p_base_origin[:-1]), w], axis=-1),
                          (1, 2, 0))
        return c.R_base_tool, c.p_base_tool, J, Jq
