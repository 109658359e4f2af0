import os
import re
import stat

import numpy as np
import pytest
import yaml

from calibration.errors import ConfigError
from cell_config import (
    DEFAULT_CELL,
    REHEARSAL_CELL,
    ControllerConfig,
    MocapConfig,
    ProbeConfig,
    RobotRegistration,
    ZenohConfig,
    load_cell,
    load_registration,
    load_robot,
    save_registration,
)


def test_default_cell_loads_both_arms():
    cell = load_cell()
    assert set(cell.robots) == {"R1", "R2"}
    r2 = cell.robot("R2")
    assert r2.robot.name == "MA1440"
    assert r2.T_cell_base[0, 3] == pytest.approx(2703.649529)
    np.testing.assert_allclose(np.degrees(cell.robot("R1").robot.upper_rad), [180, 155, 160, 150, 90, 210])
    assert cell.zenoh.multicast_scouting is False
    with pytest.raises(ConfigError, match="unknown robot 'R3'; valid: R1, R2"):
        cell.robot("R3")


def _copy_cell(tmp_path, mutate):
    data = yaml.safe_load(DEFAULT_CELL.read_text())
    for name in data["robots"]:
        for key in ("robot", "tool"):
            data["robots"][name][key] = str(DEFAULT_CELL.parent / data["robots"][name][key])
    mutate(data)
    path = tmp_path / "cell.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.mark.parametrize("mutate, key, reason", [
    (lambda d: d["robots"]["R2"].pop("T_cell_base"), "robots.R2.T_cell_base", "required key is missing"),
    (lambda d: d["robots"]["R2"].__setitem__("T_cell_base", [[1, 0], [0, 1]]), "robots.R2.T_cell_base",
     "expected shape (4, 4)"),
    (lambda d: d.__setitem__("robots", []), "robots", "expected a mapping"),
    (lambda d: d["zenoh"].__setitem__("mode", "broker"), "zenoh.mode", "expected one of peer, client, router"),
    (lambda d: d.pop("name"), "name", "required key is missing"),
    (lambda d: d.__setitem__("colour", "red"), "colour",
     "unknown key in the top level; valid keys: name, robots, zenoh, controller, mocap, probe, registration"),
    (lambda d: d.__setitem__("registraton", "reg.yaml"), "registraton", "unknown key in the top level"),
    (lambda d: d.__setitem__("controler", {"host": "1.2.3.4"}), "controler", "unknown key in the top level"),
    (lambda d: d["robots"]["R1"].__setitem__("payload_kg", 2.0), "robots.R1.payload_kg",
     "unknown key in robots.R1; valid keys: robot, tool, T_cell_base"),
])
def test_malformed_cell_names_file_and_key(tmp_path, mutate, key, reason):
    path = _copy_cell(tmp_path, mutate)
    with pytest.raises(ConfigError) as e:
        load_cell(path)
    assert e.value.key == key and reason in e.value.reason and e.value.path == str(path)


def test_malformed_robot_yaml(tmp_path):
    text = (DEFAULT_CELL.parent / "robots" / "MA2010.yaml").read_text()
    bad = tmp_path / "bad.yaml"
    bad.write_text(text.replace("lower: [-180, -105, -86, -150, -135, -210]", "lower: [-180, -105]"))
    with pytest.raises(ConfigError, match=r"joint_limits_deg.lower: expected shape \(6,\)"):
        load_robot(bad)
    bad.write_text("{not yaml: [")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_robot(bad)
    bad.write_text("name: MA2010\njoint_limits_deg: [1, 2\n")  # one line naming the place (it quoted YAML's 3 lines)
    with pytest.raises(ConfigError) as e:
        load_robot(bad)
    # the parser's own words after the place (libyaml's, read as model files are: "did not find expected ',' or ']'")
    assert re.search(r"not valid YAML \(line 3, column 1: [^()]*expected ',' or '\]'[^()]*\)$", str(e.value)), e.value
    assert "\n" not in str(e.value)
    with pytest.raises(ConfigError, match="file not found"):
        load_robot(tmp_path / "missing.yaml")


# --- the real cell's devices, network roles and registration -------------------------------------------------

def test_rehearsal_cell_puts_every_device_on_loopback():
    cell = load_cell(REHEARSAL_CELL)
    default = load_cell()
    assert set(cell.robots) == set(default.robots)
    for name in cell.robots:
        np.testing.assert_array_equal(cell.robot(name).T_cell_base, default.robot(name).T_cell_base)
        assert cell.robot(name).robot.name == default.robot(name).robot.name
        assert cell.robot(name).tool.name == default.robot(name).tool.name
    assert cell.controller == ControllerConfig("127.0.0.1", 50240, 50241, groups={"R1": 0, "R2": 1})
    assert cell.mocap == MocapConfig("127.0.0.1", "127.0.0.1", False, {"R1": "weldgun", "R2": "mti"})
    assert cell.probe == ProbeConfig("virtual", "rehearsal", 500000, 0x5A0)
    assert cell.zenoh_for("bridge") == ZenohConfig("peer", ("tcp/127.0.0.1:7447",), (), False)
    assert cell.zenoh_for("collector") == ZenohConfig("peer", (), ("tcp/127.0.0.1:7447",), False)
    assert cell.zenoh_for("router") == ZenohConfig("router", ("tcp/127.0.0.1:7446",), (), False)
    assert cell.registration_path == REHEARSAL_CELL.parent / "rehearsal.registration.yaml"
    if not cell.registration_path.exists():
        assert cell.registration == {}


