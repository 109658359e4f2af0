"""URDF export: pinocchio's URDF parser reads the written file back and its forward kinematics to the
tool-marker frame agrees with cellcal's on 1000 random configurations within the joint limits.

The figures (max position / rotation difference per case) are printed; run with ``-s`` to see them.
"""

from __future__ import annotations

import numpy as np
import pytest

from calibration import so3
from calibration.diagnosis.model import DiagnosedModel
from calibration.errors import ModelError
from calibration.models import ConstantModel
from calibration.models.base import KinematicModel
from calibration.models.rebased import RebasedModel, wrap_pose
from calibration.parameterisation import MinimalParameterisation
from calibration.physics import PhysicsModel
from calibration.physics_informed import PhysicsInformedModel
from calibration.urdf import JointLimits, R_from_rpy, rpy_from_R, urdf_text, write_urdf
from cell_config import load_cell
from tests.calibration.kinds import T_BASE, T_TOOL, models_of_every_kind
from tests.conftest import planted_parameters

pin = pytest.importorskip("pinocchio")

N_POSES = 1000
POSITION_TOL_MM = 1e-6
ROTATION_TOL_RAD = 1e-9


def limits_of(robot) -> JointLimits:
    spec = load_cell().robot(robot).robot
    return JointLimits(spec.lower_rad, spec.upper_rad, spec.max_speed_rad_s)


def random_q(robot: str, seed: int = 0) -> np.ndarray:
    lim = limits_of(robot)
    return np.random.default_rng(seed).uniform(lim.lower_rad, lim.upper_rad, (N_POSES, 6))


