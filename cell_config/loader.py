"""Typed loader for the cell described as YAML: robots, tools, the cell layout, its devices and network.

Every malformed file raises :class:`~calibration.errors.ConfigError` naming the file, the dotted key and what
was expected; nothing is returned half-built. The optional device blocks of ``cell.yaml`` (``controller``,
``mocap``, ``probe``), the ``zenoh`` block and its per-role overrides are parsed by
:mod:`cell_config.devices`, the registration file by :mod:`cell_config.registration`; their types are
re-exported here.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calibration.arm import Arm
from calibration.errors import ConfigError, ModelError
from calibration.kinematics import so3
from calibration.kinematics.poe import PoeModel
from cell_config._yaml import Node
from cell_config.devices import (
    ZENOH_MODES,
    ZENOH_ROLES,
    ControllerConfig,
    MocapConfig,
    ProbeConfig,
    ZenohConfig,
    ZenohRole,
    parse_controller,
    parse_mocap,
    parse_probe,
    parse_zenoh,
)
from cell_config.registration import RobotRegistration, load_registration, registrations_for, save_registration

__all__ = [
    "CAPSULE_SEGMENTS", "DEFAULT_CELL", "REHEARSAL_CELL", "ZENOH_MODES", "ZENOH_ROLES", "CellRobot", "CellSpec",
    "ControllerConfig", "LinkInertia", "MocapConfig", "ProbeConfig", "RobotRegistration", "RobotSpec", "TOOL_SHAPES",
    "ToolShape", "ToolSpec",
    "ZenohConfig", "ZenohRole", "load_cell", "load_registration", "load_robot", "load_tool", "save_registration",
]

PACKAGE_DIR = Path(__file__).resolve().parent
DEFAULT_CELL = PACKAGE_DIR / "cell.yaml"
REHEARSAL_CELL = PACKAGE_DIR / "rehearsal.yaml"

#: The collision capsules of an arm (``capsules_mm`` in the robot YAML); cell_config/capsules.py says what each spans.
CAPSULE_SEGMENTS: tuple[str, ...] = ("base", "shoulder", "upper_arm", "forearm", "wrist", "tool")


@dataclass(frozen=True)
class LinkInertia:
    """Approximate lumped inertial data of one moving link."""

    mass_kg: float
    com_mm: np.ndarray  # centre of mass in the base frame at q = 0, shape (3,)


@dataclass(frozen=True)
class RobotSpec:
    """Nominal description of one arm model (MA2010, MA1440)."""

    name: str
    H: np.ndarray  # (3, 6)
    P: np.ndarray  # (3, 7) [mm]
    R_flange: np.ndarray  # (3, 3)
    lower_rad: np.ndarray  # (6,)
    upper_rad: np.ndarray  # (6,)
    max_speed_rad_s: np.ndarray  # (6,)
    pulses_per_rad: np.ndarray  # (6,)
    links: tuple[LinkInertia, ...] = ()
    payload_kg: float | None = None
    capsules_mm: Mapping[str, float] = field(default_factory=dict)  # collision capsule radius per segment [mm]
    pulse_sign: np.ndarray = field(default_factory=lambda: np.ones(6))  # (6,) +1 or -1
    pulse_zero: np.ndarray = field(default_factory=lambda: np.zeros(6))  # (6,) [pulses] at q = 0
    base_height_mm: float = 0.0  # floor (the ROS-I base_link) to this robot frame [mm]
    max_torque_Nm: np.ndarray | None = None  # (6,) joint torque limits [N m] (the URDF's effort), None: not known

    def to_pulses(self, q: np.ndarray) -> np.ndarray:
        """Controller encoder pulses of joint angles, the robot YAML's pulse convention (the one definition).

        Args:
            q: joint angles [rad], shape (..., 6).

        Returns:
            ``pulse_zero + pulse_sign * q * pulses_per_rad`` rounded to the nearest pulse, int64, shape (..., 6).
        """
        q = np.asarray(q, dtype=float)
        pulses: np.ndarray = np.rint(self.pulse_zero + self.pulse_sign * q * self.pulses_per_rad).astype(np.int64)
        return pulses

    def from_pulses(self, pulses: np.ndarray) -> np.ndarray:
        """Joint angles [rad] of controller pulses, shape (..., 6): the inverse of :meth:`to_pulses`."""
        pulses = np.asarray(pulses, dtype=float)
        q: np.ndarray = (pulses - self.pulse_zero) * self.pulse_sign / self.pulses_per_rad
        return q

    def model(self, tool: ToolSpec | None = None) -> PoeModel:
        """The nominal POE model of this arm carrying ``tool`` (flange frame when None)."""
        if tool is None:
            return PoeModel(self.H, self.P, self.R_flange)
        return PoeModel(self.H, self.P, self.R_flange, tool.R_flange_tool, tool.p_flange_tool)


#: Drawing primitives a tool YAML's ``geometry`` list may hold.
TOOL_SHAPES: tuple[str, ...] = ("cylinder", "box")


@dataclass(frozen=True)
class ToolShape:
    """One drawing primitive of what an arm carries (gun, workpiece), in the flange frame [mm].

    Only the preview draws these; the safety checks and the planner use the robot YAML's ``capsules_mm``.

    Attributes:
        name: what the primitive is (``nozzle``, ``plate``).
        kind: ``cylinder`` (axis ``from_mm`` -> ``to_mm``, radius at each end) or ``box`` (``centre_mm``, edge
            lengths ``size_mm`` along the flange axes).
        from_mm, to_mm: cylinder axis end points, shape (3,); None for a box.
        radius_mm: cylinder radius at ``from_mm`` and at ``to_mm`` (a cone when they differ); None for a box.
        centre_mm, size_mm: box centre and edge lengths, shape (3,); None for a cylinder.
    """

    name: str
    kind: str
    from_mm: np.ndarray | None = None
    to_mm: np.ndarray | None = None
    radius_mm: tuple[float, float] | None = None
    centre_mm: np.ndarray | None = None
    size_mm: np.ndarray | None = None

    def cylinder(self) -> tuple[np.ndarray, np.ndarray, tuple[float, float]]:
        """``(from_mm, to_mm, radius_mm)`` of a cylinder; ModelError for a box."""
        if self.from_mm is None or self.to_mm is None or self.radius_mm is None:
            raise ModelError(f"tool shape {self.name!r} is a {self.kind}, not a cylinder")
        return self.from_mm, self.to_mm, self.radius_mm

    def box(self) -> tuple[np.ndarray, np.ndarray]:
        """``(centre_mm, size_mm)`` of a box; ModelError for a cylinder."""
        if self.centre_mm is None or self.size_mm is None:
            raise ModelError(f"tool shape {self.name!r} is a {self.kind}, not a box")
        return self.centre_mm, self.size_mm


@dataclass(frozen=True)
class ToolSpec:
    """A tool (marker rigid body) expressed in the flange frame, and the drawing geometry of what it is fixed to."""

    name: str
    rigid_body: str
    R_flange_tool: np.ndarray  # (3, 3)
    p_flange_tool: np.ndarray  # (3,) [mm]
    shapes: tuple[ToolShape, ...] = ()  # the tool YAML's ``geometry`` (flange frame), for the preview


@dataclass(frozen=True)
class CellRobot:
    """One arm placed in the cell."""

    name: str  # R1, R2
    robot: RobotSpec
    tool: ToolSpec
    T_cell_base: np.ndarray  # (4, 4) [mm]

    def model(self) -> PoeModel:
        return self.robot.model(self.tool)

    def arm(self) -> Arm:
        """This arm as calibration takes it (:class:`calibration.arm.Arm`): its name in the cell, the nominal model
        carrying its tool, the robot YAML's joint limits and link masses (None when the YAML has no ``links``)."""
        links = self.robot.links
        return Arm(self.name, self.robot.name, self.model(), (self.robot.lower_rad, self.robot.upper_rad),
                   np.array([link.mass_kg for link in links], dtype=float) if links else None,
                   np.array([link.com_mm for link in links], dtype=float) if links else None)