def test_default_cell_has_no_devices_and_every_role_uses_the_zenoh_block():
    cell = load_cell()
    assert (cell.controller, cell.mocap, cell.probe, cell.registration_path) == (None, None, None, None)
    assert cell.registration == {} and cell.zenoh_roles == {}
    for role in ("bridge", "collector", "router"):
        assert cell.zenoh_for(role) is cell.zenoh
    with pytest.raises(ConfigError, match="unknown role 'gateway'; valid: bridge, collector, router"):
        cell.zenoh_for("gateway")


def test_role_override_is_complete_on_its_own(tmp_path):
    def mutate(d):
        d["zenoh"] = {"mode": "peer", "connect": ["tcp/10.0.0.9:7447"], "multicast_scouting": True,
                      "roles": {"bridge": {"listen": ["tcp/0.0.0.0:7447"]}}}
    cell = load_cell(_copy_rehearsal(tmp_path, mutate))
    assert cell.zenoh == ZenohConfig("peer", (), ("tcp/10.0.0.9:7447",), True)
    assert cell.zenoh_for("bridge") == ZenohConfig("peer", ("tcp/0.0.0.0:7447",), (), False)
    assert cell.zenoh_for("collector") is cell.zenoh


def _copy_rehearsal(tmp_path, mutate, name="cell.yaml"):
    data = yaml.safe_load(REHEARSAL_CELL.read_text())
    for robot in data["robots"]:
        for key in ("robot", "tool"):
            data["robots"][robot][key] = str(REHEARSAL_CELL.parent / data["robots"][robot][key])
    mutate(data)
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data))
    return path


def _set(block, key, value):
    def mutate(d):
        node = d
        for part in block.split("."):
            node = node[part]
        node[key] = value
    return mutate


def _pop(block, key):
    def mutate(d):
        node = d
        for part in block.split("."):
            node = node[part]
        node.pop(key)
    return mutate


_CONTROLLER_KEYS = ("host, motion_port, state_port, groups, connect_timeout_s, reply_timeout_s, "
                    "start_traj_timeout_s, max_speed_fraction, joint_margin_deg")


