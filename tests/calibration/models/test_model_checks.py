"""Model files are checked when loaded: finite numbers, rotations, robot, method, each kind's own blocks."""

import json

import numpy as np
import pytest
import yaml

from calibration.errors import DataError, ModelFileError
from calibration.interpolation.fourier import Fourier13Interpolator
from calibration.kinematics.parameterisation import MinimalParameterisation
from calibration.methods.cdc import geometric_cdc
from calibration.models import ConstantModel, load_model, save_model
from calibration.models.cdc import CdcModel
from calibration.models.checks import known_methods
from calibration.models.pi import PhysicsInformedModel
from calibration.physics.extended import ExtendedKinematics
from cell_config import load_cell


@pytest.fixture
def constant_file(tmp_path, r1_nominal):
    path = tmp_path / "r1.yaml"
    save_model(ConstantModel("R1", "nls1", r1_nominal, 27, {}), path)
    return path


def _edit(path, change):
    data = yaml.safe_load(path.read_text())
    change(data)
    out = path.with_name("edited" + path.suffix)
    out.write_text(json.dumps(data) if path.suffix == ".json" else yaml.safe_dump(data))
    return out


def _refused(path, key, *fragments):
    with pytest.raises(ModelFileError) as e:
        load_model(path)
    assert e.value.path == str(path) and e.value.key == key, str(e.value)
    for f in fragments:
        assert f in str(e.value), str(e.value)
    assert len(str(e.value).splitlines()) == 1
    return e.value


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_a_number_that_is_not_finite_is_refused_naming_its_key(constant_file, bad):
    def plant(d):
        d["geometry"]["P"][3][0] = bad
    _refused(_edit(constant_file, plant), "geometry.P[3][0]", "expected a finite number", str(bad))


def test_nan_written_by_json_is_refused_too(tmp_path, r1_nominal):
    path = tmp_path / "m.json"
    save_model(ConstantModel("R1", "nls1", r1_nominal, 27, {}), path)
    data = json.loads(path.read_text())
    data["info"] = {"fit_seconds": float("nan")}
    path.write_text(json.dumps(data))  # json writes the literal NaN
    assert "NaN" in path.read_text()
    _refused(path, "info.fit_seconds", "expected a finite number, got nan")


def test_a_matrix_that_is_not_a_rotation_is_refused(constant_file):
    def stretch(d):
        d["geometry"]["R_flange"][0] = [0.0, 0.0, 1.1]
    _refused(_edit(constant_file, stretch), "geometry.R_flange", "not a rotation", "orthonormal")

    def reflect(d):
        d["geometry"]["R_flange_tool"] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]]
    _refused(_edit(constant_file, reflect), "geometry.R_flange_tool", "determinant -1")

    def flat(d):
        d["geometry"]["R_flange"] = [1.0, 0.0, 0.0]
    _refused(_edit(constant_file, flat), "geometry.R_flange", "expected a 3x3 rotation matrix")


def test_unknown_method_lists_the_valid_ones_and_missing_robot_is_refused(constant_file):
    e = _refused(_edit(constant_file, lambda d: d.update(method="spline")), "method", "unknown method 'spline'")
    assert "valid: " + ", ".join(known_methods()) in str(e)
    assert {"nls1", "fbf13", "pi", "diagnose"} <= set(known_methods())
    _refused(_edit(constant_file, lambda d: d.pop("robot")), "robot", "expected the name of the robot")


def test_a_model_of_another_robot_is_refused_by_name_and_by_geometry(constant_file):
    cell = load_cell()
    assert load_model(constant_file, "R1", cell.robot("R1").model()).robot == "R1"
    _refused_for = pytest.raises(ModelFileError, match="the model is for R1, not R2")
    with _refused_for:
        load_model(constant_file, "R2", cell.robot("R2").model())
    relabelled = _edit(constant_file, lambda d: d.update(robot="R2"))  # MA2010 geometry named R2 (an MA1440)
    assert load_model(relabelled, "R2").robot == "R2"  # without the robot YAML the name is all there is
    with pytest.raises(ModelFileError, match=r"not R2's geometry: link vector P\[3\] differs from the robot YAML's by 442 mm") as e:
        load_model(relabelled, "R2", cell.robot("R2").model())
    assert e.value.key == "geometry"


