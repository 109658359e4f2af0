"""Gravity torques of a POE arm: pinocchio's generalized gravity, and the linear (lumped) regressor.

Sign convention: ``tau_g`` is the torque gravity *exerts* on each joint [N m],
``tau_g = sum_k J_com,k^T m_k g`` with ``g = (0, 0, -9.80665) m/s^2`` along -z of the base frame. It is the
negative of pinocchio's generalized gravity (the torque the motors must supply), so a positive compliance
``delta_q = c tau_g`` makes the arm sag.

Lengths: POE geometry and centres of mass are in millimetres; the pinocchio model is built in metres and
torques are in N m throughout.

Lumped parameters (the mass-free form, linear in the torque): per moving link k, ``[m_k (kg),
m_k s_kx, m_k s_ky, m_k s_kz (kg mm)]`` where ``s_k`` is the centre of mass relative to the point on
joint k's axis (``cumsum(P)[:, k-1]``), in base-aligned axes at q = 0. ``tau_g = Y(q) @ pi`` exactly.
Many columns are not identifiable from torques (joint 1 is vertical, so its row is zero; masses of outer
links mix with first moments of inner ones); a fitter needs a base-parameter reduction, see
:meth:`GravityModel.independent_columns`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from calibration.errors import ModelError
from calibration.kinematics.arrays import FloatArray
from calibration.kinematics.poe import Chain, PoeModel

G_STANDARD = 9.80665  # [m/s^2]
_SPHERE_RADIUS_M = 0.05  # point masses get a small sphere inertia so pinocchio's model is regular


def joint_origins(model: PoeModel) -> np.ndarray:
    """Points on the joint axes at q = 0 in the base frame [mm], shape (n, 3)."""
    return np.cumsum(model.P, axis=1)[:, : model.n_joints].T


def _lever_factors(model: PoeModel, q: np.ndarray, g: float) -> tuple[Chain, FloatArray]:
    """Chain and ``a_i = g_vec x w_i`` [m/s^2] per joint, shape (n, N, 3)."""
    c = model.chain(q)
    g_vec = np.array([0.0, 0.0, -g])
    a = np.cross(g_vec, c.axes_base)
    return c, a


def gravity_regressor(model: PoeModel, q: np.ndarray, g: float = G_STANDARD) -> np.ndarray:
    """Regressor of the gravity torque in the lumped parameters.

    Args:
        model: POE arm (its geometry places the links).
        q: joint angles [rad], shape (N, n).
        g: gravity magnitude [m/s^2], acting along -z of the base.

    Returns:
        ``Y`` with ``tau_g = Y @ pi`` [N m], shape (N, n, 4n); columns per link k as in the module docstring.
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    c, a = _lever_factors(model, q, g)
    n = model.n_joints
    o = c.p_base_origin[:n]  # (n, N, 3) point on axis k, fixed in link k
    Y = np.zeros((q.shape[0], n, 4 * n))
    for k in range(n):
        Rk = c.R_base_link[k + 1]  # (N, 3, 3)
        for i in range(k + 1):
            Y[:, i, 4 * k] = np.einsum("nj,nj->n", a[i], o[k] - o[i]) / 1000.0
            Y[:, i, 4 * k + 1: 4 * k + 4] = np.einsum("nji,nj->ni", Rk, a[i]) / 1000.0
    return Y