@pytest.mark.parametrize("mutate, key, reason", [
    (_set("controller", "host", ""), "controller.host", "expected a non-empty string"),
    (_set("controller", "host", "192.168.255.1 x"), "controller.host", "without spaces"),
    (_pop("controller", "host"), "controller.host", "required key is missing"),
    (_set("controller", "motion_port", 0), "controller.motion_port", "expected an integer in [1, 65535], got 0"),
    (_set("controller", "state_port", 65536), "controller.state_port", "expected an integer in [1, 65535]"),
    (_set("controller", "motion_port", 50240.0), "controller.motion_port", "expected an integer in [1, 65535]"),
    (_set("controller", "motion_port", True), "controller.motion_port", "expected an integer in [1, 65535]"),
    (_set("controller", "motion_port", "50240"), "controller.motion_port", "expected an integer"),
    (_set("controller", "state_port", 50240), "controller.state_port", "other than motion_port"),
    (_set("controller", "groups", {"R1": 0, "R3": 1}), "controller.groups.R3", "unknown robot 'R3'; valid: R1, R2"),
    (_set("controller", "groups", {"R1": 0, "R2": 0}), "controller.groups", "distinct control group"),
    (_set("controller", "groups", {"R1": 4}), "controller.groups.R1", "expected an integer in [0, 3], got 4"),
    (_set("controller", "groups", {"R1": -1}), "controller.groups.R1", "expected an integer in [0, 3]"),
    (_set("controller", "groups", {"R1": True}), "controller.groups.R1", "expected an integer in [0, 3]"),
    (_set("controller", "groups", {}), "controller.groups", "expected a non-empty mapping of robot names"),
    (_set("controller", "groups", ["R1"]), "controller.groups", "expected a non-empty mapping of robot names"),
    (_pop("controller", "groups"), "controller.groups", "required key is missing"),
    (_set("controller", "reply_timeout_s", 0), "controller.reply_timeout_s", "expected a finite number > 0"),
    (_set("controller", "connect_timeout_s", float("nan")), "controller.connect_timeout_s", "finite number"),
    (_set("controller", "start_traj_timeout_s", "15"), "controller.start_traj_timeout_s", "finite number"),
    (_set("controller", "max_speed_fraction", 1.5), "controller.max_speed_fraction", "in (0, 1]"),
    (_set("controller", "joint_margin_deg", -1), "controller.joint_margin_deg", "in [0, 45]"),
    (_set("controller", "speed", 0.5), "controller.speed", f"unknown key in controller; valid keys: {_CONTROLLER_KEYS}"),
    (lambda d: d.__setitem__("controller", "127.0.0.1"), "controller", "expected a mapping"),
    (_set("mocap", "multicast", "false"), "mocap.multicast", "expected a YAML boolean (true or false, unquoted)"),
    (_set("mocap", "multicast", 0), "mocap.multicast", "expected a YAML boolean"),
    (_pop("mocap", "multicast"), "mocap.multicast", "required key is missing"),
    (_set("mocap", "server_address", ""), "mocap.server_address", "expected a non-empty string"),
    (_pop("mocap", "local_address"), "mocap.local_address", "required key is missing"),
    (_set("mocap", "rigid_bodies", {"R1": "weldgun", "R9": "x"}), "mocap.rigid_bodies.R9",
     "unknown robot 'R9'; valid: R1, R2"),
    (_set("mocap", "rigid_bodies", {"R1": "gun", "R2": "gun"}), "mocap.rigid_bodies", "distinct rigid body"),
    (_set("mocap", "rigid_bodies", {"R1": ""}), "mocap.rigid_bodies.R1", "expected a non-empty string"),
    (_set("mocap", "rigid_bodies", {"R1": 3}), "mocap.rigid_bodies.R1", "expected a non-empty string"),
    (_set("mocap", "multicast_group", "10.0.0.1"), "mocap.multicast_group", "expected a multicast IP address"),
    (_set("mocap", "data_port", 1510), "mocap.data_port", "other than command_port (1510)"),
    (_set("mocap", "command_port", 99999), "mocap.command_port", "expected an integer in [1, 65535]"),
    (_set("mocap", "rigid_body_ids", {"R1": 1}), "mocap.rigid_body_ids", "valid keys: server_address, local_address, "
     "multicast, multicast_group, command_port, data_port, rigid_bodies, dwell_s, stream_wait_s, first_frame_s"),
    (_set("mocap", "dwell_s", 0), "mocap.dwell_s", "expected a finite number in (0, 10], got 0"),
    (_set("mocap", "dwell_s", "0.5"), "mocap.dwell_s", "expected a finite number in (0, 10]"),
    (_set("mocap", "dwell_s", 1e7), "mocap.dwell_s", "expected a finite number in (0, 10], got 10000000.0"),
    (_set("mocap", "first_frame_s", 0), "mocap.first_frame_s", "expected a finite number in (0, 3600], got 0"),
    (_set("mocap", "first_frame_s", "5"), "mocap.first_frame_s", "expected a finite number in (0, 3600]"),
    (_set("mocap", "first_frame_s", float("nan")), "mocap.first_frame_s", "expected a finite number in (0, 3600]"),
    (_set("mocap", "first_frame_s", 7200), "mocap.first_frame_s", "expected a finite number in (0, 3600], got 7200"),
    (_set("probe", "bitrate", "500k"), "probe.bitrate", "expected an integer >= 1"),
    (_set("probe", "bitrate", 0), "probe.bitrate", "expected an integer >= 1"),
    (_set("probe", "base_id", 0x7FF), "probe.base_id", "expected an integer in [0, 2046]"),
    (_set("probe", "base_id", 384.0), "probe.base_id", "expected an integer in [0, 2046]"),
    (_pop("probe", "channel"), "probe.channel", "required key is missing"),
    (_set("probe", "bus", "can1"), "probe.bus", "unknown key in probe; valid keys: interface, channel, bitrate, base_id"),
    (_set("zenoh", "multicast_scouting", "false"), "zenoh.multicast_scouting", "expected a YAML boolean"),
    (_set("zenoh", "listen", "tcp/127.0.0.1:7447"), "zenoh.listen", "expected a list of endpoint strings"),
    (_set("zenoh", "scouting", False), "zenoh.scouting",
     "unknown key in zenoh; valid keys: mode, listen, connect, multicast_scouting, roles"),
    (_set("zenoh.roles", "gateway", {"mode": "peer"}), "zenoh.roles.gateway",
     "unknown key in zenoh.roles; valid keys: bridge, collector, router"),
    (_set("zenoh.roles.bridge", "multicast_scouting", "false"), "zenoh.roles.bridge.multicast_scouting",
     "expected a YAML boolean"),
    (_set("zenoh.roles.router", "mode", "broker"), "zenoh.roles.router.mode", "expected one of peer, client, router"),
    (_set("zenoh.roles.collector", "connect", [7447]), "zenoh.roles.collector.connect", "expected a list of endpoint"),
    (_set("zenoh.roles.collector", "roles", {}), "zenoh.roles.collector.roles",
     "valid keys: mode, listen, connect, multicast_scouting"),
    (_set("zenoh.roles", "bridge", ["tcp/127.0.0.1:7447"]), "zenoh.roles.bridge", "expected a mapping"),
    (lambda d: d.__setitem__("registration", ""), "registration", "expected a non-empty string"),
])
def test_malformed_device_blocks_name_the_key(tmp_path, mutate, key, reason):
    path = _copy_rehearsal(tmp_path, mutate)
    with pytest.raises(ConfigError) as e:
        load_cell(path)
    assert e.value.key == key and reason in e.value.reason and e.value.path == str(path)
    assert f": {key}: " in str(e.value)


def test_the_cell_files_dwell_window_is_the_real_collections_window(tmp_path):
    """``mocap.dwell_s`` sets the measurement window of every real-cell command; absent, the collection's default;
    never the simulated cell's (its mocap is not this block)."""
    import argparse
    import dataclasses

    from app.cli.cell_options import motion_config
    from app.collection.collect import CollectConfig

    real, sim = argparse.Namespace(sim=False, speed=None), argparse.Namespace(sim=True, speed=None)
    default = load_cell(_copy_rehearsal(tmp_path, lambda d: None))
    assert default.mocap.dwell_s is None
    assert motion_config(default, real).dwell_s == CollectConfig().dwell_s
    short = load_cell(_copy_rehearsal(tmp_path, _set("mocap", "dwell_s", 0.2), "short.yaml"))
    assert short.mocap.dwell_s == 0.2 and motion_config(short, real).dwell_s == 0.2
    assert motion_config(short, sim) == motion_config(dataclasses.replace(short, mocap=None), sim)


