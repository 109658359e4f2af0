"""The cell's devices and network as data: the MotoROS controller, the Motive server, the CAN probe, Zenoh.

Parsed from the optional ``controller``, ``mocap``, ``probe`` and ``zenoh`` blocks of ``cell.yaml`` by
:func:`~cell_config.loader.load_cell`. Every block refuses unknown keys (the message lists the valid ones) and
values of the wrong YAML type: a boolean must be a YAML boolean (the string ``"false"`` is an error), an
integer an int, a port 1..65535, a host a non-empty string without spaces.
"""

from __future__ import annotations

import ipaddress
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

from cell_config._yaml import Node

ZenohRole = Literal["bridge", "collector", "router"]
ZENOH_ROLES: tuple[str, ...] = ("bridge", "collector", "router")
ZENOH_MODES: tuple[str, ...] = ("peer", "client", "router")
MAX_MOTOROS_GROUPS = 4  # MotoROS control groups 0..3


@dataclass(frozen=True)
class ZenohConfig:
    """One Zenoh session's settings: mode, endpoints to listen on / connect to, multicast scouting."""

    mode: str = "peer"
    listen: tuple[str, ...] = ()
    connect: tuple[str, ...] = ()
    multicast_scouting: bool = False


@dataclass(frozen=True)
class ControllerConfig:
    """The MotoROS controller carrying the cell's arms.

    Attributes:
        host: controller address.
        motion_port: MotoROS motion server port (TCP).
        state_port: MotoROS state server port (TCP).
        groups: robot name -> MotoROS control group (0..3), distinct.
        connect_timeout_s: TCP connect timeout [s].
        reply_timeout_s: timeout of one motion-server reply [s].
        start_traj_timeout_s: timeout of START_TRAJ_MODE [s]: MotoROS resets alarms, turns the servos on and
            starts its job, each waited for up to 5 s, so up to ~15 s on a real controller (25 s leaves margin).
        max_speed_fraction: cap of ``--speed`` as a fraction of each joint's maximum speed, in (0, 1].
        joint_margin_deg: distance kept from every joint limit on this cell [deg].
    """

    host: str
    motion_port: int = 50240
    state_port: int = 50241
    connect_timeout_s: float = 5.0
    reply_timeout_s: float = 2.0
    start_traj_timeout_s: float = 25.0
    max_speed_fraction: float = 0.25
    joint_margin_deg: float = 2.0
    groups: Mapping[str, int] = field(kw_only=True)


#: Longest measurement window a cell file may set [s]: a static pose needs no more, and a window's give-up
#: guard scales with it.
MAX_DWELL_S = 10.0


@dataclass(frozen=True)
class MocapConfig:
    """The Motive (NatNet) server and how the bridge PC reaches it.

    Attributes:
        server_address: the Motive PC.
        local_address: the bridge PC's interface facing it.
        multicast: data stream by multicast (True) or unicast (False).
        rigid_bodies: robot name -> Motive rigid-body NAME of its marker (ids come from the model definitions).
        multicast_group: the NatNet multicast group.
        command_port: NatNet command port (UDP).
        data_port: NatNet data port (UDP).
        dwell_s: length of each measurement's averaging window [s of capture time]; None keeps the collection's
            default (:class:`app.collection.collect.CollectConfig`). It must hold ``min_frames`` frames at the frame rate.
        stream_wait_s: how long the collector waits for a stopped mocap stream (the bridge restarted, the network
            dropped) before the measurement counts as failed [s].
        first_frame_s: how long opening the real cell waits for the first frame of each arm's rigid body before
            refusing to move [s].
    """

    server_address: str
    local_address: str
    multicast: bool
    rigid_bodies: Mapping[str, str]
    multicast_group: str = "239.255.42.99"
    command_port: int = 1510
    data_port: int = 1511
    dwell_s: float | None = None
    stream_wait_s: float = 30.0
    first_frame_s: float = 5.0


@dataclass(frozen=True)
class ProbeConfig:
    """The CAN touch probe: python-can interface and channel, bitrate, heartbeat id (event = base_id + 1)."""

    interface: str
    channel: str
    bitrate: int
    base_id: int


#: The keys of the ``controller``, ``mocap`` and ``probe`` blocks of a cell file (any other key is refused).
CONTROLLER_KEYS = ("host", "motion_port", "state_port", "groups", "connect_timeout_s", "reply_timeout_s",
                   "start_traj_timeout_s", "max_speed_fraction", "joint_margin_deg")
MOCAP_KEYS = ("server_address", "local_address", "multicast", "multicast_group", "command_port", "data_port",
              "rigid_bodies", "dwell_s", "stream_wait_s", "first_frame_s")
PROBE_KEYS = ("interface", "channel", "bitrate", "base_id")


def _robot_names(node: Node, key: str, robots: Mapping[str, Any]) -> Node:
    """The mapping under ``key`` whose keys must be robots of the cell (non-empty)."""
    if not isinstance(node.get(key), dict) or not node.get(key):
        raise node.error(key, f"expected a non-empty mapping of robot names ({', '.join(robots)}) to values")
    m = node.child(key)
    for name in m.data:
        if name not in robots:
            raise m.error(str(name), f"unknown robot {name!r}; valid: {', '.join(robots)}")
    return m


