"""Product-of-exponentials (POE) kinematics of a serial revolute arm, vectorised over samples.

Convention (general-robotics-toolbox): ``H = [h1..hn]`` unit joint axes in the base frame at q = 0,
``P = [p01, p12, ..., p(n-1)n, pnT]`` link vectors [mm]. Forward kinematics::

    p = p01; R = I
    for i in 1..n: R = R @ rot(h_i, q_i); p += R @ p_{i,i+1}

then the flange rotation and the tool (marker) transform in the flange frame. ``H`` and ``P`` may carry a
leading sample axis, so configuration-dependent models evaluate one geometry per sample in one call.
Pose vectors and Jacobian rows are ordered ``[position (3) mm; rotation (3) rad]``, both in the base frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from calibration.errors import ModelError
from calibration.kinematics import so3
from calibration.kinematics.arrays import FloatArray


def poe_to_dict(m: PoeModel) -> dict[str, Any]:
    return {"H": m.H.T.tolist(), "P": m.P.T.tolist(), "R_flange": m.R_flange.tolist(),
            "R_flange_tool": m.R_flange_tool.tolist(), "p_flange_tool": m.p_flange_tool.tolist()}


def poe_from_dict(d: dict[str, Any]) -> PoeModel:
    return PoeModel(np.array(d["H"], dtype=float).T, np.array(d["P"], dtype=float).T,
                    np.array(d["R_flange"], dtype=float), np.array(d["R_flange_tool"], dtype=float),
                    np.array(d["p_flange_tool"], dtype=float))




@dataclass(frozen=True)
class Chain:
    """Intermediate frames of a forward-kinematics pass over N samples.

    Attributes:
        R_base_link: rotation of link j (after joint j), j = 0..n (link 0 = base), shape (n+1, N, 3, 3).
        p_base_origin: point on joint axis j+1 for j < n, then the flange point, shape (n+1, N, 3).
        axes_base: joint axes in the base frame, shape (n, N, 3).
        R_base_tool: tool rotation, shape (N, 3, 3).
        p_base_tool: tool position [mm], shape (N, 3).
    """

    R_base_link: FloatArray
    p_base_origin: FloatArray
    axes_base: FloatArray
    R_base_tool: FloatArray
    p_base_tool: FloatArray


@dataclass(frozen=True)
class PoeModel:
    """A POE arm with a tool.

    Attributes:
        H: unit joint axes at q = 0 in the base frame, shape (3, n).
        P: link vectors [mm], shape (3, n+1).
        R_flange: rotation of the flange frame in the last link frame, shape (3, 3).
        R_flange_tool: tool rotation in the flange frame, shape (3, 3).
        p_flange_tool: tool position in the flange frame [mm], shape (3,).
    """

    H: FloatArray
    P: FloatArray
    R_flange: FloatArray = field(default_factory=lambda: np.eye(3))
    R_flange_tool: FloatArray = field(default_factory=lambda: np.eye(3))
    p_flange_tool: FloatArray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        H = np.asarray(self.H, dtype=float)
        P = np.asarray(self.P, dtype=float)
        if H.ndim != 2 or H.shape[0] != 3:
            raise ModelError(f"H must have shape (3, n), got {H.shape}")
        if P.shape != (3, H.shape[1] + 1):
            raise ModelError(f"P must have shape (3, {H.shape[1] + 1}) for {H.shape[1]} joints, got {P.shape}")
        norms = np.linalg.norm(H, axis=0)
        if np.any(np.abs(norms - 1.0) > 1e-6):
            raise ModelError(f"joint axes must be unit vectors, norms are {np.round(norms, 6).tolist()}")
        object.__setattr__(self, "H", H)
        object.__setattr__(self, "P", P)
        for name in ("R_flange", "R_flange_tool", "p_flange_tool"):
            object.__setattr__(self, name, np.asarray(getattr(self, name), dtype=float))

    @property
    def n_joints(self) -> int:
        n: int = self.H.shape[1]
        return n

    @property
    def R_6_tool(self) -> np.ndarray:
        """Tool rotation in the last link frame, shape (3, 3)."""
        return self.R_flange @ self.R_flange_tool

    @property
    def p_6_tool(self) -> np.ndarray:
        """Tool position in the last link frame relative to the flange point [mm], shape (3,)."""
        return self.R_flange @ self.p_flange_tool

    def with_geometry(self, H: np.ndarray, P: np.ndarray) -> PoeModel:
        """The same arm and tool with other axes and link vectors."""
        return replace(self, H=H, P=P)

    def chain(self, q: np.ndarray, H: np.ndarray | None = None, P: np.ndarray | None = None) -> Chain:
        """Forward kinematics with every intermediate frame.

        Args:
            q: joint angles [rad], shape (N, n).
            H: axes overriding the model's, shape (3, n) or per sample (N, 3, n).
            P: link vectors overriding the model's, shape (3, n+1) or per sample (N, 3, n+1).
        """
        q, Hs, Ps = self._inputs(q, H, P)
        N, n = q.shape
        R = np.broadcast_to(np.eye(3), (N, 3, 3)).copy()
        p = Ps[:, :, 0].copy()
        Rs = [R]
        origins = [p.copy()]
        axes = []
        for i in range(n):
            axes.append((R @ Hs[:, :, i, None])[..., 0])
            R = R @ so3.rot(Hs[:, :, i], q[:, i])
            p = p + (R @ Ps[:, :, i + 1, None])[..., 0]
            Rs.append(R)
            origins.append(p.copy())
        R_tool = R @ self.R_6_tool
        p_tool = p + R @ self.p_6_tool
        return Chain(np.stack(Rs), np.stack(origins), np.stack(axes), R_tool, p_tool)

    def _inputs(self, q: np.ndarray, H: np.ndarray | None, P: np.ndarray | None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Validated q (N, n) and geometry broadcast to (N, 3, n), (N, 3, n+1)."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        n = self.n_joints
        if q.shape[1] != n:
            raise ModelError(f"q must have {n} columns, got shape {q.shape}")
        H = self.H if H is None else np.asarray(H, dtype=float)
        P = self.P if P is None else np.asarray(P, dtype=float)
        return q, np.broadcast_to(H, (q.shape[0], 3, n)), np.broadcast_to(P, (q.shape[0], 3, n + 1))

    def fk(self, q: np.ndarray, H: np.ndarray | None = None, P: np.ndarray | None = None
           ) -> tuple[np.ndarray, np.ndarray]:
        """Tool pose in the base frame.

        Args:
            q: joint angles [rad], shape (N, n).
            H, P: optional geometry overrides, see :meth:`chain`.

        Returns:
            ``(R_base_tool (N, 3, 3), p_base_tool (N, 3) [mm])``.
        """
        q, Hs, Ps = self._inputs(q, H, P)
        R = so3.rot(Hs[:, :, 0], q[:, 0])
        p = Ps[:, :, 0] + (R @ Ps[:, :, 1, None])[..., 0]
        for i in range(1, self.n_joints):
            R = R @ so3.rot(Hs[:, :, i], q[:, i])
            p = p + (R @ Ps[:, :, i + 1, None])[..., 0]
        return R @ self.R_6_tool, p + R @ self.p_6_tool

    def casadi(self, q: Any, theta: Any = None, q_at: Any = None, kind: str = "poe") -> Any:
        """The chain on casadi symbols q (n,) as a :class:`calibration.kinematics.casadi_expr.CasadiPose` (no parameters)."""
        from calibration.kinematics.casadi_expr import chain_pose, poe_chain  # the casadi path only when asked for

        return chain_pose(poe_chain(self, q), kind)

    def jacobian_q(self, q: np.ndarray, H: np.ndarray | None = None, P: np.ndarray | None = None) -> np.ndarray:
        """Geometric Jacobian of the tool pose with respect to the joint angles.

        Args:
            q: joint angles [rad], shape (N, n).
            H, P: optional geometry overrides, see :meth:`chain`.

        Returns:
            ``d[p; theta] / dq``, shape (N, 6, n): rows 0-2 tool velocity [mm/rad], rows 3-5 angular velocity
            in the base frame.
        """
        c = self.chain(q, H, P)
        w = c.axes_base  # (n, N, 3)
        r = c.p_base_tool[None] - c.p_base_origin[:-1]  # (n, N, 3)
        J = np.concatenate([np.cross(w, r), w], axis=-1)  # (n, N, 6)
        return np.transpose(J, (1, 2, 0))


def pose_error(R_meas: np.ndarray, p_meas: np.ndarray, R: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Position and orientation error of measured against predicted poses.

    Returns:
        ``(position error [mm] (N,), orientation error [deg] (N,))``.
    """
    dp = np.linalg.norm(np.asarray(p_meas) - np.asarray(p), axis=-1)
    dR = np.degrees(np.linalg.norm(so3.log(np.asarray(R_meas) @ np.swapaxes(R, -1, -2)), axis=-1))
    return dp, dR
