"""The cell described as data (robots, tools, layout) and its typed loader."""

from cell_config.loader import (
    DEFAULT_CELL,
    CellRobot,
    CellSpec,
    LinkInertia,
    RobotSpec,
    ToolSpec,
    ZenohConfig,
    load_cell,
    load_robot,
    load_tool,
)

__all__ = [
    "DEFAULT_CELL",
    "CellRobot",
    "CellSpec",
    "LinkInertia",
    "RobotSpec",
    "ToolSpec",
    "ZenohConfig",
    "load_cell",
    "load_robot",
    "load_tool",
]