def test_save_refuses_a_model_the_loader_would_refuse_and_writes_nothing(tmp_path, r1_nominal):
    bad = ConstantModel("R1", "nls1", r1_nominal.with_geometry(r1_nominal.H, r1_nominal.P * np.nan), 27, {})
    with pytest.raises(ModelFileError, match="geometry.P.*expected a finite number"):
        save_model(bad, tmp_path / "m.yaml")
    assert not (tmp_path / "m.yaml").exists() and list(tmp_path.iterdir()) == []


@pytest.fixture
def cdc_file(tmp_path, r1_nominal):
    par = MinimalParameterisation(r1_nominal)
    rng = np.random.default_rng(2)
    x = rng.uniform(-1.0, 1.0, (30, 2))
    y = np.column_stack([0.2 * np.sin(x[:, 0] + k) for k in range(par.size)])
    path = tmp_path / "cdc.yaml"
    save_model(CdcModel("R1", "fbf13", *geometric_cdc(par), Fourier13Interpolator().fit(x, y)), path)
    return path


@pytest.mark.parametrize("inputs, fragment", [("q2", "expected distinct joint indices 0..5"),
                                              ([1, 9], "expected distinct joint indices"),
                                              ([1, 1], "expected distinct joint indices"),
                                              ([1.5, 2], "expected distinct joint indices"),
                                              ([2], "the interpolator takes 2 inputs, the list names 1")])
def test_cdc_with_malformed_inputs_is_refused(cdc_file, inputs, fragment):
    _refused(_edit(cdc_file, lambda d: d.update(inputs=inputs)), "inputs", fragment)


def test_cdc_with_a_short_theta_ref_and_pi_with_a_short_theta_are_refused(cdc_file, tmp_path, r1_nominal):
    n = len(yaml.safe_load(cdc_file.read_text())["theta_ref"])
    _refused(_edit(cdc_file, lambda d: d.update(theta_ref=d["theta_ref"][:5])), "theta_ref",
             f"expected a list of {n} numbers, got 5 entries")
    kin = ExtendedKinematics(MinimalParameterisation(r1_nominal, True))
    pi = tmp_path / "pi.json"
    save_model(PhysicsInformedModel("R1", "pi", kin, np.zeros(kin.size), kin.size), pi)
    _refused(_edit(pi, lambda d: d.update(theta=d["theta"][:-1])), "theta",
             f"expected a list of {kin.size} numbers, got {kin.size - 1} entries")


def test_binary_files_and_folders_are_one_line_errors(tmp_path):
    binary = tmp_path / "m.yaml"
    binary.write_bytes(b"\x89PNG\r\n\x1a\n\x00\xff\xfe")
    with pytest.raises(DataError, match="m.yaml: not a model file .binary content"):
        load_model(binary)
    folder = tmp_path / "folder.yaml"
    folder.mkdir()
    with pytest.raises(DataError, match="folder.yaml: is a folder, not a model file"):
        load_model(folder)


def test_a_tilted_axis_beyond_the_tolerance_is_another_geometry(constant_file):
    from calibration.kinematics import so3

    def tilt(d):
        H = np.array(d["geometry"]["H"])
        H[1] = so3.rot(np.array([1.0, 0.0, 0.0]), np.radians(10)) @ H[1]
        d["geometry"]["H"] = H.tolist()
    with pytest.raises(ModelFileError, match="joint 2's axis differs from the robot YAML's by 10.0 deg"):
        load_model(_edit(constant_file, tilt), "R1", load_cell().robot("R1").model())