def test_the_cell_files_first_frame_wait_is_the_real_cells(tmp_path, capsys):
    """``mocap.first_frame_s`` sets how long opening the real cell waits for each arm's first mocap frame; absent,
    5 s (the wait before the key existed). A bad value is refused in one line naming the file and the key, before
    the command does anything."""
    from app.collection.runtime.real import RealCell
    from tests.conftest import assert_bad_input

    default = load_cell(_copy_rehearsal(tmp_path, lambda d: None))
    assert default.mocap.first_frame_s == 5.0 and RealCell(default, registered=False).first_frame_s == 5.0
    short = load_cell(_copy_rehearsal(tmp_path, _set("mocap", "first_frame_s", 0.5), "short.yaml"))
    assert short.mocap.first_frame_s == 0.5 and RealCell(short, registered=False).first_frame_s == 0.5
    assert RealCell(short, registered=False, first_frame_s=2.0).first_frame_s == 2.0  # the caller's value wins
    bad = _copy_rehearsal(tmp_path, _set("mocap", "first_frame_s", -1), "bad.yaml")
    session = tmp_path / "s"
    assert_bad_input(capsys, ["--cell", str(bad), "collect", "--robot", "R1", "--session", str(session), "--yes"],
                     str(bad), "mocap.first_frame_s", "(0, 3600]", "-1")
    assert not session.exists()


@pytest.mark.parametrize("block, key", [("zenoh", "multicast_scouting"), ("mocap", "multicast")])
def test_quoted_false_is_not_a_boolean(tmp_path, block, key):
    """The YAML string "false" is truthy in Python: it must be refused, never read as True."""
    text = REHEARSAL_CELL.read_text().replace("robots/", f"{REHEARSAL_CELL.parent}/robots/").replace(
        "tools/", f"{REHEARSAL_CELL.parent}/tools/")
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if line.split("#")[0].strip() == f"{block}:")
    i = next(i for i in range(start, len(lines)) if lines[i].strip().startswith(f"{key}:"))
    lines[i] = lines[i].split(":")[0] + ': "false"'
    path = tmp_path / "cell.yaml"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(ConfigError) as e:
        load_cell(path)
    assert e.value.key == f"{block}.{key}" and "'false'" in e.value.reason
    path.write_text("\n".join(lines).replace('"false"', "false") + "\n")
    cell = load_cell(path)
    assert (cell.zenoh.multicast_scouting if block == "zenoh" else cell.mocap.multicast) is False


# --- registration file ------------------------------------------------------------------------------------------

def _random_rigid(rng):
    Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    Q *= np.sign(np.linalg.det(Q))
    T = np.eye(4)
    T[:3, :3] = Q
    T[:3, 3] = rng.normal(scale=1500.0, size=3)
    return T


def _registration(seed=0, **changes):
    rng = np.random.default_rng(seed)
    fields = dict(T_world_base=_random_rigid(rng), T_flange_marker=_random_rigid(rng),
                  date="2026-12-01T16:05:00+00:00", rms_mm=float(rng.uniform(0.05, 1.0)),
                  rms_deg=float(rng.uniform(0.01, 0.2)), n_samples=24,
                  sigma_world_base=rng.uniform(0.0, 0.5, 6), sigma_flange_marker=rng.uniform(0.0, 0.5, 6))
    fields.update(changes)
    return RobotRegistration(**fields)