@dataclass(frozen=True)
class CellSpec:
    """The whole cell: named arms, its devices, the network layout and the registration.

    Attributes:
        name: cell name.
        path: the cell file.
        robots: robot name -> arm placed in the cell.
        zenoh: the default Zenoh session settings (the ``zenoh`` block's own keys).
        controller: the MotoROS controller, None on a simulated-only cell.
        mocap: the Motive server, None on a simulated-only cell.
        probe: the CAN probe, None on a simulated-only cell.
        zenoh_roles: per-role Zenoh overrides (bridge, collector, router); see :meth:`zenoh_for`.
        registration_path: the registration file (absolute), None when the cell names none.
        registration: robot name -> registration; empty when the file does not exist yet.
    """

    name: str
    path: Path
    robots: dict[str, CellRobot]
    zenoh: ZenohConfig = field(default_factory=ZenohConfig)
    controller: ControllerConfig | None = None
    mocap: MocapConfig | None = None
    probe: ProbeConfig | None = None
    zenoh_roles: Mapping[str, ZenohConfig] = field(default_factory=dict)
    registration_path: Path | None = None
    registration: Mapping[str, RobotRegistration] = field(default_factory=dict)

    def robot(self, name: str) -> CellRobot:
        if name not in self.robots:
            raise ConfigError(self.path, "robots", f"unknown robot {name!r}; valid: {', '.join(self.robots)}")
        return self.robots[name]

    def zenoh_for(self, role: ZenohRole) -> ZenohConfig:
        """The Zenoh settings of ``role``: its override under ``zenoh.roles`` if given, else the default block."""
        if role not in ZENOH_ROLES:
            raise ConfigError(self.path, "zenoh.roles", f"unknown role {role!r}; valid: {', '.join(ZENOH_ROLES)}")
        return self.zenoh_roles.get(role, self.zenoh)