def point_mass_torque(model: PoeModel, q: np.ndarray, mass_kg: np.ndarray, g: float = G_STANDARD) -> np.ndarray:
    """Gravity torque [N m] of a point mass at the tool point, shape (N, n).

    Args:
        model: POE arm with tool (the mass sits at ``p_base_tool``).
        q: joint angles [rad], shape (N, n).
        mass_kg: mass per sample [kg], shape (N,) or scalar.
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    c, a = _lever_factors(model, q, g)
    r = c.p_base_tool[None] - c.p_base_origin[:-1]  # (n, N, 3) [mm]
    tau = np.einsum("inj,inj->ni", a, r) / 1000.0
    tau_Nm: FloatArray = tau * np.broadcast_to(np.asarray(mass_kg, dtype=float), (q.shape[0],))[:, None]
    return tau_Nm


def chain_torques(ops: Any, chain: Any, lumped: np.ndarray | None, g: float = G_STANDARD) -> list[Any]:
    """Gravity torque per joint [N m] from a chain of frames, written once for numpy and casadi.

    ``tau_i = sum_{k >= i} a_i . (m_k (o_k - o_i) + R_k (m_k s_k)) / 1000`` with ``a_i = g_vec x w_i``: the
    lumped form of :func:`gravity_regressor` contracted with ``lumped`` (4n,). With ``lumped`` None, the
    torque of 1 kg at the tool point, ``a_i . (p_tool - o_i) / 1000`` (see :func:`point_mass_torque`).

    Args:
        ops: :data:`calibration.kinematics.casadi_expr.NUMPY` (chain of (N, ...) arrays) or ``casadi_ops()``.
        chain: a :class:`calibration.kinematics.poe.Chain` or :class:`calibration.kinematics.casadi_expr.SxChain`.
    """
    g_vec = np.array([0.0, 0.0, -g])
    n = len(chain.axes_base)
    a = [ops.cross(g_vec, chain.axes_base[i]) for i in range(n)]
    o = chain.p_base_origin
    if lumped is None:
        return [ops.dot(a[i], chain.p_base_tool - o[i]) / 1000.0 for i in range(n)]
    tau = []
    for i in range(n):
        t: Any = 0.0
        for k in range(i, n):
            m_k, ms_k = lumped[4 * k], lumped[4 * k + 1: 4 * k + 4]
            t = t + ops.dot(a[i], m_k * (o[k] - o[i]) + ops.matvec(chain.R_base_link[k + 1], ms_k))
        tau.append(t / 1000.0)
    return tau


def chain_torque_columns(ops: Any, chain: Any, joint: int, columns: tuple[int, ...], g: float = G_STANDARD
                         ) -> list[Any]:
    """Columns of :func:`gravity_regressor` for one joint, from a chain of frames, written once for numpy and casadi.

    Column ``4k`` is the torque on ``joint`` [N m] of 1 kg at joint k+1's axis point, ``4k + 1..3`` that of
    1 kg mm of first moment along link k+1's x, y, z axes: ``a . (o_k - o_i) / 1000`` and ``a . R_k e_c / 1000``
    with ``a = g_vec x w_i``.

    Args:
        ops: the backend (:data:`calibration.kinematics.casadi_expr.NUMPY` or ``casadi_ops()``).
        chain: a :class:`calibration.kinematics.poe.Chain` or :class:`calibration.kinematics.casadi_expr.SxChain`.
        joint: 0-based joint index i.
        columns: lumped column indices (0-based, of links k >= i).
    """
    a = ops.cross(np.array([0.0, 0.0, -g]), chain.axes_base[joint])
    o = chain.p_base_origin
    out = []
    for c in columns:
        k, comp = divmod(int(c), 4)
        lever = o[k] - o[joint] if comp == 0 else ops.matvec(chain.R_base_link[k + 1], np.eye(3)[comp - 1])
        out.append(ops.dot(a, lever) / 1000.0)
    return out


def independent_link_columns(model: PoeModel, joint: int, tol: float = 1e-3, n_samples: int = 400) -> tuple[int, ...]:
    """The lumped columns of the links joint ``joint`` (0-based) carries whose torques on that joint are independent
    functions of q: a pivoted QR of the unit-normalised columns at ``n_samples`` fixed joint angles spread over a
    full turn of every joint (a column within ``tol`` of the others' span is left out). The geometry's small
    deviations from the nominal arm (a fitted link a fraction of a millimetre off) stay below ``tol``.
    """
    from scipy.linalg import qr

    q = np.random.default_rng(0).uniform(-np.pi, np.pi, (n_samples, model.n_joints))
    cols = np.arange(4 * joint, 4 * model.n_joints)
    A = gravity_regressor(model, q)[:, joint, cols]
    norm = np.linalg.norm(A, axis=0)
    live = norm > 1e-9 * max(float(norm.max()), 1e-300)
    if not live.any():
        return ()
    _, Rm, piv = qr(A[:, live] / norm[live], mode="economic", pivoting=True)
    d = np.abs(np.diag(Rm))
    rank = int(np.sum(d > tol * d[0]))
    return tuple(int(c) for c in np.sort(cols[live][piv[:rank]]))


@dataclass(frozen=True, eq=False)
class GravityModel:
    """Lumped inertial parameters of the moving links, enough for gravity torques.

    Attributes:
        lumped: ``[m_k (kg), m_k s_k (kg mm) x3]`` per link k = 1..n, shape (4n,).
        g: gravity magnitude [m/s^2] along -z of the base.
    """

    lumped: np.ndarray
    g: float = G_STANDARD

    def __post_init__(self) -> None:
        lumped = np.array(self.lumped, dtype=float).reshape(-1)
        if lumped.size % 4 or not np.all(np.isfinite(lumped)):
            raise ModelError(f"lumped gravity parameters must be 4 finite numbers per link, got {lumped.size}")
        if np.any(lumped[0::4] < 0):
            raise ModelError("link masses must be non-negative")
        object.__setattr__(self, "lumped", lumped)

    @classmethod
    def from_links(cls, model: PoeModel, masses_kg: ArrayLike, com_mm: np.ndarray,
                   g: float = G_STANDARD) -> GravityModel:
        """From link masses [kg] (n,) and centres of mass in the base frame at q = 0 [mm] (n, 3)."""
        m = np.asarray(masses_kg, dtype=float).reshape(-1)
        com = np.asarray(com_mm, dtype=float)
        if m.shape != (model.n_joints,) or com.shape != (model.n_joints, 3):
            raise ModelError(f"expected {model.n_joints} masses and ({model.n_joints}, 3) centres of mass, "
                             f"got {m.shape} and {com.shape}")
        s = com - joint_origins(model)
        return cls(np.concatenate([m[:, None], m[:, None] * s], axis=1).ravel(), g)

    @classmethod
    def from_spec(cls, spec: Any, model: PoeModel | None = None) -> GravityModel:
        """From a :class:`cell_config.loader.RobotSpec` with ``links`` (nominal geometry when model is None)."""
        if not spec.links:
            raise ModelError(f"robot {spec.name} has no 'links' (mass_kg, com_mm) in its YAML")
        model = spec.model() if model is None else model
        return cls.from_links(model, [l.mass_kg for l in spec.links], np.array([l.com_mm for l in spec.links]))

    @property
    def n_links(self) -> int:
        return self.lumped.size // 4

    def names(self) -> list[str]:
        """Lumped parameter names with units."""
        return [f"{p}{k + 1}_{u}" for k in range(self.n_links)
                for p, u in (("m", "kg"), ("mx", "kg_mm"), ("my", "kg_mm"), ("mz", "kg_mm"))]

    def masses_coms(self, model: PoeModel) -> tuple[np.ndarray, np.ndarray]:
        """Masses [kg] (n,) and centres of mass in the base frame at q = 0 [mm] (n, 3) (origin for m = 0)."""
        L = self.lumped.reshape(-1, 4)
        m = L[:, 0]
        s = np.divide(L[:, 1:], m[:, None], out=np.zeros_like(L[:, 1:]), where=m[:, None] > 0)
        return m, joint_origins(model) + s

    def _check(self, model: PoeModel) -> None:
        if model.n_joints != self.n_links:
            raise ModelError(f"gravity model has {self.n_links} links, the arm {model.n_joints} joints")

    def regressor(self, model: PoeModel, q: np.ndarray) -> np.ndarray:
        """``Y (N, n, 4n)`` with ``torque == Y @ lumped``; see :func:`gravity_regressor`."""
        self._check(model)
        return gravity_regressor(model, q, self.g)

    def pinocchio_model(self, model: PoeModel) -> Any:
        """A pinocchio model of the arm: unaligned revolute joints placed at the POE origins, point-mass links."""
        import pinocchio as pin

        self._check(model)
        m, com = self.masses_coms(model)
        o0 = joint_origins(model)
        pm = pin.Model()
        parent, prev = 0, np.zeros(3)
        for i in range(model.n_joints):
            h = model.H[:, i] / np.linalg.norm(model.H[:, i])
            placement = pin.SE3(np.eye(3), (o0[i] - prev) / 1000.0)
            jid = pm.addJoint(parent, pin.JointModelRevoluteUnaligned(h), placement, f"joint{i + 1}")
            inertia = pin.Inertia(float(m[i]), (com[i] - o0[i]) / 1000.0,
                                  np.eye(3) * 0.4 * float(m[i]) * _SPHERE_RADIUS_M**2)
            pm.appendBodyToJoint(jid, inertia, pin.SE3.Identity())
            parent, prev = jid, o0[i]
        pm.gravity = pin.Motion(np.array([0.0, 0.0, -self.g]), np.zeros(3))
        return pm

    def torque(self, model: PoeModel, q: np.ndarray) -> np.ndarray:
        """Gravity torque on each joint [N m], shape (N, n), from ``pin.computeGeneralizedGravity`` (sign flipped,
        see the module docstring)."""
        import pinocchio as pin

        q = np.atleast_2d(np.asarray(q, dtype=float))
        pm = self.pinocchio_model(model)
        data = pm.createData()
        return -np.array([pin.computeGeneralizedGravity(pm, data, qi) for qi in q])

    def independent_columns(self, model: PoeModel, q: np.ndarray, tol: float = 1e-8) -> np.ndarray:
        """Indices of a set of identifiable lumped columns (pivoted QR of the stacked regressor at ``q``)."""
        from scipy.linalg import qr

        Y = self.regressor(model, q).reshape(-1, 4 * self.n_links)
        _, Rm, piv = qr(Y, mode="economic", pivoting=True)
        d = np.abs(np.diag(Rm))
        rank = int(np.sum(d > tol * max(d[0], 1e-300)))
        return np.sort(piv[:rank])

    def to_dict(self) -> dict[str, Any]:
        return {"lumped": self.lumped.tolist(), "g": float(self.g)}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> GravityModel:
        return cls(np.array(d["lumped"], dtype=float), float(d.get("g", G_STANDARD)))