def urdf_fk(text: str, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tool-marker pose (R (N, 3, 3), p (N, 3) [mm]) of a URDF document, computed by pinocchio."""
    model = pin.buildModelFromXML(text)
    data = model.createData()
    frame = model.getFrameId("tool_marker", pin.FrameType.BODY)
    R, p = np.empty((len(q), 3, 3)), np.empty((len(q), 3))
    for k, qk in enumerate(q):
        pin.framesForwardKinematics(model, data, qk)
        R[k], p[k] = data.oMf[frame].rotation, data.oMf[frame].translation * 1e3
    return R, p


def differences(R_a, p_a, R_b, p_b) -> tuple[float, float]:
    """Max position difference [mm] and max rotation angle difference [rad] over the poses."""
    dp = np.linalg.norm(p_a - p_b, axis=1).max()
    dR = np.linalg.norm(so3.log(np.swapaxes(R_a, -1, -2) @ R_b), axis=-1).max()
    return float(dp), float(dR)


def planted(robot: str) -> ConstantModel:
    par = MinimalParameterisation(load_cell().robot(robot).model(), fit_tool=True)
    return ConstantModel(robot, "nls1", par.model(planted_parameters(par)), par.size)


@pytest.mark.parametrize("robot", ["R1", "R2"])
@pytest.mark.parametrize("case", ["nominal", "planted"])
def test_urdf_fk_matches_constant_model(robot, case, tmp_path):
    model = (ConstantModel(robot, "nominal", load_cell().robot(robot).model()) if case == "nominal"
             else planted(robot))
    path = tmp_path / "robot.urdf"
    write_urdf(path, model.urdf_geometry(), limits_of(robot), robot)
    q = random_q(robot)
    pm = pin.buildModelFromUrdf(str(path))
    assert pm.nq == 6
    np.testing.assert_allclose(pm.lowerPositionLimit, limits_of(robot).lower_rad, rtol=0, atol=0)
    np.testing.assert_allclose(pm.upperPositionLimit, limits_of(robot).upper_rad, rtol=0, atol=0)
    R_u, p_u = urdf_fk(path.read_text(), q)
    R_m, p_m = model.fk(q)
    dp, dR = differences(R_u, p_u, R_m, p_m)
    print(f"\nURDF vs cellcal, {robot} {case}, {N_POSES} poses: max position {dp:.3e} mm, max rotation {dR:.3e} rad")
    assert dp <= POSITION_TOL_MM and dR <= ROTATION_TOL_RAD
    if case == "planted":  # the test can fail: the nominal URDF is millimetres away from the planted model
        dp_nominal, _ = differences(*urdf_fk(urdf_text(ConstantModel(robot, "nominal", load_cell().robot(robot)
                                                                     .model()).urdf_geometry(), limits_of(robot),
                                                       robot), q), R_m, p_m)
        assert dp_nominal > 0.5


@pytest.fixture(scope="module")
def kinds() -> dict:
    """A model of every kind with non-trivial parameters, and the constant pose its URDF must reproduce."""
    k = models_of_every_kind()
    par, kin, theta, geometry, effects, pi, cdc = k.par, k.kin, k.theta, k.geometry, k.effects, k.pi, k.cdc
    constant, T_base, T_tool = k.constant, T_BASE, T_TOOL
    geometric = theta.copy()  # theta with the compliance and the deflection at zero
    geometric[par.size + 3:] = 0.0

    def pi_geometry(q):
        return kin.pose(q, geometric)

    return {"constant": (constant, constant.fk, ()),
            "pi": (pi, pi_geometry, ("compliance", "deflection")),
            "cdc": (cdc, pi_geometry, ("configuration-dependent", "q2, q3", "theta_ref", "compliance")),
            "physics": (PhysicsModel("R1", "diagnose", geometry, effects), geometry.fk,
                        ("joint_compliance", "joint_offset")),
            "diagnosed": (DiagnosedModel("R1", "diagnose", pi, effects), pi_geometry,
                          ("compliance", "deflection", "joint_compliance", "joint_offset")),
            "rebased": (RebasedModel("R1", "nls1", pi, T_base, T_tool, 12),
                        lambda q: wrap_pose(T_base, *pi_geometry(q), T_tool), ("compliance", "deflection"))}


@pytest.mark.parametrize("kind", ["constant", "pi", "cdc", "physics", "diagnosed", "rebased"])
def test_urdf_of_every_kind_holds_its_constant_geometry_and_names_what_is_lost(kinds, kind):
    model, reference, lost_words = kinds[kind]
    geometry = model.urdf_geometry()
    text = urdf_text(geometry, limits_of("R1"), "R1", "model.yaml")
    q = random_q("R1", seed=1)
    R_u, p_u = urdf_fk(text, q)
    dp, dR = differences(R_u, p_u, *reference(q))
    print(f"\nURDF vs {kind}'s exported geometry, {N_POSES} poses: max position {dp:.3e} mm, rotation {dR:.3e} rad")
    assert dp <= POSITION_TOL_MM and dR <= ROTATION_TOL_RAD
    lost = " ".join(geometry.lost)
    for word in lost_words:
        assert word in lost, (word, lost)
        assert word in text  # the URDF comment says it too
    if lost_words:  # what is lost is real: the full model differs from its URDF
        dp_full, _ = differences(R_u, p_u, *model.fk(q))
        assert dp_full > 1e-3
    else:
        assert "Lost: nothing" in text


def test_a_kind_without_constant_geometry_is_refused():
    class Opaque(ConstantModel):
        kind = "opaque_test_kind"
        urdf_geometry = KinematicModel.urdf_geometry

    with pytest.raises(ModelError, match="opaque_test_kind model cannot be exported as a URDF; exportable kinds"):
        Opaque("R1", "nls1", load_cell().robot("R1").model()).urdf_geometry()
    KinematicModel._registry.pop("opaque_test_kind")


@pytest.mark.parametrize("rpy", [(0.3, -0.2, 1.1), (0.0, -np.pi / 2, np.pi), (0.0, np.pi / 2, -0.4), (3.0, 0.1, -3.0)])
def test_rpy_round_trip_including_gimbal_lock(rpy):
    R = R_from_rpy(*rpy)
    np.testing.assert_allclose(R_from_rpy(*rpy_from_R(R)), R, rtol=0, atol=1e-15)


def test_rpy_refuses_a_non_rotation():
    with pytest.raises(ModelError, match="not a rotation"):
        rpy_from_R(np.diag([1.0, 1.0, -1.0]))


def test_lost_names_only_the_blocks_a_model_uses(kinds):
    pi = kinds["pi"][0]
    par = pi.kinematics.par
    theta = pi.theta.copy()
    theta[par.size + 3:] = 0.0
    assert PhysicsInformedModel("R1", "pi", pi.kinematics, theta, pi.rank).urdf_geometry().lost == ()
    theta[par.size + 3] = 1e-4  # one compliance parameter: the compliance is lost, the (zero) deflection is not
    lost = PhysicsInformedModel("R1", "pi", pi.kinematics, theta, pi.rank).urdf_geometry().lost
    assert len(lost) == 1 and "compliance" in lost[0]