def _host(node: Node, key: str, default: str | None = None) -> str:
    value = node.string(key) if default is None else node.string(key, default)
    if value != value.strip() or any(c.isspace() for c in value):
        raise node.error(key, f"expected a host name or address without spaces, got {value!r}")
    return value


def parse_controller(node: Node | None, robots: Mapping[str, Any]) -> ControllerConfig | None:
    """The ``controller`` block (None when absent); ``robots`` are the cell's, which ``groups`` must name."""
    if node is None:
        return None
    d = ControllerConfig("", groups={})
    node.only(CONTROLLER_KEYS)
    g = _robot_names(node, "groups", robots)
    groups = {str(name): g.integer(name, lo=0, hi=MAX_MOTOROS_GROUPS - 1) for name in g.data}
    if len(set(groups.values())) != len(groups):
        raise node.error("groups", f"expected a distinct control group per robot, got {groups}")
    motion_port, state_port = node.port("motion_port", d.motion_port), node.port("state_port", d.state_port)
    if motion_port == state_port:
        raise node.error("state_port", f"expected a port other than motion_port ({motion_port})")
    return ControllerConfig(
        host=_host(node, "host"), motion_port=motion_port, state_port=state_port, groups=groups,
        connect_timeout_s=node.number("connect_timeout_s", d.connect_timeout_s, lo=0.0, lo_open=True),
        reply_timeout_s=node.number("reply_timeout_s", d.reply_timeout_s, lo=0.0, lo_open=True),
        start_traj_timeout_s=node.number("start_traj_timeout_s", d.start_traj_timeout_s, lo=0.0, lo_open=True),
        max_speed_fraction=node.number("max_speed_fraction", d.max_speed_fraction, lo=0.0, hi=1.0, lo_open=True),
        joint_margin_deg=node.number("joint_margin_deg", d.joint_margin_deg, lo=0.0, hi=45.0),
    )


def parse_mocap(node: Node | None, robots: Mapping[str, Any]) -> MocapConfig | None:
    """The ``mocap`` block (None when absent); ``robots`` are the cell's, which ``rigid_bodies`` must name."""
    if node is None:
        return None
    d = MocapConfig("", "", False, {})
    node.only(MOCAP_KEYS)
    b = _robot_names(node, "rigid_bodies", robots)
    bodies = {str(name): b.string(name) for name in b.data}
    if len(set(bodies.values())) != len(bodies):
        raise node.error("rigid_bodies", f"expected a distinct rigid body per robot, got {bodies}")
    group = _host(node, "multicast_group", d.multicast_group)
    try:
        is_multicast = ipaddress.ip_address(group).is_multicast
    except ValueError:
        is_multicast = False
    if not is_multicast:
        raise node.error("multicast_group", f"expected a multicast IP address like 239.255.42.99, got {group!r}")
    command_port, data_port = node.port("command_port", d.command_port), node.port("data_port", d.data_port)
    if command_port == data_port:
        raise node.error("data_port", f"expected a port other than command_port ({command_port})")
    return MocapConfig(
        server_address=_host(node, "server_address"), local_address=_host(node, "local_address"),
        multicast=node.boolean("multicast"), rigid_bodies=bodies, multicast_group=group,
        command_port=command_port, data_port=data_port, dwell_s=node.number("dwell_s", None, lo=0.0, hi=MAX_DWELL_S,
                                                                       lo_open=True),
        stream_wait_s=node.number("stream_wait_s", d.stream_wait_s, lo=0.0, hi=3600.0, lo_open=True),
        first_frame_s=node.number("first_frame_s", d.first_frame_s, lo=0.0, hi=3600.0, lo_open=True),
    )


def parse_probe(node: Node | None) -> ProbeConfig | None:
    """The ``probe`` block (None when absent)."""
    if node is None:
        return None
    node.only(PROBE_KEYS)
    return ProbeConfig(
        interface=node.string("interface"), channel=node.string("channel"),
        bitrate=node.integer("bitrate", lo=1),
        base_id=node.integer("base_id", lo=0, hi=0x7FE),  # 11-bit ids; the event frame uses base_id + 1
    )


#: The keys of one Zenoh session (the ``zenoh`` block, which adds ``roles``, and each of its roles).
ZENOH_KEYS = ("mode", "listen", "connect", "multicast_scouting")


def _zenoh_session(node: Node, extra: tuple[str, ...] = ()) -> ZenohConfig:
    node.only(ZENOH_KEYS + extra)
    d = ZenohConfig()
    mode = node.get("mode", d.mode)
    if mode not in ZENOH_MODES:
        raise node.error("mode", f"expected one of {', '.join(ZENOH_MODES)}, got {mode!r}")
    what = "endpoint strings like tcp/127.0.0.1:7447"
    return ZenohConfig(mode, node.strings("listen", d.listen, what), node.strings("connect", d.connect, what),
                       node.boolean("multicast_scouting", d.multicast_scouting))


def parse_zenoh(node: Node | None) -> tuple[ZenohConfig, dict[str, ZenohConfig]]:
    """The default session settings and the per-role overrides (each complete: unset keys take the defaults
    of :class:`ZenohConfig`, not the default block's values)."""
    if node is None:
        return ZenohConfig(), {}
    default = _zenoh_session(node, ("roles",))
    roles_node = node.child("roles", None)
    if roles_node is None:
        return default, {}
    roles_node.only(ZENOH_ROLES)
    return default, {str(role): _zenoh_session(roles_node.child(role)) for role in roles_node.data}