def _assert_bit_identical(a, b):
    for name in ("T_world_base", "T_flange_marker", "sigma_world_base", "sigma_flange_marker"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype == np.float64 and x.shape == y.shape and x.tobytes() == y.tobytes(), name
    for name in ("date", "rms_mm", "rms_deg", "n_samples"):
        x, y = getattr(a, name), getattr(b, name)
        assert type(x) is type(y) and x == y, name


def test_registration_round_trip_is_bit_identical(tmp_path):
    path = tmp_path / "cell.registration.yaml"
    regs = {"R1": _registration(1), "R2": _registration(2, sigma_world_base=np.array([-0.0, 1e-300, 5e-324,
                                                                                    1e300, 0.1, 1 / 3]))}
    for name, reg in regs.items():
        save_registration(path, name, reg)
    text = path.read_text()
    assert text.startswith("# Cell registration") and "T_world_base: the robot base in the mocap world" in text
    loaded = load_registration(path)
    assert list(loaded) == ["R1", "R2"]
    for name in regs:
        _assert_bit_identical(loaded[name], regs[name])
    again = tmp_path / "again.yaml"
    for name, reg in loaded.items():
        save_registration(again, name, reg)
    assert again.read_bytes() == path.read_bytes()


def test_save_registration_merges_with_the_other_robots(tmp_path):
    path = tmp_path / "reg.yaml"
    save_registration(path, "R1", _registration(1))
    save_registration(path, "R2", _registration(2))
    save_registration(path, "R1", _registration(3, n_samples=np.int64(30)))  # a numpy int is an int
    loaded = load_registration(path)
    assert list(loaded) == ["R1", "R2"] and loaded["R1"].n_samples == 30
    _assert_bit_identical(loaded["R1"], _registration(3, n_samples=30))
    _assert_bit_identical(loaded["R2"], _registration(2))
    assert sorted(os.listdir(tmp_path)) == ["reg.yaml"]


def test_cell_loads_its_registration(tmp_path):
    cell_path = _copy_rehearsal(tmp_path, lambda d: None)
    assert load_cell(cell_path).registration == {}
    save_registration(tmp_path / "rehearsal.registration.yaml", "R2", _registration(7))
    cell = load_cell(cell_path)
    assert cell.registration_path == tmp_path / "rehearsal.registration.yaml"
    assert list(cell.registration) == ["R2"]
    _assert_bit_identical(cell.registration["R2"], _registration(7))
    save_registration(tmp_path / "rehearsal.registration.yaml", "R9", _registration(8))
    with pytest.raises(ConfigError) as e:
        load_cell(cell_path)
    assert e.value.path == str(tmp_path / "rehearsal.registration.yaml") and e.value.key == "R9"
    assert "unknown robot 'R9'; valid: R1, R2" in e.value.reason


def _scaled(T, s):
    T = T.copy()
    T[:3, :3] *= s
    return T


def _reflected(T):
    T = T.copy()
    T[:3, 0] *= -1
    return T


def _with(T, index, value):
    T = np.array(T, dtype=float)
    T[index] = value
    return T


_T = _random_rigid(np.random.default_rng(5))


@pytest.mark.parametrize("changes, key, reason", [
    (dict(T_world_base=_scaled(_T, 1.01)), "T_world_base", "not orthonormal"),
    (dict(T_world_base=_reflected(_T)), "T_world_base", "det -1"),
    (dict(T_flange_marker=_with(_T, (3, 3), 2.0)), "T_flange_marker", "last row [0, 0, 0, 1]"),
    (dict(T_flange_marker=_with(_T, (3, 0), 1e-3)), "T_flange_marker", "last row [0, 0, 0, 1]"),
    (dict(T_flange_marker=_with(_T, (0, 3), np.nan)), "T_flange_marker", "expected finite numbers"),
    (dict(T_world_base=_with(_T, (1, 1), np.inf)), "T_world_base", "expected finite numbers"),
    (dict(T_world_base=np.eye(3)), "T_world_base", "expected shape (4, 4), got (3, 3)"),
    (dict(sigma_world_base=np.array([0.1, 0.1, np.inf, 0, 0, 0])), "sigma_world_base", "expected finite numbers"),
    (dict(sigma_flange_marker=np.array([0.1, -0.1, 0, 0, 0, 0])), "sigma_flange_marker", "non-negative"),
    (dict(sigma_flange_marker=np.zeros(3)), "sigma_flange_marker", "expected shape (6,)"),
    (dict(n_samples=0), "n_samples", "expected an integer >= 1"),
    (dict(n_samples=24.0), "n_samples", "expected an integer >= 1"),
    (dict(n_samples=True), "n_samples", "expected an integer >= 1"),
    (dict(date="yesterday"), "date", "expected an ISO 8601 date string"),
    (dict(date=None), "date", "expected an ISO 8601 date string"),
    (dict(rms_mm=-0.5), "rms_mm", "expected a finite number >= 0"),
    (dict(rms_deg=float("nan")), "rms_deg", "expected a finite number >= 0"),
])
def test_bad_registration_is_refused_and_nothing_is_written(tmp_path, changes, key, reason):
    path = tmp_path / "reg.yaml"
    save_registration(path, "R2", _registration(2))
    before = path.read_bytes()
    with pytest.raises(ConfigError) as e:
        save_registration(path, "R1", _registration(1, **changes))
    assert e.value.key == f"R1.{key}" and reason in e.value.reason and e.value.path == str(path)
    assert path.read_bytes() == before and sorted(os.listdir(tmp_path)) == ["reg.yaml"]
    new = tmp_path / "new.yaml"
    with pytest.raises(ConfigError):
        save_registration(new, "R1", _registration(1, **changes))
    assert not new.exists()


@pytest.mark.parametrize("edit, key, reason", [
    (lambda e: e.__setitem__("offset_mm", 1.0), "R1.offset_mm",
     "unknown key in R1; valid keys: T_world_base, T_flange_marker, date, rms_mm, rms_deg, n_samples, "
     "sigma_world_base, sigma_flange_marker"),
    (lambda e: e.pop("T_flange_marker"), "R1.T_flange_marker", "required key is missing"),
    (lambda e: e.__setitem__("T_world_base", [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, "1"]]),
     "R1.T_world_base", "expected numbers of shape (4, 4)"),
    (lambda e: e.__setitem__("rms_mm", "0.2"), "R1.rms_mm", "expected a finite number >= 0"),
    (lambda e: e.__setitem__("n_samples", "24"), "R1.n_samples", "expected an integer >= 1"),
])
def test_malformed_registration_file_names_the_key(tmp_path, edit, key, reason):
    path = tmp_path / "reg.yaml"
    save_registration(path, "R1", _registration(1))
    data = yaml.safe_load(path.read_text())
    edit(data["R1"])
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError) as e:
        load_registration(path)
    assert e.value.key == key and reason in e.value.reason and e.value.path == str(path)
    before = path.read_bytes()
    with pytest.raises(ConfigError):  # nor is a malformed file overwritten by a save of another robot
        save_registration(path, "R2", _registration(2))
    assert path.read_bytes() == before


