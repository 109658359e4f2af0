"""URDF export: pinocchio's URDF parser reads the written file back and its forward kinematics to the
tool-marker frame, relative to the ``base`` link (the robot frame), agrees with cellcal's on 1000 random
configurations within the joint limits; the ROS-Industrial Motoman names, floor height, efforts and meshes are
those of the robot YAML and ros-industrial/motoman's descriptions.

The figures (max position / rotation difference per case) are printed; run with ``-s`` to see them.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pytest

from calibration.errors import ModelError
from calibration.kinematics import so3
from calibration.kinematics.parameterisation import MinimalParameterisation
from calibration.models import ConstantModel
from calibration.models.base import KinematicModel
from calibration.models.diagnosed import DiagnosedModel
from calibration.models.physics import PhysicsModel
from calibration.models.pi import PhysicsInformedModel
from calibration.models.rebased import RebasedModel, wrap_pose
from calibration.models.registry import KINDS
from calibration.models.urdf import (
    ROS_JOINTS,
    ROS_LINKS,
    JointLimits,
    R_from_rpy,
    UrdfLayout,
    rpy_from_R,
    urdf_text,
    write_urdf,
    xacro_text,
)
from cell_config import load_cell
from tests.calibration.models.kinds import T_BASE, T_TOOL, models_of_every_kind
from tests.conftest import planted_parameters

pin = pytest.importorskip("pinocchio")

N_POSES = 1000
POSITION_TOL_MM = 1e-6
ROTATION_TOL_RAD = 1e-9


def limits_of(robot) -> JointLimits:
    spec = load_cell().robot(robot).robot
    return JointLimits(spec.lower_rad, spec.upper_rad, spec.max_speed_rad_s, spec.max_torque_Nm)


def layout_of(robot) -> UrdfLayout:
    return UrdfLayout(load_cell().robot(robot).robot.base_height_mm)


def random_q(robot: str, seed: int = 0) -> np.ndarray:
    lim = limits_of(robot)
    return np.random.default_rng(seed).uniform(lim.lower_rad, lim.upper_rad, (N_POSES, 6))


def urdf_fk(text: str, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tool-marker pose in the ``base`` link (R (N, 3, 3), p (N, 3) [mm]) of a URDF document, by pinocchio."""
    model = pin.buildModelFromXML(text)
    data = model.createData()
    frame = model.getFrameId("tool_marker", pin.FrameType.BODY)
    base = model.getFrameId("base", pin.FrameType.BODY)
    R, p = np.empty((len(q), 3, 3)), np.empty((len(q), 3))
    for k, qk in enumerate(q):
        pin.framesForwardKinematics(model, data, qk)
        T = data.oMf[base].actInv(data.oMf[frame])
        R[k], p[k] = T.rotation, T.translation * 1e3
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
    write_urdf(path, model.urdf_geometry(), limits_of(robot), robot, layout=layout_of(robot))
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
    KINDS.pop("opaque_test_kind")


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


@pytest.mark.parametrize("robot", ["R1", "R2"])
def test_urdf_has_the_ros_industrial_names_floor_height_and_efforts(robot):
    spec = load_cell().robot(robot).robot
    text = urdf_text(ConstantModel(robot, "nominal", spec.model()).urdf_geometry(), limits_of(robot), robot,
                     layout=layout_of(robot))
    pm = pin.buildModelFromXML(text)
    assert list(pm.names)[1:] == list(ROS_JOINTS)
    for link in ("base_link", *ROS_LINKS, "base", "tool0", "flange", "tool_marker"):
        assert pm.existFrame(link), link
    data = pm.createData()
    pin.framesForwardKinematics(pm, data, np.zeros(6))
    base = data.oMf[pm.getFrameId("base")]
    np.testing.assert_allclose(base.translation, [0, 0, spec.base_height_mm * 1e-3], atol=1e-15)
    np.testing.assert_allclose(base.rotation, np.eye(3), atol=0)
    # tool0 has link_6_t's orientation (the robot frame's at q = 0) and lies p6T along it (ROS-I: 0.100 m along x)
    tool0 = base.actInv(data.oMf[pm.getFrameId("tool0")])
    np.testing.assert_allclose(tool0.rotation, np.eye(3), atol=0)
    np.testing.assert_allclose(tool0.translation * 1e3, spec.P[:, :7].sum(axis=1), atol=1e-12)
    efforts = [float(j.find("limit").get("effort")) for j in ET.fromstring(text.split("\n", 1)[1]).iter("joint")
               if j.get("type") == "revolute"]
    if spec.max_torque_Nm is None:
        assert efforts == [0.0] * 6 and "effort: 0, the robot YAML gives no torque limits" in text
    else:
        assert efforts == spec.max_torque_Nm.tolist()
    np.testing.assert_allclose(pm.velocityLimit, spec.max_speed_rad_s, rtol=0, atol=0)


