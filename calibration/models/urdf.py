"""URDF export of a model's constant geometry with the ROS-Industrial Motoman names, and its xacro macro.

Names and frames are those of ros-industrial/motoman's descriptions (motoman_ma2010_support/urdf/ma2010_macro.xacro):
``base_link`` on the floor, revolute joints ``joint_1_s`` .. ``joint_6_t`` moving ``link_1_s`` .. ``link_6_t``, the
fixed ``base`` link (the manufacturer's robot frame, cellcal's base frame) ``base_height_mm`` above ``base_link``,
and ``tool0`` at the flange with ``link_6_t``'s orientation. Two cellcal frames follow as extra fixed links:
``flange`` (the Yaskawa flange frame, ``R_flange`` from ``tool0``) and ``tool_marker`` (the tool/marker frame).

POE to URDF. At q = 0 every POE frame is aligned with the base, so each URDF joint frame is put at the joint's
point on its axis with identity rotation relative to the previous one: joint i's origin is ``p_(i-1)i`` [m] in
joint (i-1)'s child link frame (``p01`` from ``base``, i.e. ``base_height + p01`` from ``base_link``), its axis is
``h_i`` in that frame. Joint i turns its child link by ``rot(h_i, q_i)``, which is the POE product
``R = R @ rot(h_i, q_i); p += R @ p_i(i+1)`` term by term. The last link vector ``p6T`` makes ``tool0``;
``R_flange`` makes ``flange``; ``R_flange_tool, p_flange_tool`` make ``tool_marker``. A constant base or
tool-marker correction (the ``rebased`` kind) is folded into the first joint's and the tool joint's origins.
Poses relative to ``base`` are cellcal's forward kinematics (tests/calibration/models/test_urdf.py checks it).

URDF lengths are metres; cellcal's are millimetres. Numbers are written with their shortest exact repr, so
the URDF reproduces the model's kinematics to rounding (see tests/calibration/models/test_urdf.py for the figures).
Which part of a model is exported, and what is lost, is the model kind's :meth:`urdf_geometry`.

The xacro (:func:`xacro_text`) is the same description as a macro with a ``prefix`` parameter, the shape of
motoman_support's ``motoman_ma2010`` macro: a ROS-I user includes it in place of that macro (same link and joint
names) and gets the calibrated joint origins.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calibration.data.files import atomic_write_text
from calibration.errors import ModelError
from calibration.kinematics.poe import PoeModel

MM_TO_M = 1e-3
#: ROS-Industrial Motoman names (motoman_support): the moving links and the revolute joints of a 6-axis arm.
ROS_LINKS: tuple[str, ...] = ("link_1_s", "link_2_l", "link_3_u", "link_4_r", "link_5_b", "link_6_t")
ROS_JOINTS: tuple[str, ...] = ("joint_1_s", "joint_2_l", "joint_3_u", "joint_4_r", "joint_5_b", "joint_6_t")
#: The frames every exported URDF holds besides the chain: floor, robot frame, ROS-I tool frame, cellcal's two.
BASE_LINK, ROBOT_FRAME_LINK, TOOL0_LINK, FLANGE_LINK, TOOL_LINK = "base_link", "base", "tool0", "flange", "tool_marker"


@dataclass(frozen=True)
class UrdfGeometry:
    """What of a model goes into a URDF.

    Attributes:
        arm: the constant POE geometry with the tool marker [mm].
        exported: which part of the model ``arm`` is (for the URDF comment and the CLI).
        lost: what the URDF cannot hold (empty for a purely constant model).
        T_base: constant correction in front of the chain (4, 4) [mm] (the ``rebased`` kind's base correction).
        T_tool: constant correction after the tool marker (4, 4) [mm] (the ``rebased`` kind's tool correction).
    """

    arm: PoeModel
    exported: str
    lost: tuple[str, ...] = ()
    T_base: np.ndarray = field(default_factory=lambda: np.eye(4))
    T_tool: np.ndarray = field(default_factory=lambda: np.eye(4))


@dataclass(frozen=True)
class JointLimits:
    """Joint limits written into the URDF (from the robot YAML).

    Attributes:
        lower_rad, upper_rad: position limits [rad], shape (n,).
        velocity_rad_s: speed limits [rad/s], shape (n,).
        effort_Nm: torque limits [N m], shape (n,); None: not known (the URDF's effort is then 0, as URDF requires
            the attribute, and the comment says so).
    """

    lower_rad: np.ndarray
    upper_rad: np.ndarray
    velocity_rad_s: np.ndarray
    effort_Nm: np.ndarray | None = None


@dataclass(frozen=True)
class UrdfLayout:
    """Where the robot stands and how its links look (from the robot YAML and the command line).

    Attributes:
        base_height_mm: floor (``base_link``) to the robot frame (``base``) [mm].
        meshes: package URI of the mesh folder (``package://motoman_ma2010_support/meshes/ma2010``): each link
            gets ``<meshes>/visual/<link>.stl`` and ``<meshes>/collision/<link>.stl``; None: no geometry.
    """

    base_height_mm: float = 0.0
    meshes: str | None = None


def rpy_from_R(R: np.ndarray) -> tuple[float, float, float]:
    """URDF roll-pitch-yaw (fixed X, then Y, then Z: ``R = Rz(y) Ry(p) Rx(r)``) of a rotation.

    At pitch = +-90 deg (the Motoman flange) roll is set to 0 and the yaw takes the whole rotation about z.

    Raises:
        ModelError: the angles do not reproduce R to 1e-12 (R is not a rotation).
    """
    R = np.asarray(R, dtype=float)
    pitch = math.atan2(-R[2, 0], math.hypot(R[0, 0], R[1, 0]))
    if math.hypot(R[0, 0], R[1, 0]) > 1e-9:
        roll = math.atan2(R[2, 1], R[2, 2])
        yaw = math.atan2(R[1, 0], R[0, 0])
    else:  # gimbal lock: only yaw - roll (pitch = -90) or yaw + roll (pitch = +90) is defined
        roll = 0.0
        yaw = math.atan2(-R[0, 1], R[1, 1])
    err = np.abs(R_from_rpy(roll, pitch, yaw) - R).max()
    if not err <= 1e-12:
        raise ModelError(f"rotation {R.tolist()} has no exact roll-pitch-yaw (error {err:.1e}); not a rotation")
    return roll, pitch, yaw


def R_from_rpy(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """The rotation ``Rz(yaw) Ry(pitch) Rx(roll)`` (URDF convention)."""
    cr, sr, cp, sp, cy, sy = (math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch),
                              math.cos(yaw), math.sin(yaw))
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def _T(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, p
    return T


def _num(values: np.ndarray | tuple[float, ...]) -> str:
    return " ".join(repr(float(v) + 0.0) for v in values)  # + 0.0: no "-0.0"


def _origin(parent: ET.Element, T_mm: np.ndarray) -> None:
    ET.SubElement(parent, "origin", xyz=_num(T_mm[:3, 3] * MM_TO_M), rpy=_num(rpy_from_R(T_mm[:3, :3])))


def _link(robot: ET.Element, name: str, meshes: str | None = None, prefix: str = "") -> None:
    link = ET.SubElement(robot, "link", name=prefix + name)
    if meshes is None:
        return
    for kind in ("visual", "collision"):
        geometry = ET.SubElement(ET.SubElement(link, kind), "geometry")
        ET.SubElement(geometry, "mesh", filename=f"{meshes}/{kind}/{name}.stl")


def _check_meshes(meshes: str | None) -> None:
    if meshes is None:
        return
    if not meshes or any(c.isspace() for c in meshes) or "://" not in meshes or meshes.endswith("/"):
        raise ModelError(f"mesh folder {meshes!r} is not a URI; expected e.g. "
                         "package://motoman_ma2010_support/meshes/ma2010 (no trailing slash)")


def _fixed(robot: ET.Element, name: str, parent: str, child: str, T_mm: np.ndarray, prefix: str = "") -> None:
    j = ET.SubElement(robot, "joint", name=prefix + name, type="fixed")
    _origin(j, T_mm)
    ET.SubElement(j, "parent", link=prefix + parent)
    ET.SubElement(j, "child", link=prefix + child)


def _robot_element(geometry: UrdfGeometry, limits: JointLimits, source: str, layout: UrdfLayout,
                   root: ET.Element, prefix: str) -> None:
    """Append the links and joints of ``geometry`` to ``root`` (names prefixed with ``prefix``)."""
    arm = geometry.arm
    n = arm.n_joints
    if n != len(ROS_JOINTS):
        raise ModelError(f"a {n}-joint model has no ROS-Industrial Motoman names; exportable: 6-axis arms")
    for key in ("lower_rad", "upper_rad", "velocity_rad_s", "effort_Nm"):
        value = getattr(limits, key)
        if value is not None and np.shape(value) != (n,):
            raise ModelError(f"joint limits {key} must have {n} entries, got shape {np.shape(value)}")
    _check_meshes(layout.meshes)
    lost = "; ".join(geometry.lost) if geometry.lost else "nothing (the model is one constant geometry)"
    effort = ("effort: joint torques [N m] from the robot YAML" if limits.effort_Nm is not None
              else "effort: 0, the robot YAML gives no torque limits")
    root.append(ET.Comment(f" written by cellcal export-urdf from {source or 'a model'}: {geometry.exported}. "
                           f"Lost: {lost}. Lengths in metres; {effort}. Frames: {BASE_LINK} on the floor, "
                           f"{ROBOT_FRAME_LINK} = the robot frame of cellcal's model "
                           f"({layout.base_height_mm:g} mm up), {TOOL0_LINK} = ROS-I tool frame, {FLANGE_LINK} = "
                           f"Yaskawa flange frame, {TOOL_LINK} = the calibrated tool/marker frame. "))
    T_floor_base = _T(np.eye(3), np.array([0.0, 0.0, layout.base_height_mm]))
    _link(root, BASE_LINK, layout.meshes, prefix)
    parent = BASE_LINK
    for i in range(n):
        T = _T(np.eye(3), arm.P[:, i])
        if i == 0:
            T = T_floor_base @ geometry.T_base @ T
        child = ROS_LINKS[i]
        _link(root, child, layout.meshes, prefix)
        j = ET.SubElement(root, "joint", name=prefix + ROS_JOINTS[i], type="revolute")
        _origin(j, T)
        ET.SubElement(j, "parent", link=prefix + parent)
        ET.SubElement(j, "child", link=prefix + child)
        ET.SubElement(j, "axis", xyz=_num(arm.H[:, i]))
        torque = 0.0 if limits.effort_Nm is None else float(limits.effort_Nm[i])
        ET.SubElement(j, "limit", lower=repr(float(limits.lower_rad[i])), upper=repr(float(limits.upper_rad[i])),
                      effort=repr(torque), velocity=repr(float(limits.velocity_rad_s[i])))
        parent = child
    _link(root, ROBOT_FRAME_LINK, prefix=prefix)
    _fixed(root, f"{BASE_LINK}-{ROBOT_FRAME_LINK}", BASE_LINK, ROBOT_FRAME_LINK, T_floor_base, prefix)
    _link(root, TOOL0_LINK, prefix=prefix)
    _fixed(root, f"{parent}-{TOOL0_LINK}", parent, TOOL0_LINK, _T(np.eye(3), arm.P[:, n]), prefix)
    _link(root, FLANGE_LINK, prefix=prefix)
    _fixed(root, f"{TOOL0_LINK}-{FLANGE_LINK}", TOOL0_LINK, FLANGE_LINK, _T(arm.R_flange, np.zeros(3)), prefix)
    _link(root, TOOL_LINK, prefix=prefix)
    _fixed(root, f"{FLANGE_LINK}-{TOOL_LINK}", FLANGE_LINK, TOOL_LINK,
           _T(arm.R_flange_tool, arm.p_flange_tool) @ geometry.T_tool, prefix)


def urdf_text(geometry: UrdfGeometry, limits: JointLimits, name: str, source: str = "",
              layout: UrdfLayout = UrdfLayout()) -> str:
    """The URDF document of ``geometry`` with ``limits``, standing as ``layout`` says.

    Links: ``base_link``, ``link_1_s`` .. ``link_6_t``, ``base``, ``tool0``, ``flange``, ``tool_marker``; revolute
    joints ``joint_1_s`` .. ``joint_6_t``; fixed joints ``base_link-base``, ``link_6_t-tool0``, ``tool0-flange``
    and ``flange-tool_marker``.

    Args:
        geometry: what to export (see :class:`UrdfGeometry`).
        limits: joint limits from the robot YAML.
        name: the robot name in the URDF (``R1``).
        source: the model file, for the comment.
        layout: floor height of the robot frame and the mesh folder.

    Raises:
        ModelError: not a 6-axis arm, limits of the wrong size, a mesh folder that is not a URI.
    """
    robot = ET.Element("robot", name=name)
    _robot_element(geometry, limits, source, layout, robot, "")
    ET.indent(robot)
    return '<?xml version="1.0"?>\n' + ET.tostring(robot, encoding="unicode") + "\n"


XACRO_NS = "http://ros.org/wiki/xacro"


def xacro_text(geometry: UrdfGeometry, limits: JointLimits, macro: str, source: str = "",
               layout: UrdfLayout = UrdfLayout()) -> str:
    """The same description as a xacro macro ``macro`` with a ``prefix`` parameter (motoman_support's shape).

    A ROS-Industrial user includes the file and calls ``<xacro:NAME prefix=""/>`` where the robot's support
    package macro was called (``<xacro:motoman_ma2010 prefix=""/>``): the link and joint names are the same,
    the joint origins are the calibrated ones. The ``prefix`` goes in front of every link and joint name.
    """
    robot = ET.Element("robot", {"xmlns:xacro": XACRO_NS})
    body = ET.SubElement(robot, "xacro:macro", name=macro, params="prefix")
    _robot_element(geometry, limits, source, layout, body, "${prefix}")
    ET.indent(robot)
    return '<?xml version="1.0"?>\n' + ET.tostring(robot, encoding="unicode") + "\n"


def write_urdf(path: str | Path, geometry: UrdfGeometry, limits: JointLimits, name: str, source: str = "",
               layout: UrdfLayout = UrdfLayout()) -> None:
    """Write :func:`urdf_text` to ``path`` atomically (nothing is written when it fails)."""
    atomic_write_text(path, urdf_text(geometry, limits, name, source, layout))