#: The keys of a robot YAML (``repeatability_mm``: the datasheet's figure, kept for the record, read by no command),
#: and of its ``joint_limits_deg``. A misspelt key (``pulse_zeros``) is refused, not ignored.
ROBOT_KEYS = ("name", "H", "P", "R_flange", "joint_limits_deg", "max_speed_deg_s", "base_height_mm", "max_torque_Nm",
              "pulses_per_deg", "pulse_sign", "pulse_zero", "payload_kg", "repeatability_mm", "links", "capsules_mm")
JOINT_LIMIT_KEYS = ("lower", "upper")
#: The keys of a tool YAML.
TOOL_KEYS = ("name", "rigid_body", "position_mm", "quaternion_wxyz", "geometry")


def load_robot(path: str | Path) -> RobotSpec:
    """Load a robot YAML (``robots/MA2010.yaml``).

    Raises:
        ConfigError: an unknown key (naming the valid ones) or a bad value.
    """
    r = Node.load(path)
    r.only(ROBOT_KEYS)
    H = r.array("H", (6, 3)).T
    norms = np.linalg.norm(H, axis=0)
    if np.any(np.abs(norms - 1.0) > 1e-9):
        raise r.error("H", f"expected unit axes, norms are {norms.tolist()}")
    R_flange = r.array("R_flange", (3, 3))
    if not np.allclose(R_flange @ R_flange.T, np.eye(3), atol=1e-6) or np.linalg.det(R_flange) < 0:
        raise r.error("R_flange", "expected a rotation matrix")
    if not isinstance(r.get("joint_limits_deg"), dict):
        raise r.error("joint_limits_deg", "expected a mapping with 'lower' and 'upper'")
    limits = r.child("joint_limits_deg")
    limits.only(JOINT_LIMIT_KEYS)
    lower = limits.array("lower", (6,))
    upper = limits.array("upper", (6,))
    if np.any(lower >= upper):
        raise r.error("joint_limits_deg", "expected lower < upper for every joint")
    speeds = r.array("max_speed_deg_s", (6,))
    pulses = r.array("pulses_per_deg", (6,))
    if np.any(speeds <= 0) or np.any(pulses <= 0):
        raise r.error("max_speed_deg_s/pulses_per_deg", "expected positive values")
    links = []
    raw_links = r.get("links", [])
    if not isinstance(raw_links, list) or (raw_links and len(raw_links) != 6):
        raise r.error("links", "expected a list of 6 {mass_kg, com_mm} entries")
    for i, link in enumerate(raw_links):
        if not isinstance(link, dict):
            raise r.error(f"links[{i}]", "expected a mapping with mass_kg and com_mm")
        entry = Node(r.path, link, f"links[{i}]")
        links.append(LinkInertia(float(entry.array("mass_kg", ())), entry.array("com_mm", (3,))))
    pulse_sign = r.array("pulse_sign", (6,))
    if not np.all(np.isin(pulse_sign, (-1.0, 1.0))):
        raise r.error("pulse_sign", f"expected +1 or -1 per joint, got {pulse_sign.tolist()}")
    pulse_zero = r.array("pulse_zero", (6,))
    if np.any(pulse_zero != np.rint(pulse_zero)):
        raise r.error("pulse_zero", f"expected whole pulses, got {pulse_zero.tolist()}")
    payload = None if r.get("payload_kg", None) is None else r.number("payload_kg", lo=0.0)
    base_height = 0.0 if r.get("base_height_mm", None) is None else r.number("base_height_mm", lo=0.0)
    torque = None if r.get("max_torque_Nm", None) is None else r.array("max_torque_Nm", (6,))
    if torque is not None and not np.all(torque > 0):
        raise r.error("max_torque_Nm", f"expected positive torques [N m], got {torque.tolist()}")
    caps = r.child("capsules_mm")
    caps.only(CAPSULE_SEGMENTS)
    capsules = {s: caps.number(s, lo=0.0, lo_open=True) for s in CAPSULE_SEGMENTS}
    return RobotSpec(
        name=r.string("name"), H=H, P=r.array("P", (7, 3)).T, R_flange=R_flange,
        lower_rad=np.radians(lower), upper_rad=np.radians(upper), max_speed_rad_s=np.radians(speeds),
        pulses_per_rad=pulses * 180.0 / np.pi, links=tuple(links),
        payload_kg=payload, capsules_mm=capsules,
        pulse_sign=pulse_sign, pulse_zero=pulse_zero, base_height_mm=base_height, max_torque_Nm=torque,
    )


