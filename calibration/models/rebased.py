"""The ``rebased`` model kind: any fitted model with its two frames corrected for a new day.

``T_base_marker(q) = T_base_correction @ T_inner(q + joint_offsets) @ T_tool_correction``: a rigid correction of
the base (mocap-to-base registration) on the left and of the tool marker (marker-to-flange registration) on the
right of the inner model's pose; both constant (4, 4) [mm]; and, optionally, constant joint-angle offsets [rad]
added to the readings before the inner model sees them (a day whose joint zeros moved; zero by default, and then
not written to the file). :func:`calibration.frames.rebase.rebase` fits them.

Its blocks are the inner model's, then ``base_correction`` and ``tool_correction`` (6 each): perturbations
``[dp (3) mm, dtheta (3) rad]`` about the stored corrections, ``p <- p + dp``, ``R <- exp(dtheta) R`` (the
convention of :func:`calibration.frames.registration.retract`), so ``vector()`` ends in 12 zeros. Its pose, its
analytic Jacobians and its casadi expression all wrap the inner model's by the same two transforms.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, ClassVar

import numpy as np

from calibration.errors import ModelError, ModelFileError
from calibration.kinematics import so3
from calibration.kinematics.blocks import Block
from calibration.kinematics.casadi_expr import CasadiPose, exp_sx
from calibration.kinematics.poe import PoeModel
from calibration.kinematics.so3 import make_T
from calibration.models.base import KinematicModel

#: Names of one correction block (perturbation of a transform in its parent frame).
CORRECTION_NAMES = ("dx", "dy", "dz", "rx", "ry", "rz")


def wrap_pose(T_base: np.ndarray, R: np.ndarray, p: np.ndarray, T_tool: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
    """``T_base @ (R, p) @ T_tool`` for poses ``R`` (N, 3, 3), ``p`` (N, 3) [mm]."""
    R_b, p_b, R_t, p_t = T_base[:3, :3], T_base[:3, 3], T_tool[:3, :3], T_tool[:3, 3]
    return R_b @ R @ R_t, (R @ p_t + p) @ R_b.T + p_b


def _checked_T(value: Any, what: str) -> np.ndarray:
    T = np.array(value, dtype=float)
    if T.shape != (4, 4) or not np.isfinite(T).all() or not np.array_equal(T[3], [0.0, 0.0, 0.0, 1.0]):
        raise ModelError(f"{what} must be a finite homogeneous transform (4, 4), got shape {T.shape}")
    if float(np.max(np.abs(T[:3, :3].T @ T[:3, :3] - np.eye(3)))) > 1e-6 or np.linalg.det(T[:3, :3]) < 0:
        raise ModelError(f"{what}: its rotation block is not a rotation")
    return T


@dataclass
class RebasedModel(KinematicModel):
    """An inner model of any kind with constant base and tool-marker corrections (kind ``rebased``).

    Attributes:
        robot, method: as every model (``method`` is the inner model's).
        inner: the model that was fitted on another day.
        T_base_correction: left correction (4, 4) [mm]: new base frame from the inner model's base frame.
        T_tool_correction: right correction (4, 4) [mm]: the new marker in the inner model's marker frame.
        fitted: number of correction directions the data determined (the rest were held at identity).
        info: free metadata (what the rebase held, on which data, its residuals).
        joint_offsets: constant offsets [rad] added to the joint readings, shape (n,) (zeros: none). Constants of
            the rebase, like the corrections; not part of :meth:`vector`.
    """

    kind: ClassVar[str] = "rebased"
    robot: str
    method: str
    inner: KinematicModel
    T_base_correction: np.ndarray = field(default_factory=lambda: np.eye(4))
    T_tool_correction: np.ndarray = field(default_factory=lambda: np.eye(4))
    fitted: int = 0
    info: dict[str, Any] = field(default_factory=dict)
    joint_offsets: np.ndarray = field(default_factory=lambda: np.zeros(6))

    def __post_init__(self) -> None:
        self.T_base_correction = _checked_T(self.T_base_correction, "T_base_correction")
        self.T_tool_correction = _checked_T(self.T_tool_correction, "T_tool_correction")
        dq = np.array(self.joint_offsets, dtype=float)
        if dq.shape != (6,) or not np.isfinite(dq).all():
            raise ModelError(f"joint_offsets must be 6 finite numbers [rad], got shape {dq.shape}")
        self.joint_offsets = dq

    def _shifted(self, q: Any) -> Any:
        """The readings as the inner model sees them (``q`` itself when there are no offsets)."""
        if q is None or not self.joint_offsets.any():
            return q
        if isinstance(q, np.ndarray):
            return q + self.joint_offsets
        import casadi as ca

        return q + ca.DM(self.joint_offsets)

    def fk(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.fk_context(q, None)

    def fk_context(self, q: np.ndarray, context: Any) -> tuple[np.ndarray, np.ndarray]:
        """The inner model's pose at the shifted readings and the context, in the corrected frames."""
        R, p = self.inner.fk_context(self._shifted(np.asarray(q, dtype=float)), context)
        return wrap_pose(self.T_base_correction, R, p, self.T_tool_correction)

    def out_of_range(self, q: np.ndarray) -> np.ndarray:
        return self.inner.out_of_range(self._shifted(np.asarray(q, dtype=float)))

    @property
    def context_keys(self) -> frozenset[str]:
        return self.inner.context_keys

    def interpolation(self) -> Any:
        return self.inner.interpolation()

    def region(self) -> Any:
        """The training region in this model's joint readings: its own (set by :meth:`with_region`), else its inner
        model's, moved by the joint offsets. A rebase keeps the inner model's data, so it keeps its range: without
        this, evaluate said nothing of poses far outside it (0725's test recording on a rebased 0801 model, 92 deg)."""
        own = KinematicModel.region(self)
        if own is not None:
            return own
        inner = self.inner.region()
        if inner is None or not self.joint_offsets.any():
            return inner
        return replace(inner, lower_rad=inner.lower_rad - self.joint_offsets,
                       upper_rad=inner.upper_rad - self.joint_offsets)

    def with_region(self, region: Any) -> RebasedModel:
        """The same rebase with another training region (in its joint readings), in its own info and its inner
        model's (the one that holds), moved by the joint offsets into the inner model's readings."""
        own = KinematicModel.with_region(self, region)
        if region is not None and self.joint_offsets.any():
            region = replace(region, lower_rad=region.lower_rad + self.joint_offsets,
                             upper_rad=region.upper_rad + self.joint_offsets)
        return replace(own, inner=self.inner.with_region(region))

    @property
    def n_parameters(self) -> int:
        return int(self.inner.n_parameters) + int(self.fitted)

    def blocks(self) -> tuple[Block, ...]:
        """The inner model's blocks, then the base and tool corrections (6 each)."""
        return tuple(self.inner.blocks()) + (
            Block("base_correction", tuple(f"base_{n}" for n in CORRECTION_NAMES)),
            Block("tool_correction", tuple(f"tool_{n}" for n in CORRECTION_NAMES)))

    def vector(self) -> np.ndarray:
        return np.concatenate([self.inner.vector(), np.zeros(12)])

    def with_vector(self, theta: np.ndarray) -> RebasedModel:
        theta = np.asarray(theta, dtype=float)
        k = theta.size - 12
        d = theta[k:]
        T_b, T_t = self.T_base_correction, self.T_tool_correction
        return replace(self, inner=self.inner.with_vector(theta[:k]),
                       T_base_correction=make_T(so3.exp(d[3:6]) @ T_b[:3, :3], T_b[:3, 3] + d[0:3]),
                       T_tool_correction=make_T(so3.exp(d[9:12]) @ T_t[:3, :3], T_t[:3, 3] + d[6:9]))

    def _wrap_jacobian(self, R: np.ndarray, J: np.ndarray) -> np.ndarray:
        """An inner pose Jacobian ``d[p; rot]`` (N, 6, m) at inner rotations R (N, 3, 3), seen through the
        corrections: ``dp' = R_b (dp - [R p_t]x drot)``, ``drot' = R_b drot``."""
        R_b, p_t = self.T_base_correction[:3, :3], self.T_tool_correction[:3, 3]
        lever = so3.hat(R @ p_t)  # (N, 3, 3)
        out = np.empty_like(J)
        out[:, :3] = R_b @ (J[:, :3] - lever @ J[:, 3:])
        out[:, 3:] = R_b @ J[:, 3:]
        return out

    def _correction_columns(self, R_i: np.ndarray, p: np.ndarray) -> np.ndarray:
        """``d[p; rot] / d`` the 12 correction perturbations (N, 6, 12), at inner rotations R_i and poses p."""
        R_wf = self.T_base_correction[:3, :3] @ R_i  # inner rotation in the new base frame
        J_c = np.zeros((p.shape[0], 6, 12))
        J_c[:, :3, 0:3] = np.eye(3)
        J_c[:, :3, 3:6] = -so3.hat(p - self.T_base_correction[:3, 3])
        J_c[:, 3:, 3:6] = np.eye(3)
        J_c[:, :3, 6:9] = R_wf
        J_c[:, 3:, 9:12] = R_wf
        return J_c

    def jacobian(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pose and ``d[p; rot] / d vector`` (N, 6, m + 12): the inner Jacobian wrapped, then the corrections'."""
        R_i, p_i, J_i = self.inner.jacobian(self._shifted(np.asarray(q, dtype=float)))
        R, p = wrap_pose(self.T_base_correction, R_i, p_i, self.T_tool_correction)
        return R, p, np.concatenate([self._wrap_jacobian(R_i, J_i), self._correction_columns(R_i, p)], axis=2)

    def jacobian_q(self, q: np.ndarray) -> np.ndarray:
        qs = self._shifted(np.asarray(q, dtype=float))
        R_i, _ = self.inner.fk(qs)
        return self._wrap_jacobian(R_i, self.inner.jacobian_q(qs))

    def rebase_jacobian(self, q: np.ndarray, joints: tuple[int, ...] = ()) -> tuple[np.ndarray, np.ndarray,
                                                                                     np.ndarray]:
        """Pose and ``d[p; rot]`` / d the rebase's own parameters (N, 6, 12 + k): the 12 correction
        perturbations, then the offsets of ``joints`` (1-based) [rad]; the inner model's parameters fixed."""
        qs = self._shifted(np.asarray(q, dtype=float))
        R_i, p_i = self.inner.fk(qs)
        R, p = wrap_pose(self.T_base_correction, R_i, p_i, self.T_tool_correction)
        J = self._correction_columns(R_i, p)
        if joints:
            J_q = self._wrap_jacobian(R_i, self.inner.jacobian_q(qs))
            J = np.concatenate([J, J_q[:, :, [j - 1 for j in joints]]], axis=2)
        return R, p, J

    def casadi(self, q: Any, theta: Any = None, q_at: Any = None) -> CasadiPose:
        """The inner model's expression wrapped by the corrections (constants when ``theta`` is None, else the
        last 12 symbols perturb them as :meth:`with_vector` does); the skeleton moves with the base only."""
        import casadi as ca


        k = self.inner.vector().size
        pose = self.inner.casadi(self._shifted(q), None if theta is None else theta[:k], self._shifted(q_at))
        R_b, p_b = ca.DM(self.T_base_correction[:3, :3]), ca.DM(self.T_base_correction[:3, 3])
        R_t, p_t = ca.DM(self.T_tool_correction[:3, :3]), ca.DM(self.T_tool_correction[:3, 3])
        if theta is not None:
            d = theta[k:k + 12]
            R_b, p_b = exp_sx(d[3:6]) @ R_b, p_b + d[0:3]
            R_t, p_t = exp_sx(d[9:12]) @ R_t, p_t + d[6:9]
        tool = replace(pose, R=pose.R @ R_t, p=pose.p + pose.R @ p_t)
        return replace(tool.transformed(R_b, p_b), kind=pose.kind)

    def pose_at(self, q: np.ndarray, q_at: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        R, p = self.inner.pose_at(self._shifted(np.asarray(q, dtype=float)),
                                  self._shifted(np.asarray(q_at, dtype=float)))
        return wrap_pose(self.T_base_correction, R, p, self.T_tool_correction)

    def effects_arm(self) -> PoeModel:
        raise ModelError("a rebased model cannot carry effects: add them to the inner model, then rebase it")

    def urdf_geometry(self) -> Any:
        geo = self.inner.urdf_geometry()
        if self.joint_offsets.any():
            geo = replace(geo, lost=tuple(geo.lost) + (
                "the rebase's joint offsets " + ", ".join(f"joint {j + 1} {np.degrees(v):+.4f} deg" for j, v in
                                                          enumerate(self.joint_offsets) if v)
                + " (add them to the joint readings)",))
        return replace(geo, exported=f"{geo.exported} with the rebase's base and tool-marker corrections",
                       T_base=self.T_base_correction @ geo.T_base, T_tool=geo.T_tool @ self.T_tool_correction)

    def _body(self) -> dict[str, Any]:
        T_b, T_t = self.T_base_correction, self.T_tool_correction
        return {"inner": self.inner.to_dict(), "R_base_correction": T_b[:3, :3].tolist(),
                "p_base_correction": T_b[:3, 3].tolist(), "R_tool_correction": T_t[:3, :3].tolist(),
                "p_tool_correction": T_t[:3, 3].tolist(), "fitted": int(self.fitted),
                **({"joint_offsets_rad": self.joint_offsets.tolist()} if self.joint_offsets.any() else {})}

    @classmethod
    def _from_body(cls, robot: str, method: str, info: dict[str, Any], body: dict[str, Any]) -> RebasedModel:
        if not isinstance(body.get("inner"), dict):
            raise ModelFileError("", "inner", "expected the wrapped model (a mapping)")
        inner = KinematicModel.from_dict(body["inner"])
        T = {}
        for side in ("base", "tool"):
            R, p = np.array(body[f"R_{side}_correction"], dtype=float), np.array(body[f"p_{side}_correction"],
                                                                                   dtype=float)
            if R.shape != (3, 3) or p.shape != (3,):
                raise ModelFileError("", f"p_{side}_correction", "expected a 3x3 rotation and 3 numbers")
            T[side] = make_T(R, p)
        offsets = body.get("joint_offsets_rad", [0.0] * 6)
        try:
            offsets = np.array(offsets, dtype=float)
        except (TypeError, ValueError):
            raise ModelFileError("", "joint_offsets_rad", f"expected 6 numbers [rad], got {offsets!r}") from None
        if offsets.shape != (6,) or not np.isfinite(offsets).all():
            raise ModelFileError("", "joint_offsets_rad", f"expected 6 finite numbers [rad], got {offsets.tolist()}")
        return cls(robot, method, inner, T["base"], T["tool"], int(body.get("fitted", 0)), info, offsets)
