"""The cell described as data (robots, tools, layout, devices, network, registration) and its typed loader."""

from cell_config.devices import ZENOH_ROLES, ControllerConfig, MocapConfig, ProbeConfig, ZenohConfig, ZenohRole
from cell_config.loader import (
    DEFAULT_CELL,
    REHEARSAL_CELL,
    CellRobot,
    CellSpec,
    LinkInertia,
    RobotSpec,
    ToolSpec,
    load_cell,
    load_robot,
    load_tool,
)
from cell_config.registration import RobotRegistration, load_registration, save_registration

__all__ = [
    "DEFAULT_CELL",
    "REHEARSAL_CELL",
    "ZENOH_ROLES",
    "CellRobot",
    "CellSpec",
    "ControllerConfig",
    "LinkInertia",
    "MocapConfig",
    "ProbeConfig",
    "RobotRegistration",
    "RobotSpec",
    "ToolSpec",
    "ZenohConfig",
    "ZenohRole",
    "load_cell",
    "load_registration",
    "load_robot",
    "load_tool",
    "save_registration",
]