def load_tool(path: str | Path) -> ToolSpec:
    """Load a tool YAML (``tools/weldgun_marker.yaml``).

    Raises:
        ConfigError: an unknown key (naming the valid ones) or a bad value.
    """
    r = Node.load(path)
    r.only(TOOL_KEYS)
    quat = r.array("quaternion_wxyz", (4,))
    if abs(np.linalg.norm(quat) - 1.0) > 1e-3:
        raise r.error("quaternion_wxyz", f"expected a unit quaternion, norm is {np.linalg.norm(quat):.6f}")
    return ToolSpec(r.string("name"), r.string("rigid_body"), so3.quat_to_R(quat), r.array("position_mm", (3,)),
                    _tool_shapes(r))


def _tool_shapes(r: Node) -> tuple[ToolShape, ...]:
    """The optional ``geometry`` list of a tool YAML: drawing primitives in the flange frame [mm]."""
    raw = r.get("geometry", [])
    if not isinstance(raw, list):
        raise r.error("geometry", f"expected a list of shapes ({', '.join(TOOL_SHAPES)})")
    shapes = []
    for i, item in enumerate(raw):
        if not isinstance(item, dict):
            raise r.error(f"geometry[{i}]", "expected a mapping with name and shape")
        e = Node(r.path, item, f"geometry[{i}]")
        kind = e.string("shape")
        if kind == "cylinder":
            e.only(("name", "shape", "from_mm", "to_mm", "radius_mm"))
            a, b = e.array("from_mm", (3,)), e.array("to_mm", (3,))
            if isinstance(e.get("radius_mm"), list):  # [at from_mm, at to_mm]: a cone
                radii = e.array("radius_mm", (2,))
                if np.any(radii <= 0):
                    raise e.error("radius_mm", f"expected radii > 0, got {radii.tolist()}")
            else:
                radii = np.full(2, e.number("radius_mm", lo=0.0, lo_open=True))
            if np.linalg.norm(b - a) == 0:
                raise e.error("to_mm", "expected an axis of non-zero length (to_mm != from_mm)")
            shapes.append(ToolShape(e.string("name"), kind, a, b, (float(radii[0]), float(radii[1]))))
        elif kind == "box":
            e.only(("name", "shape", "centre_mm", "size_mm"))
            size = e.array("size_mm", (3,))
            if np.any(size <= 0):
                raise e.error("size_mm", f"expected positive edge lengths, got {size.tolist()}")
            shapes.append(ToolShape(e.string("name"), kind, centre_mm=e.array("centre_mm", (3,)), size_mm=size))
        else:
            raise e.error("shape", f"unknown shape {kind!r}; valid: {', '.join(TOOL_SHAPES)}")
    return tuple(shapes)