def test_registration_file_must_be_a_mapping(tmp_path):
    path = tmp_path / "reg.yaml"
    path.write_text("- R1\n")
    with pytest.raises(ConfigError, match="expected a mapping at the top level"):
        load_registration(path)
    with pytest.raises(ConfigError, match="file not found"):
        load_registration(tmp_path / "missing.yaml")
    path.write_text("")
    assert load_registration(path) == {}


@pytest.mark.parametrize("failing", ["replace", "fsync"])
def test_failed_save_leaves_the_old_file_and_no_temporary(tmp_path, monkeypatch, failing):
    path = tmp_path / "reg.yaml"
    save_registration(path, "R1", _registration(1))
    before = path.read_bytes()

    def fail(*args, **kwargs):
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(os, failing, fail)
    with pytest.raises(ConfigError, match="cannot write .*No space left on device") as e:
        save_registration(path, "R2", _registration(2))
    assert e.value.path == str(path)
    monkeypatch.undo()
    assert path.read_bytes() == before and sorted(os.listdir(tmp_path)) == ["reg.yaml"]


def test_save_refuses_symlinks_and_non_regular_files(tmp_path):
    real = tmp_path / "real.yaml"
    save_registration(real, "R1", _registration(1))
    before = real.read_bytes()
    link = tmp_path / "link.yaml"
    link.symlink_to(real)
    with pytest.raises(ConfigError, match="refusing to replace a symlink"):
        save_registration(link, "R2", _registration(2))
    assert link.is_symlink() and real.read_bytes() == before
    folder = tmp_path / "dir.yaml"
    folder.mkdir()
    fifo = tmp_path / "fifo.yaml"
    os.mkfifo(fifo)
    for path in (folder, fifo):
        with pytest.raises(ConfigError, match="not a regular file") as e:
            save_registration(path, "R1", _registration(1))
        assert e.value.path == str(path)
    assert sorted(os.listdir(tmp_path)) == ["dir.yaml", "fifo.yaml", "link.yaml", "real.yaml"]


def test_saved_file_mode_follows_the_umask_like_open(tmp_path):
    old = os.umask(0o027)
    try:
        save_registration(tmp_path / "new.yaml", "R1", _registration(1))
        with open(tmp_path / "plain.yaml", "w") as f:
            f.write("{}\n")
    finally:
        os.umask(old)
    mode = stat.S_IMODE(os.stat(tmp_path / "new.yaml").st_mode)
    assert mode == stat.S_IMODE(os.stat(tmp_path / "plain.yaml").st_mode) == 0o640
    existing = tmp_path / "plain.yaml"
    os.chmod(existing, 0o604)
    save_registration(existing, "R1", _registration(1))  # an existing file keeps its mode, as open("w") does
    assert stat.S_IMODE(os.stat(existing).st_mode) == 0o604


# --- collision capsules in the robot YAML -----------------------------------------------------------------------

_CAPS_LINE = "capsules_mm: {base: 220, shoulder: 180, upper_arm: 140, forearm: 110, wrist: 90, tool: 50}"


def test_robot_yaml_carries_its_capsule_radii():
    spec = load_robot(DEFAULT_CELL.parent / "robots" / "MA1440.yaml")
    assert spec.capsules_mm == {"base": 180.0, "shoulder": 150.0, "upper_arm": 110.0, "forearm": 90.0,
                                "wrist": 70.0, "tool": 50.0}
    assert all(type(v) is float for v in spec.capsules_mm.values())


@pytest.mark.parametrize("line, key, reason", [
    ("", "capsules_mm", "required key is missing"),
    ("capsules_mm: [220, 180]", "capsules_mm", "expected a mapping"),
    (_CAPS_LINE.replace(", tool: 50", ""), "capsules_mm.tool", "required key is missing"),
    (_CAPS_LINE.replace("tool: 50", "tool: 50, gun: 60"), "capsules_mm.gun",
     "unknown key in capsules_mm; valid keys: base, shoulder, upper_arm, forearm, wrist, tool"),
    (_CAPS_LINE.replace("wrist: 90", "wrist: 0"), "capsules_mm.wrist", "expected a finite number > 0"),
    (_CAPS_LINE.replace("wrist: 90", "wrist: -90"), "capsules_mm.wrist", "expected a finite number > 0"),
    (_CAPS_LINE.replace("wrist: 90", "wrist: '90'"), "capsules_mm.wrist", "expected a finite number > 0"),
    (_CAPS_LINE.replace("wrist: 90", "wrist: true"), "capsules_mm.wrist", "expected a finite number > 0"),
    (_CAPS_LINE.replace("wrist: 90", "wrist: .inf"), "capsules_mm.wrist", "expected a finite number > 0"),
])
def test_malformed_capsules_name_the_key(tmp_path, line, key, reason):
    text = (DEFAULT_CELL.parent / "robots" / "MA2010.yaml").read_text()
    assert _CAPS_LINE in text
    bad = tmp_path / "bad.yaml"
    bad.write_text(text.replace(_CAPS_LINE, line))
    with pytest.raises(ConfigError) as e:
        load_robot(bad)
    assert e.value.key == key and reason in e.value.reason and e.value.path == str(bad)


