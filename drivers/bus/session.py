"""Zenoh sessions and key expressions of the cellcal bus.

Sessions are built from the cell's :class:`~cell_config.devices.ZenohConfig`: peer mode, multicast
scouting off and, when no endpoint is configured, a listener on an ephemeral loopback port, so nothing
leaves the machine unless ``cell.yaml`` says so. Separate machines work by listing endpoints
(``listen: [tcp/0.0.0.0:7447]`` on one, ``connect: [tcp/<ip>:7447]`` on the other) or by pointing every
process at a router (``mode: client``, ``connect: [tcp/<router>:7447]``). With multicast scouting off, two
processes only meet if one of them connects to an endpoint the other listens on.
"""

from __future__ import annotations

import json
import re
import time
from typing import TYPE_CHECKING, Any, cast

from cell_config.devices import ZenohConfig
from drivers.errors import DriverError

if TYPE_CHECKING:
    import zenoh

DEVICE = "zenoh"
DEFAULT_LISTEN = ("tcp/127.0.0.1:0",)
_CHUNK = re.compile(r"[A-Za-z0-9_.\-]+")


def _chunk(value: str, what: str) -> str:
    if not isinstance(value, str) or not _CHUNK.fullmatch(value):
        raise DriverError(DEVICE, f"{what} {value!r} is not a valid key chunk; use letters, digits, '_', '.', '-'")
    return value


def mocap_key(cell: str, rigid_body: str) -> str:
    """Key of a rigid body's frames: ``cellcal/<cell>/mocap/<rigid_body>`` (``*`` matches every body)."""
    body = rigid_body if rigid_body == "*" else _chunk(rigid_body, "rigid body name")
    return f"cellcal/{_chunk(cell, 'cell name')}/mocap/{body}"


def joints_key(cell: str, robot: str) -> str:
    """Key of a robot's joint states: ``cellcal/<cell>/robot/<robot>/joints``."""
    return f"cellcal/{_chunk(cell, 'cell name')}/robot/{_chunk(robot, 'robot name')}/joints"


def session_settings(config: ZenohConfig) -> dict[str, Any]:
    """The zenoh configuration entries (key path -> JSON value) that ``config`` stands for.

    Raises:
        DriverError: unknown mode, or client mode without a connect endpoint.
    """
    if config.mode not in ("peer", "client", "router"):
        raise DriverError(DEVICE, f"mode {config.mode!r} is not one of peer, client, router")
    if config.mode == "client" and not config.connect:
        raise DriverError(DEVICE, "client mode needs at least one connect endpoint (the router)")
    listen = list(config.listen) or ([] if config.mode == "client" else list(DEFAULT_LISTEN))
    return {
        "mode": config.mode,
        "listen/endpoints": listen,
        "connect/endpoints": list(config.connect),
        "scouting/multicast/enabled": bool(config.multicast_scouting),
    }


def open_session(config: ZenohConfig | None = None) -> zenoh.Session:
    """Open a zenoh session for ``config`` (defaults: peer, loopback listener, no multicast scouting).

    Raises:
        DriverError: bad settings, or zenoh could not open the session (endpoint in use, bad locator).
    """
    import zenoh

    settings = session_settings(config or ZenohConfig())
    conf = zenoh.Config()
    try:
        for key, value in settings.items():
            conf.insert_json5(key, json.dumps(value))
        return zenoh.open(conf)
    except zenoh.ZError as e:
        raise DriverError(DEVICE, f"cannot open a session with {settings} ({e})") from e


def wait_for_subscriber(session: zenoh.Session, key: str, timeout_s: float) -> bool:
    """Block until some subscriber on the network matches ``key``; False after ``timeout_s`` [s].

    Samples put before the route exists are lost, so a publisher that must not miss the first frames
    (tests, benchmarks, a recording that starts on command) waits here first.
    """
    import zenoh

    deadline = time.monotonic() + timeout_s
    try:
        probe = session.declare_publisher(key)
    except zenoh.ZError as e:
        raise DriverError(DEVICE, f"cannot declare a publisher on {key} ({e})") from e
    try:
        # zenoh's stub types matching_status as bool; it is a MatchingStatus
        while not cast("zenoh.MatchingStatus", probe.matching_status).matching:
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.01)
        return True
    finally:
        probe.undeclare()  # type: ignore[no-untyped-call]  # zenoh's stub leaves undeclare() unannotated