#: The keys of a cell file's top level, and of each entry under ``robots``.
CELL_KEYS = ("name", "robots", "zenoh", "controller", "mocap", "probe", "registration")
ROBOT_ENTRY_KEYS = ("robot", "tool", "T_cell_base")


def load_cell(path: str | Path = DEFAULT_CELL) -> CellSpec:
    """Load ``cell.yaml``; robot, tool and registration paths inside it are relative to the cell file.

    Raises:
        ConfigError: an unknown key at any level (a misspelt ``registraton`` or ``controler`` would otherwise
            leave the cell without its registration or controller), naming the valid keys; a bad value.
    """
    r = Node.load(path)
    r.only(CELL_KEYS)
    robots = _robots(r)
    zenoh, roles = parse_zenoh(r.child("zenoh", None))
    registration_path = None
    registration: dict[str, RobotRegistration] = {}
    if "registration" in r:
        registration_path = (r.path.parent / r.string("registration")).absolute()
        registration = registrations_for(registration_path, robots)
    return CellSpec(
        name=r.string("name"), path=r.path, robots=robots, zenoh=zenoh,
        controller=parse_controller(r.child("controller", None), robots),
        mocap=parse_mocap(r.child("mocap", None), robots),
        probe=parse_probe(r.child("probe", None)),
        zenoh_roles=roles, registration_path=registration_path, registration=registration,
    )


def _robots(r: Node) -> dict[str, CellRobot]:
    robots_node = r.get("robots")
    if not isinstance(robots_node, dict) or not robots_node:
        raise r.error("robots", "expected a mapping of robot names (R1, R2) to entries")
    robots = {}
    for name in robots_node:
        if not isinstance(robots_node[name], dict):
            raise r.error(f"robots.{name}", "expected a mapping with robot, tool, T_cell_base")
        entry = Node(r.path, robots_node[name], f"robots.{name}")
        entry.only(ROBOT_ENTRY_KEYS)
        T = entry.array("T_cell_base", (4, 4))
        Rb = T[:3, :3]
        if not np.allclose(Rb @ Rb.T, np.eye(3), atol=1e-5) or not np.allclose(T[3], [0, 0, 0, 1]):
            raise entry.error("T_cell_base", "expected a homogeneous rigid transform")
        robot = load_robot(r.path.parent / entry.string("robot"))
        tool = load_tool(r.path.parent / entry.string("tool"))
        robots[str(name)] = CellRobot(str(name), robot, tool, T)
    return robots
