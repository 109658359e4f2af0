"""The ``cdc`` model kind: the ``pi`` layout with its geometric block interpolated over (q2, q3).

Its blocks are the terms every configuration shares (tool rotation, compliance, deflection); the geometric
block is the interpolator's. Its casadi expression writes the interpolator out in casadi through the kind's
``casadi_predict`` (:func:`calibration.kinematics.casadi_expr.interpolator_sx`; every built-in kind has one), clipped
to ``bounds`` like the numpy path, so derivatives include the parameters' dependence on q; for an
interpolator without one the geometric block is a frozen input (kind ``cdc-frozen``). The fits that build it are in
:mod:`calibration.methods.cdc`.

Its reference (:attr:`CdcModel.reference`) is ``geometric`` when every term beyond the geometric block is zero
(the paper's construction: methods ``fbf13``, ``linear``, ...) and ``pi`` otherwise (``pi+fbf13``, ...). The file
records it as ``reference``, checked against ``theta_ref`` on load; files written before the key existed carry
no such key and load with the reference their ``theta_ref`` implies (they were all built on pi, whatever their
method name says).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, ClassVar

import numpy as np

from calibration.errors import ModelFileError
from calibration.interpolation import interpolator_from_dict
from calibration.kinematics.arrays import BoolArray
from calibration.kinematics.blocks import Block
from calibration.kinematics.casadi_expr import CasadiPose, interpolator_sx
from calibration.kinematics.parameterisation import MinimalParameterisation
from calibration.kinematics.poe import PoeModel, poe_from_dict, poe_to_dict
from calibration.models.base import KinematicModel
from calibration.physics.extended import ExtendedKinematics

CDC_INPUTS = (1, 2)  # q2, q3 (0-based)


@dataclass
class CdcModel(KinematicModel):
    """Configuration-dependent model: the geometric block of an extended model interpolated over (q2, q3)."""

    kind: ClassVar[str] = "cdc"
    robot: str
    method: str
    kinematics: ExtendedKinematics
    theta_ref: np.ndarray
    interpolator: Any  # calibration.interpolation.Interpolator
    inputs: tuple[int, ...] = CDC_INPUTS
    info: dict[str, Any] = field(default_factory=dict)
    #: per-parameter [min, max] of the geometric block, shape (2, g), or None: the interpolated parameters are
    #: clipped to it (the local fits' range), so no kind extrapolates beyond what the anchors span.
    bounds: np.ndarray | None = None

    @property
    def reference(self) -> str:
        """``geometric`` (every non-geometric term of ``theta_ref`` is zero: the paper's construction) or ``pi``."""
        return _reference(self.theta_ref, self.kinematics.par.size)

    def interpolation(self) -> Any:
        return self.interpolator

    def _clip(self, x: np.ndarray) -> np.ndarray:
        return x if self.bounds is None else np.clip(x, self.bounds[0], self.bounds[1])

    def parameters_at(self, q: np.ndarray) -> np.ndarray:
        """Full extended parameters per sample, shape (N, size): the reference with interpolated geometry."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        theta = np.array(np.broadcast_to(self.theta_ref, (q.shape[0], self.kinematics.size)))
        theta[:, : self.kinematics.par.size] = self._clip(self.interpolator.predict(q[:, list(self.inputs)]))
        return theta

    def fk(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.kinematics.pose(q, self.parameters_at(q))

    def out_of_range(self, q: np.ndarray) -> np.ndarray:
        q = np.atleast_2d(np.asarray(q, dtype=float))
        outside: BoolArray = self.interpolator.out_of_range(q[:, list(self.inputs)])
        return outside

    @property
    def n_parameters(self) -> int:
        return int(self.info.get("n_parameters", self.kinematics.size))

    def blocks(self) -> tuple[Block, ...]:
        """The blocks shared by every configuration (tool, compliance, deflection); the geometric block is the
        interpolator's."""
        return self.kinematics.blocks()[1:]

    def vector(self) -> np.ndarray:
        return np.asarray(self.theta_ref[self.kinematics.par.size:], dtype=float).copy()

    def with_vector(self, theta: np.ndarray) -> CdcModel:
        g = self.kinematics.par.size
        return replace(self, theta_ref=np.concatenate([self.theta_ref[:g], np.asarray(theta, dtype=float)]))

    def jacobian(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        R, p, J = self.kinematics.jacobian(q, self.parameters_at(q))
        return R, p, J[..., self.kinematics.par.size:]

    def casadi(self, q: Any, theta: Any = None, q_at: Any = None) -> CasadiPose:
        """The pose on casadi symbols; the geometric block is the interpolator's expression of ``q_at``'s (q2,
        q3) when it has one, else a frozen input (kind ``cdc-frozen``) that a caller fixes at an iterate."""
        import casadi as ca

        kin, g = self.kinematics, self.kinematics.par.size
        kin.check_casadi(self.theta_ref)
        rest = ca.DM(self.theta_ref[g:]) if theta is None else theta
        q_at = q if q_at is None else q_at
        u = ca.SX.sym("u", len(self.inputs))
        expr = interpolator_sx(self.interpolator, u, g)
        if expr is not None:
            if self.bounds is not None:
                expr = ca.fmin(ca.fmax(expr, ca.DM(self.bounds[0])), ca.DM(self.bounds[1]))
            xq = ca.substitute(expr, u, ca.vertcat(*[q_at[i] for i in self.inputs]))
            return replace(kin.casadi(q, ca.vertcat(xq, rest)), kind="cdc")
        x = ca.SX.sym("x", g)
        e = kin.casadi(q, ca.vertcat(x, rest))
        return replace(e, kind="cdc-frozen", frozen=x,
                       frozen_at=lambda qq: self.parameters_at(np.asarray(qq, dtype=float)[None])[0, :g])

    def pose_at(self, q: np.ndarray, q_at: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pose at joint angles q (N, 6) [rad] the kinematics see, the geometry interpolated at ``q_at``."""
        return self.kinematics.pose(q, self.parameters_at(q_at))

    def effects_arm(self) -> PoeModel:
        """The POE arm effects acting on this model see: its reference geometry."""
        return self.kinematics.par.model(self.theta_ref[: self.kinematics.par.size])

    def effects_geometry(self, theta: Any = None) -> tuple[PoeModel, Any, Any]:
        """The arm effects on this model act on (its reference geometry), in casadi: ``(nominal, H, P)``."""
        import casadi as ca

        par = self.kinematics.par
        H, P = par.geometry(self.theta_ref[: par.size])
        return par.nominal, ca.DM(H), ca.DM(P)

    def urdf_geometry(self) -> Any:
        from calibration.models.urdf import UrdfGeometry  # xml.etree only when a URDF is asked for

        joints = ", ".join(f"q{i + 1}" for i in self.inputs)
        lost = (f"the configuration-dependent geometry (the {self.kinematics.par.size} geometric parameters "
                f"interpolated over {joints} by the {self.interpolator.__class__.__name__}; the URDF holds them "
                "at theta_ref everywhere)",) + self.kinematics.lost_terms(self.theta_ref)
        return UrdfGeometry(self.kinematics.constant_arm(self.theta_ref),
                            f"the reference geometry theta_ref of the {self.method} model", lost)

    def _body(self) -> dict[str, Any]:
        return {"nominal": poe_to_dict(self.kinematics.par.nominal), "fit_tool": self.kinematics.par.fit_tool,
                "reference": self.reference, "theta_ref": self.theta_ref.tolist(), "inputs": list(self.inputs),
                "interpolator": self.interpolator.to_dict(),
                **({} if self.bounds is None else {"bounds": self.bounds.tolist()})}

    @classmethod
    def _from_body(cls, robot: str, method: str, info: dict[str, Any], body: dict[str, Any]) -> CdcModel:

        kin = ExtendedKinematics(MinimalParameterisation(poe_from_dict(body["nominal"]), bool(body["fit_tool"])))
        theta_ref = _vector(body["theta_ref"], kin.size, "theta_ref")
        if "reference" in body and body["reference"] != _reference(theta_ref, kin.par.size):
            implied = _reference(theta_ref, kin.par.size)
            raise ModelFileError("", "reference", f"{body['reference']!r} does not match theta_ref, whose terms beyond "
                                                  f"the geometric block make it {implied!r}")
        interpolator = interpolator_from_dict(body["interpolator"])
        inputs = _inputs(body["inputs"], kin.par.n_joints, interpolator.n_inputs)
        if interpolator.n_outputs != kin.par.size:
            raise ModelFileError("", "interpolator.n_outputs", f"expected {kin.par.size} (the geometric block), "
                                                               f"got {interpolator.n_outputs}")
        bounds = None
        if "bounds" in body:
            lo_hi = body["bounds"]
            if not (isinstance(lo_hi, list) and len(lo_hi) == 2):
                raise ModelFileError("", "bounds", f"expected [min list, max list], got {lo_hi!r}")
            bounds = np.stack([_vector(lo_hi[0], kin.par.size, "bounds"), _vector(lo_hi[1], kin.par.size, "bounds")])
        return cls(robot, method, kin, theta_ref, interpolator, inputs, info, bounds)


def _reference(theta_ref: np.ndarray, n_geometric: int) -> str:
    return "pi" if np.any(theta_ref[n_geometric:]) else "geometric"


def _vector(value: Any, size: int, key: str) -> np.ndarray:
    """``value`` as a float vector of ``size`` entries, or a ModelFileError naming ``key``."""
    v = np.array(value, dtype=float) if isinstance(value, list) else None
    if v is None or v.shape != (size,):
        got = f"{len(value)} entries" if isinstance(value, list) else repr(value)
        raise ModelFileError("", key, f"expected a list of {size} numbers, got {got}")
    return v


def _inputs(value: Any, n_joints: int, n_inputs: int) -> tuple[int, ...]:
    """The joint indices (0-based) the interpolator reads, checked against the arm and the interpolator."""
    ok = (isinstance(value, list) and all(isinstance(i, int) and not isinstance(i, bool) for i in value)
          and all(0 <= i < n_joints for i in value) and len(set(value)) == len(value))
    if not ok:
        raise ModelFileError("", "inputs", f"expected distinct joint indices 0..{n_joints - 1} (q2, q3: [1, 2]), "
                                           f"got {value!r}")
    if len(value) != n_inputs:
        raise ModelFileError("", "inputs", f"the interpolator takes {n_inputs} inputs, the list names {len(value)}")
    return tuple(value)