def test_ma2010_yaml_holds_the_ros_industrial_facts():
    """The MA2010's floor height and efforts as ros-industrial/motoman's ma2010_macro.xacro gives them."""
    spec = load_cell().robot("R1").robot
    assert spec.name == "MA2010" and spec.base_height_mm == 505.0
    assert spec.max_torque_Nm.tolist() == [3087, 2744, 874.65, 78.4, 59.58, 29.6]
    np.testing.assert_allclose(spec.max_speed_rad_s, [3.4383, 3.3161, 3.6652, 7.1558, 7.1558, 10.6465], atol=1e-4)


def test_meshes_by_package_uri_for_every_link():
    uri = "package://motoman_ma2010_support/meshes/ma2010"
    text = urdf_text(ConstantModel("R1", "nominal", load_cell().robot("R1").model()).urdf_geometry(), limits_of("R1"),
                     "R1", layout=UrdfLayout(505.0, uri))
    root = ET.fromstring(text.split("\n", 1)[1])
    meshes = {(link.get("name"), kind.tag): kind.find("geometry/mesh").get("filename")
              for link in root.iter("link") for kind in link if kind.tag in ("visual", "collision")}
    assert meshes == {(name, kind): f"{uri}/{kind}/{name}.stl"
                      for name in ("base_link", *ROS_LINKS) for kind in ("visual", "collision")}
    pin.buildModelFromXML(text)  # still a URDF pinocchio reads


@pytest.mark.parametrize("bad", ["", "meshes/ma2010", "package://x/meshes/ma2010/", "package://x y/meshes"])
def test_a_mesh_folder_that_is_not_a_uri_is_refused(bad):
    with pytest.raises(ModelError, match="is not a URI"):
        urdf_text(ConstantModel("R1", "nominal", load_cell().robot("R1").model()).urdf_geometry(), limits_of("R1"),
                  "R1", layout=UrdfLayout(505.0, bad))


def test_xacro_macro_expands_to_the_same_description_with_a_prefix():
    """The xacro is the URDF as a macro: substituting the prefix (what xacro does) gives the URDF's elements with
    every link and joint name prefixed; pinocchio's FK of the expansion equals the URDF's."""
    geometry = planted("R1").urdf_geometry()
    text = xacro_text(geometry, limits_of("R1"), "cellcal_ma2010", "m.yaml", layout_of("R1"))
    root = ET.fromstring(text.split("\n", 1)[1])
    macro = root.find("{http://ros.org/wiki/xacro}macro")
    assert macro.get("name") == "cellcal_ma2010" and macro.get("params") == "prefix"
    expanded = ET.Element("robot", name="R1")
    for child in macro:
        expanded.append(child)
    doc = '<?xml version="1.0"?>\n' + ET.tostring(expanded, encoding="unicode").replace("${prefix}", "r1_")
    pm = pin.buildModelFromXML(doc)
    assert list(pm.names)[1:] == ["r1_" + j for j in ROS_JOINTS]
    urdf = urdf_text(geometry, limits_of("R1"), "R1", layout=layout_of("R1"))
    q = random_q("R1", seed=4)[:50]
    dp, dR = differences(*urdf_fk(doc.replace("r1_", ""), q), *urdf_fk(urdf, q))
    assert dp == 0.0 and dR == 0.0