# --- the controller's pulse convention in the robot YAML ---------------------------------------------------------

_SIGN_LINE = "pulse_sign: [1, 1, 1, 1, 1, 1]"
_ZERO_LINE = "pulse_zero: [0, 0, 0, 0, 0, 0]  # [pulses] at q = 0"


def test_pulse_convention_round_trips_and_follows_sign_and_zero(tmp_path):
    spec = load_robot(DEFAULT_CELL.parent / "robots" / "MA2010.yaml")
    np.testing.assert_array_equal(spec.pulse_sign, np.ones(6))
    np.testing.assert_array_equal(spec.pulse_zero, np.zeros(6))
    np.testing.assert_allclose(spec.pulses_per_rad[0], 1341.380023 * 180 / np.pi)
    pulses = np.random.default_rng(0).integers(-200000, 200000, (50, 6))
    np.testing.assert_array_equal(spec.to_pulses(spec.from_pulses(pulses)), pulses)
    text = (DEFAULT_CELL.parent / "robots" / "MA2010.yaml").read_text()
    other = tmp_path / "signed.yaml"
    other.write_text(text.replace(_SIGN_LINE, "pulse_sign: [1, -1, 1, 1, -1, 1]")
                     .replace(_ZERO_LINE, "pulse_zero: [0, 100, 0, 0, -7, 0]"))
    signed = load_robot(other)
    q = np.radians([[10.0, 20.0, -5.0, 0.0, 30.0, 1.0]])
    expected = np.rint(np.array([0, 100, 0, 0, -7, 0]) + np.array([1, -1, 1, 1, -1, 1]) * q * spec.pulses_per_rad)
    np.testing.assert_array_equal(signed.to_pulses(q), expected)
    np.testing.assert_allclose(signed.from_pulses(signed.to_pulses(q)), q, atol=1e-5)


@pytest.mark.parametrize("old, new, key, reason", [
    (_SIGN_LINE, "", "pulse_sign", "required key is missing"),
    (_SIGN_LINE, "pulse_sign: [1, 1, 0, 1, 1, 1]", "pulse_sign", "expected +1 or -1 per joint"),
    (_SIGN_LINE, "pulse_sign: [1, 1]", "pulse_sign", "expected shape (6,)"),
    (_ZERO_LINE, "pulse_zero: [0, 0.5, 0, 0, 0, 0]", "pulse_zero", "expected whole pulses"),
    (_ZERO_LINE, "pulse_zero: [0, zero, 0, 0, 0, 0]", "pulse_zero", "expected numbers of shape (6,)"),
])
def test_malformed_pulse_convention_names_the_key(tmp_path, old, new, key, reason):
    text = (DEFAULT_CELL.parent / "robots" / "MA2010.yaml").read_text()
    assert old in text
    bad = tmp_path / "bad.yaml"
    bad.write_text(text.replace(old, new))
    with pytest.raises(ConfigError) as e:
        load_robot(bad)
    assert e.value.key == key and reason in e.value.reason and e.value.path == str(bad)


@pytest.mark.parametrize("value", ["heavy", "'6'", "-1", ".nan", "true", "[6]"])
def test_payload_must_be_a_non_negative_number(tmp_path, value):
    text = (DEFAULT_CELL.parent / "robots" / "MA1440.yaml").read_text()
    assert "payload_kg: 6.0" in text
    bad = tmp_path / "bad.yaml"
    bad.write_text(text.replace("payload_kg: 6.0", f"payload_kg: {value}"))
    with pytest.raises(ConfigError) as e:
        load_robot(bad)
    assert e.value.key == "payload_kg" and "expected a finite number >= 0" in e.value.reason
    ok = tmp_path / "ok.yaml"
    ok.write_text(text.replace("payload_kg: 6.0", "payload_kg: 3"))
    assert load_robot(ok).payload_kg == 3.0
    assert load_robot(DEFAULT_CELL.parent / "robots" / "MA2010.yaml").payload_kg is None


# --- drawing geometry of what an arm carries (tool YAML `geometry`) ----------------------------------------------

_GEOM_LINE = "  - {name: barrel, shape: cylinder, from_mm: [0, 0, 40], to_mm: [0, 0, 230], radius_mm: 30}"


def test_tool_yaml_carries_its_drawing_geometry():
    from cell_config import load_tool

    gun = load_tool(DEFAULT_CELL.parent / "tools" / "weldgun_marker.yaml")
    barrel = {s.name: s for s in gun.shapes}["barrel"]
    assert barrel.kind == "cylinder" and barrel.radius_mm == (30.0, 30.0)
    np.testing.assert_array_equal(barrel.to_mm, [0, 0, 230])
    plate = {s.name: s for s in load_tool(DEFAULT_CELL.parent / "tools" / "mti_marker.yaml").shapes}["plate"]
    assert plate.kind == "box"
    np.testing.assert_array_equal(plate.size_mm, [250, 160, 8])


