"""``cellcal export-urdf``: the written URDF, read by pinocchio, reproduces the saved model's kinematics; the
command says what a URDF cannot hold; bad input is one line, exit 2, nothing written."""

from __future__ import annotations

import json

import numpy as np
import pytest

from app.cli.commands import build_parser, main
from calibration.kinematics.parameterisation import MinimalParameterisation
from calibration.models import ConstantModel, load_model, save_model
from calibration.models.pi import PhysicsInformedModel
from calibration.physics.extended import ExtendedKinematics
from cell_config import load_cell
from tests.calibration.models.test_urdf import (
    N_POSES,
    POSITION_TOL_MM,
    ROTATION_TOL_RAD,
    differences,
    random_q,
    urdf_fk,
)
from tests.conftest import assert_bad_input, planted_parameters

pytest.importorskip("pinocchio")


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    root = tmp_path_factory.mktemp("urdf_models")
    for robot in ("R1", "R2"):
        par = MinimalParameterisation(load_cell().robot(robot).model(), fit_tool=True)
        save_model(ConstantModel(robot, "nls1", par.model(planted_parameters(par)), par.size), root / f"{robot}.yaml")
    par = MinimalParameterisation(load_cell().robot("R1").model(), fit_tool=True)
    kin = ExtendedKinematics(par)
    theta = np.random.default_rng(3).normal(size=kin.size) * kin.scale() * 0.5
    save_model(PhysicsInformedModel("R1", "pi", kin, theta, kin.size), root / "pi.yaml")
    return root


@pytest.mark.parametrize("robot", ["R1", "R2"])
def test_export_urdf_reproduces_the_saved_model(models, robot, tmp_path, capsys):
    out, js = tmp_path / "robot.urdf", tmp_path / "export.json"
    assert main(["export-urdf", "--model", str(models / f"{robot}.yaml"), "--out", str(out), "--json", str(js)]) == 0
    stdout = capsys.readouterr().out
    assert "constant nls1 model of " + robot in stdout and "lost: nothing" in stdout
    report = json.loads(js.read_text())
    assert report["robot"] == robot and report["lost"] == [] and report["tool_link"] == "tool_marker"
    assert report["joints"] == ["joint_1_s", "joint_2_l", "joint_3_u", "joint_4_r", "joint_5_b", "joint_6_t"]
    assert report["base_height_mm"] == load_cell().robot(robot).robot.base_height_mm
    q = random_q(robot, seed=2)
    dp, dR = differences(*urdf_fk(out.read_text(), q), *load_model(models / f"{robot}.yaml").fk(q))
    print(f"\ncellcal export-urdf {robot} nls1 (planted), {N_POSES} poses: max position {dp:.3e} mm, "
          f"max rotation {dR:.3e} rad")
    assert dp <= POSITION_TOL_MM and dR <= ROTATION_TOL_RAD


def test_export_urdf_of_pi_says_what_is_lost(models, tmp_path, capsys):
    out, js = tmp_path / "pi.urdf", tmp_path / "pi.json"
    assert main(["export-urdf", "--model", str(models / "pi.yaml"), "--out", str(out), "--json", str(js)]) == 0
    stdout = capsys.readouterr().out
    assert stdout.startswith("pi model of R1: exported ")  # it said "pi pi model of R1"
    assert "27-parameter geometry block and the tool rotation" in stdout
    assert "lost: the gravity compliance" in stdout and "lost: the structural deflection" in stdout
    assert len(json.loads(js.read_text())["lost"]) == 2
    assert "Lost: the gravity compliance" in out.read_text()


def test_export_urdf_of_another_robots_model_exits_2_and_writes_nothing(models, tmp_path, capsys):
    out = tmp_path / "robot.urdf"
    assert_bad_input(capsys, ["export-urdf", "--model", str(models / "R2.yaml"), "--robot", "R1", "--out", str(out)],
                     "R2.yaml")
    assert not out.exists()


def test_export_urdf_of_a_missing_model_exits_2_and_writes_nothing(tmp_path, capsys):
    out = tmp_path / "robot.urdf"
    assert_bad_input(capsys, ["export-urdf", "--model", str(tmp_path / "none.yaml"), "--out", str(out)],
                     "none.yaml", "not found")
    assert not out.exists()


def test_export_urdf_options_all_have_help():
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command").choices["export-urdf"]
    options = [a for a in sub._actions if a.dest != "help"]
    assert {a.dest for a in options} >= {"model", "robot", "out", "json"}
    assert all(a.help for a in options), [a.dest for a in options if not a.help]


def test_export_urdf_writes_the_xacro_and_meshes(models, tmp_path, capsys):
    out, xacro = tmp_path / "r1.urdf", tmp_path / "r1_calibration.xacro"
    uri = "package://motoman_ma2010_support/meshes/ma2010"
    assert main(["export-urdf", "--model", str(models / "R1.yaml"), "--out", str(out), "--xacro", str(xacro),
                 "--meshes", uri]) == 0
    assert "xacro macro cellcal_ma2010 (prefix parameter) -> " in capsys.readouterr().out
    text = xacro.read_text()
    assert '<xacro:macro name="cellcal_ma2010" params="prefix">' in text
    assert 'name="${prefix}joint_1_s"' in text and f'filename="{uri}/visual/link_1_s.stl"' in text
    assert f'filename="{uri}/collision/base_link.stl"' in out.read_text()


def test_export_urdf_with_a_bad_mesh_uri_exits_2_and_writes_neither_file(models, tmp_path, capsys):
    out, xacro = tmp_path / "r1.urdf", tmp_path / "r1.xacro"
    assert_bad_input(capsys, ["export-urdf", "--model", str(models / "R1.yaml"), "--out", str(out), "--xacro",
                              str(xacro), "--meshes", "meshes/ma2010"], "meshes/ma2010", "not a URI")
    assert not out.exists() and not xacro.exists()


def test_export_urdf_refuses_the_xacro_on_the_urdf(models, tmp_path, capsys):
    out = tmp_path / "r1.urdf"
    assert_bad_input(capsys, ["export-urdf", "--model", str(models / "R1.yaml"), "--out", str(out), "--xacro",
                              str(out)], "--xacro")
    assert not out.exists()


@pytest.mark.parametrize("macro", ["my macro", 'a"b', "a<b&c>", "", "1abc", "ns:name"])
def test_a_macro_name_xacro_cannot_call_is_refused_and_nothing_written(models, tmp_path, capsys, macro):
    out, xacro = tmp_path / "r1.urdf", tmp_path / "r1.xacro"
    assert_bad_input(capsys, ["export-urdf", "--model", str(models / "R1.yaml"), "--out", str(out), "--xacro",
                              str(xacro), "--macro", macro], "--macro", repr(macro))
    assert not out.exists() and not xacro.exists()


def test_macro_without_xacro_is_refused(models, tmp_path, capsys):
    out = tmp_path / "r1.urdf"
    assert_bad_input(capsys, ["export-urdf", "--model", str(models / "R1.yaml"), "--out", str(out), "--macro",
                              "abc"], "--macro", "--xacro")
    assert not out.exists()
