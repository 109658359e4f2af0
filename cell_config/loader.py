"""Typed loader for the cell described as YAML: robots, tools and the cell layout.

Every malformed file raises :class:`~calibration.errors.ConfigError` naming the file, the key and what
was expected; nothing is returned half-built.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from calibration import so3
from calibration.errors import ConfigError
from calibration.poe import PoeModel

PACKAGE_DIR = Path(__file__).resolve().parent
DEFAULT_CELL = PACKAGE_DIR / "cell.yaml"


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

    def model(self, tool: "ToolSpec | None" = None) -> PoeModel:
        """The nominal POE model of this arm carrying ``tool`` (flange frame when None)."""
        if tool is None:
            return PoeModel(self.H, self.P, self.R_flange)
        return PoeModel(self.H, self.P, self.R_flange, tool.R_flange_tool, tool.p_flange_tool)


@dataclass(frozen=True)
class ToolSpec:
    """A tool (marker rigid body) expressed in the flange frame."""

    name: str
    rigid_body: str
    R_flange_tool: np.ndarray  # (3, 3)
    p_flange_tool: np.ndarray  # (3,) [mm]


@dataclass(frozen=True)
class CellRobot:
    """One arm placed in the cell."""

    name: str  # R1, R2
    robot: RobotSpec
    tool: ToolSpec
    T_cell_base: np.ndarray  # (4, 4) [mm]

    def model(self) -> PoeModel:
        return self.robot.model(self.tool)


@dataclass(frozen=True)
class ZenohConfig:
    mode: str = "peer"
    listen: tuple[str, ...] = ()
    connect: tuple[str, ...] = ()
    multicast_scouting: bool = False


@dataclass(frozen=True)
class CellSpec:
    """The whole cell: named arms and the network layout."""

    name: str
    path: Path
    robots: dict[str, CellRobot]
    zenoh: ZenohConfig = field(default_factory=ZenohConfig)

    def robot(self, name: str) -> CellRobot:
        if name not in self.robots:
            raise ConfigError(self.path, "robots", f"unknown robot {name!r}; valid: {', '.join(self.robots)}")
        return self.robots[name]


class _Reader:
    """Typed access to a parsed YAML mapping that reports errors with file and dotted key."""

    def __init__(self, path: Path) -> None:
        self.path = path
        try:
            with open(path, encoding="utf-8") as f:
                self.data = yaml.safe_load(f)
        except FileNotFoundError as e:
            raise ConfigError(path, "", "file not found") from e
        except yaml.YAMLError as e:
            raise ConfigError(path, "", f"not valid YAML ({e.__class__.__name__}: {e})") from e
        if not isinstance(self.data, dict):
            raise ConfigError(path, "", "expected a mapping at the top level")

    def get(self, key: str, default: Any = ..., node: dict | None = None, prefix: str = "") -> Any:
        node = self.data if node is None else node
        if key not in node:
            if default is ...:
                raise ConfigError(self.path, prefix + key, "required key is missing")
            return default
        return node[key]

    def array(self, key: str, shape: tuple[int, ...], node: dict | None = None, prefix: str = "",
              default: Any = ...) -> np.ndarray:
        value = self.get(key, default, node, prefix)
        try:
            arr = np.asarray(value, dtype=float)
        except (TypeError, ValueError) as e:
            raise ConfigError(self.path, prefix + key, f"expected numbers of shape {shape}") from e
        if arr.shape != shape:
            raise ConfigError(self.path, prefix + key, f"expected shape {shape}, got {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise ConfigError(self.path, prefix + key, "expected finite numbers")
        return arr

    def string(self, key: str, node: dict | None = None, prefix: str = "") -> str:
        value = self.get(key, ..., node, prefix)
        if not isinstance(value, str) or not value:
            raise ConfigError(self.path, prefix + key, f"expected a non-empty string, got {value!r}")
        return value


def load_robot(path: str | Path) -> RobotSpec:
    """Load a robot YAML (``robots/MA2010.yaml``)."""
    r = _Reader(Path(path))
    H = r.array("H", (6, 3)).T
    norms = np.linalg.norm(H, axis=0)
    if np.any(np.abs(norms - 1.0) > 1e-9):
        raise ConfigError(r.path, "H", f"expected unit axes, norms are {norms.tolist()}")
    R_flange = r.array("R_flange", (3, 3))
    if not np.allclose(R_flange @ R_flange.T, np.eye(3), atol=1e-6) or np.linalg.det(R_flange) < 0:
        raise ConfigError(r.path, "R_flange", "expected a rotation matrix")
    limits = r.get("joint_limits_deg")
    if not isinstance(limits, dict):
        raise ConfigError(r.path, "joint_limits_deg", "expected a mapping with 'lower' and 'upper'")
    lower = r.array("lower", (6,), limits, "joint_limits_deg.")
    upper = r.array("upper", (6,), limits, "joint_limits_deg.")
    if np.any(lower >= upper):
        raise ConfigError(r.path, "joint_limits_deg", "expected lower < upper for every joint")
    speeds = r.array("max_speed_deg_s", (6,))
    pulses = r.array("pulses_per_deg", (6,))
    if np.any(speeds <= 0) or np.any(pulses <= 0):
        raise ConfigError(r.path, "max_speed_deg_s/pulses_per_deg", "expected positive values")
    links = []
    raw_links = r.get("links", [])
    if not isinstance(raw_links, list) or (raw_links and len(raw_links) != 6):
        raise ConfigError(r.path, "links", "expected a list of 6 {mass_kg, com_mm} entries")
    for i, link in enumerate(raw_links):
        if not isinstance(link, dict):
            raise ConfigError(r.path, f"links[{i}]", "expected a mapping with mass_kg and com_mm")
        mass = r.array("mass_kg", (), link, f"links[{i}].")
        links.append(LinkInertia(float(mass), r.array("com_mm", (3,), link, f"links[{i}].")))
    payload = r.get("payload_kg", None)
    return RobotSpec(
        name=r.string("name"), H=H, P=r.array("P", (7, 3)).T, R_flange=R_flange,
        lower_rad=np.radians(lower), upper_rad=np.radians(upper), max_speed_rad_s=np.radians(speeds),
        pulses_per_rad=pulses * 180.0 / np.pi, links=tuple(links),
        payload_kg=None if payload is None else float(payload),
    )


def load_tool(path: str | Path) -> ToolSpec:
    """Load a tool YAML (``tools/weldgun_marker.yaml``)."""
    r = _Reader(Path(path))
    quat = r.array("quaternion_wxyz", (4,))
    if abs(np.linalg.norm(quat) - 1.0) > 1e-3:
        raise ConfigError(r.path, "quaternion_wxyz", f"expected a unit quaternion, norm is {np.linalg.norm(quat):.6f}")
    return ToolSpec(r.string("name"), r.string("rigid_body"), so3.quat_to_R(quat), r.array("position_mm", (3,)))


def load_cell(path: str | Path = DEFAULT_CELL) -> CellSpec:
    """Load ``cell.yaml``; robot and tool paths inside it are relative to the cell file."""
    r = _Reader(Path(path))
    robots_node = r.get("robots")
    if not isinstance(robots_node, dict) or not robots_node:
        raise ConfigError(r.path, "robots", "expected a mapping of robot names (R1, R2) to entries")
    robots = {}
    for name, entry in robots_node.items():
        prefix = f"robots.{name}."
        if not isinstance(entry, dict):
            raise ConfigError(r.path, f"robots.{name}", "expected a mapping with robot, tool, T_cell_base")
        T = r.array("T_cell_base", (4, 4), entry, prefix)
        Rb = T[:3, :3]
        if not np.allclose(Rb @ Rb.T, np.eye(3), atol=1e-5) or not np.allclose(T[3], [0, 0, 0, 1]):
            raise ConfigError(r.path, prefix + "T_cell_base", "expected a homogeneous rigid transform")
        robot = load_robot(r.path.parent / r.string("robot", entry, prefix))
        tool = load_tool(r.path.parent / r.string("tool", entry, prefix))
        robots[str(name)] = CellRobot(str(name), robot, tool, T)
    z = r.get("zenoh", {})
    if not isinstance(z, dict):
        raise ConfigError(r.path, "zenoh", "expected a mapping")
    mode = z.get("mode", "peer")
    if mode not in ("peer", "client", "router"):
        raise ConfigError(r.path, "zenoh.mode", f"expected one of peer, client, router, got {mode!r}")
    for key in ("listen", "connect"):
        if not isinstance(z.get(key, []), list) or not all(isinstance(e, str) for e in z.get(key, [])):
            raise ConfigError(r.path, f"zenoh.{key}", "expected a list of endpoint strings like tcp/127.0.0.1:7447")
    zenoh = ZenohConfig(mode, tuple(z.get("listen", [])), tuple(z.get("connect", [])),
                        bool(z.get("multicast_scouting", False)))
    return CellSpec(r.string("name"), r.path, robots, zenoh)
