"""URDF export of a model's constant geometry: a chain of revolute joints, the flange and the tool marker.

POE to URDF. At q = 0 every POE frame is aligned with the base, so each URDF joint frame is put at the joint's
point on its axis with identity rotation relative to the previous one: joint i's origin is ``p_(i-1)i`` [m] in
joint (i-1)'s child link frame (``p01`` in ``base_link``), its axis is ``h_i`` in that frame. Joint i turns its
child link by ``rot(h_i, q_i)``, which is the POE product ``R = R @ rot(h_i, q_i); p += R @ p_i(i+1)`` term by
term. The last link vector ``p6T`` and ``R_flange`` make the fixed ``flange_joint``; the tool (marker) frame
``R_flange_tool, p_flange_tool`` makes the fixed ``tool_marker_joint``. A constant base or tool-marker
correction (the ``rebased`` kind) is folded into the first joint's and the tool joint's origins.

URDF lengths are metres; cellcal's are millimetres. Numbers are written with their shortest exact repr, so
the URDF reproduces the model's kinematics to rounding (see tests/calibration/test_urdf.py for the figures).
Which part of a model is exported, and what is lost, is the model kind's :meth:`urdf_geometry`.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calibration.errors import ModelError
from calibration.files import atomic_write_text
from calibration.poe import PoeModel

MM_TO_M = 1e-3


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
    """

    lower_rad: np.ndarray
    upper_rad: np.ndarray
    velocity_rad_s: np.ndarray


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


def _link(robot: ET.Element, name: str) -> None:
    ET.SubElement(robot, "link", name=name)


def _fixed(robot: ET.Element, name: str, parent: str, child: str, T_mm: np.ndarray) -> None:
    j = ET.SubElement(robot, "joint", name=name, type="fixed")
    _origin(j, T_mm)
    ET.SubElement(j, "parent", link=parent)
    ET.SubElement(j, "child", link=child)


def urdf_text(geometry: UrdfGeometry, limits: JointLimits, name: str, source: str = "") -> str:
    """The URDF document of ``geometry`` with ``limits``.

    Links: ``base_link``, ``link_1`` .. ``link_n``, ``flange``, ``tool_marker``; revolute joints ``joint_1`` ..
    ``joint_n``; fixed joints ``flange_joint`` (link_n -> flange) and ``tool_marker_joint`` (flange -> tool_marker).

    Args:
        geometry: what to export (see :class:`UrdfGeometry`).
        limits: joint limits from the robot YAML.
        name: the robot name in the URDF (``R1``).
        source: the model file, for the comment.
    """
    arm = geometry.arm
    n = arm.n_joints
    for key in ("lower_rad", "upper_rad", "velocity_rad_s"):
        if np.shape(getattr(limits, key)) != (n,):
            raise ModelError(f"joint limits {key} must have {n} entries, got shape {np.shape(getattr(limits, key))}")
    robot = ET.Element("robot", name=name)
    lost = "; ".join(geometry.lost) if geometry.lost else "nothing (the model is one constant geometry)"
    robot.append(ET.Comment(f" written by cellcal export-urdf from {source or 'a model'}: {geometry.exported}. "
                            f"Lost: {lost}. Lengths in metres. "))
    _link(robot, "base_link")
    parent = "base_link"
    for i in range(n):
        T = _T(np.eye(3), arm.P[:, i])
        if i == 0:
            T = geometry.T_base @ T
        child = f"link_{i + 1}"
        _link(robot, child)
        j = ET.SubElement(robot, "joint", name=f"joint_{i + 1}", type="revolute")
        _origin(j, T)
        ET.SubElement(j, "parent", link=parent)
        ET.SubElement(j, "child", link=child)
        ET.SubElement(j, "axis", xyz=_num(arm.H[:, i]))
        ET.SubElement(j, "limit", lower=repr(float(limits.lower_rad[i])), upper=repr(float(limits.upper_rad[i])),
                      effort="0", velocity=repr(float(limits.velocity_rad_s[i])))
        parent = child
    _link(robot, "flange")
    _fixed(robot, "flange_joint", parent, "flange", _T(arm.R_flange, arm.P[:, n]))
    _link(robot, "tool_marker")
    _fixed(robot, "tool_marker_joint", "flange", "tool_marker",
           _T(arm.R_flange_tool, arm.p_flange_tool) @ geometry.T_tool)
    ET.indent(robot)
    return '<?xml version="1.0"?>\n' + ET.tostring(robot, encoding="unicode") + "\n"


def write_urdf(path: str | Path, geometry: UrdfGeometry, limits: JointLimits, name: str, source: str = "") -> None:
    """Write :func:`urdf_text` to ``path`` atomically (nothing is written when it fails)."""
    atomic_write_text(path, urdf_text(geometry, limits, name, source))