@pytest.mark.parametrize("line, key, reason", [
    (_GEOM_LINE.replace("cylinder", "cone"), "geometry[1].shape", "unknown shape 'cone'; valid: cylinder, box"),
    (_GEOM_LINE.replace("radius_mm: 30", "radius_mm: -30"), "geometry[1].radius_mm", "expected a finite number > 0"),
    (_GEOM_LINE.replace("radius_mm: 30", "radius_mm: [30, 0]"), "geometry[1].radius_mm", "expected radii > 0"),
    (_GEOM_LINE.replace("[0, 0, 230]", "[0, 0, 40]"), "geometry[1].to_mm", "non-zero length"),
    (_GEOM_LINE.replace("radius_mm: 30", "radius_mm: 30, colour: red"), "geometry[1].colour", "unknown key"),
    (_GEOM_LINE.replace("to_mm: [0, 0, 230]", "to_mm: [0, 230]"), "geometry[1].to_mm", "expected shape (3,)"),
    ("  - {name: plate, shape: box, centre_mm: [0, 0, 1], size_mm: [1, 0, 1]}", "geometry[1].size_mm",
     "expected positive edge lengths"),
    ("  - barrel", "geometry[1]", "expected a mapping"),
])
def test_malformed_tool_geometry_names_the_key(tmp_path, line, key, reason):
    from cell_config import load_tool

    text = (DEFAULT_CELL.parent / "tools" / "weldgun_marker.yaml").read_text()
    assert _GEOM_LINE in text
    bad = tmp_path / "bad.yaml"
    bad.write_text(text.replace(_GEOM_LINE, line))
    with pytest.raises(ConfigError) as e:
        load_tool(bad)
    assert e.value.key == key and reason in e.value.reason and e.value.path == str(bad)


def test_the_cli_refuses_an_unknown_top_level_key_in_one_line(tmp_path, capsys):
    from tests.conftest import assert_bad_input

    path = _copy_cell(tmp_path, lambda d: d.__setitem__("registraton", "reg.yaml"))
    out = tmp_path / "plan.json"
    assert_bad_input(capsys, ["--cell", str(path), "plan", "--robot", "R1", "--out", str(out)], str(path),
                     "registraton", "valid keys: name, robots")
    assert not out.exists()


@pytest.mark.parametrize("kind, name, extra, key", [
    ("robots", "MA2010.yaml", "pulse_zeros: [0, 0, 0, 0, 0, 0]\n", "pulse_zeros"),  # a misspelt convention
    ("robots", "MA1440.yaml", "base_height: 450\n", "base_height"),  # the unit left out of the name
    ("robots", "MA2010.yaml", None, "joint_limits_deg.lowr"),  # a misspelt limit under its block
    ("tools", "weldgun_marker.yaml", "positon_mm: [0, 0, 0]\n", "positon_mm"),
    ("tools", "mti_marker.yaml", "quaternion_xyzw: [0, 0, 0, 1]\n", "quaternion_xyzw"),
])
def test_robot_and_tool_yaml_refuse_an_unknown_key(tmp_path, kind, name, extra, key):
    """A robot or tool YAML ignored keys it did not know: a misspelt ``pulse_zeros`` left the pulse convention at its
    default with no word (the cell file refused its own misspelt keys). Every key of the packaged files is known."""
    from cell_config import load_tool
    from cell_config.loader import ROBOT_KEYS, TOOL_KEYS

    text = (DEFAULT_CELL.parent / kind / name).read_text()
    load = load_robot if kind == "robots" else load_tool
    assert set(yaml.safe_load(text)) <= set(ROBOT_KEYS if kind == "robots" else TOOL_KEYS)
    bad = tmp_path / name
    bad.write_text(text + extra if extra else text.replace("  lower:", "  lowr:"))
    with pytest.raises(ConfigError) as e:
        load(bad)
    assert e.value.key == key and "unknown key" in e.value.reason and "valid keys:" in e.value.reason
    assert e.value.path == str(bad) and "\n" not in str(e.value)


@pytest.mark.parametrize("name", ["R1", "R2"])
def test_a_cell_robots_arm_is_its_yaml(name):
    """CellRobot.arm(): the name in the cell, the nominal model with the tool, the YAML's limits and link masses."""
    from calibration.physics.gravity import GravityModel

    robot = load_cell().robot(name)
    arm = robot.arm()
    assert (arm.name, arm.model_name) == (name, robot.robot.name)
    q = np.random.default_rng(0).uniform(-1.0, 1.0, (10, 6))
    for got, want in zip(arm.nominal.fk(q), robot.model().fk(q)):
        np.testing.assert_array_equal(got, want)
    assert arm.joint_limits_rad is not None
    np.testing.assert_array_equal(arm.joint_limits_rad[0], robot.robot.lower_rad)
    np.testing.assert_array_equal(arm.joint_limits_rad[1], robot.robot.upper_rad)
    np.testing.assert_array_equal(arm.link_mass_kg, [link.mass_kg for link in robot.robot.links])
    np.testing.assert_array_equal(arm.gravity().lumped, GravityModel.from_spec(robot.robot, robot.model()).lumped)


def test_a_robot_yaml_without_links_gives_an_arm_without_masses():
    from dataclasses import replace

    from calibration.errors import ModelError
    from calibration.physics.gravity import GravityModel

    robot = load_cell().robot("R1")
    bare = replace(robot, robot=replace(robot.robot, links=()))
    arm = bare.arm()
    assert arm.link_mass_kg is None and arm.link_com_mm is None
    with pytest.raises(ModelError) as got:  # what GravityModel.from_spec says, word for word
        arm.gravity()
    with pytest.raises(ModelError) as want:
        GravityModel.from_spec(bare.robot, bare.model())
    assert str(got.value) == str(want.value) and "MA2010" in str(got.value)
