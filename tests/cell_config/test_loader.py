import numpy as np
import pytest
import yaml

from calibration.errors import ConfigError
from cell_config import DEFAULT_CELL, load_cell, load_robot


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
    with pytest.raises(ConfigError, match="file not found"):
        load_robot(tmp_path / "missing.yaml")
