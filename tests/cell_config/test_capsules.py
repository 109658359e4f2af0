"""The one capsule model: radii from the robot YAMLs, the same capsules for safety, planner and preview."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from app.collection.safety import CellSafety, SafetyConfig
from calibration.errors import ConfigError
from cell_config import DEFAULT_CELL, load_cell
from cell_config.capsules import (
    DEFAULT_FLOOR_Z_MM,
    FLOOR_CHECKED,
    PROCESS_ZONE,
    SEGMENTS,
    SPANS,
    CellCapsules,
    pairs_outside,
    segment_distance,
    segment_distance_casadi,
)
from cell_config.loader import CAPSULE_SEGMENTS


@pytest.fixture(scope="module")
def cell():
    return load_cell()


def _random_q(cell, name, n, seed):
    spec = cell.robot(name).robot
    return np.random.default_rng(seed).uniform(spec.lower_rad, spec.upper_rad, (n, 6))


def test_every_yaml_segment_has_a_span_and_radii_come_from_the_robot_yaml(cell):
    assert SEGMENTS == CAPSULE_SEGMENTS and set(SPANS) == set(SEGMENTS)
    caps = CellCapsules(cell)
    for name, robot in cell.robots.items():
        np.testing.assert_array_equal(caps.radii(name), [robot.robot.capsules_mm[s] for s in SEGMENTS])
    assert cell.robot("R1").robot.capsules_mm == {"base": 220, "shoulder": 180, "upper_arm": 140, "forearm": 110,
                                                  "wrist": 90, "tool": 50}


@pytest.mark.parametrize("name", ["R1", "R2"])
def test_capsules_span_the_skeleton_points(cell, name):
    caps = CellCapsules(cell)
    q = _random_q(cell, name, 20, 1)
    segs = caps.segments(name, q)
    assert segs.shape == (20, len(SEGMENTS), 2, 3)
    r = cell.robot(name)
    chain = r.model().chain(q)
    to_cell = lambda p: p @ r.T_cell_base[:3, :3].T + r.T_cell_base[:3, 3]  # noqa: E731
    origins = to_cell(np.moveaxis(chain.p_base_origin, 0, 1))  # (N, 7, 3)
    k = SEGMENTS.index
    # the column stands on the floor (along the base z axis: R2's base is tilted by ~3 mrad, 2 um off at the foot)
    np.testing.assert_allclose(segs[:, k("base"), 0, 2], DEFAULT_FLOOR_Z_MM, atol=1e-2)
    np.testing.assert_allclose(segs[:, k("base"), 1], origins[:, 0], atol=1e-9)
    np.testing.assert_allclose(segs[:, k("upper_arm")], origins[:, [1, 2]], atol=1e-9)
    np.testing.assert_allclose(segs[:, k("wrist"), 1], origins[:, 6], atol=1e-9)  # the flange
    np.testing.assert_allclose(segs[:, k("tool"), 1], to_cell(chain.p_base_tool), atol=1e-9)
    for i in range(len(SEGMENTS) - 1):  # a connected chain from the floor to the tool
        np.testing.assert_allclose(segs[:, i, 1], segs[:, i + 1, 0], atol=1e-9)


@pytest.mark.parametrize("name", ["R1", "R2"])
def test_casadi_capsules_are_the_numpy_capsules(cell, name):
    ca = pytest.importorskip("casadi")
    from app.dual.casadi_kinematics import casadi_fk

    caps = CellCapsules(cell)
    fk = casadi_fk(cell.robot(name).model())
    T = cell.robot(name).T_cell_base
    qs = ca.SX.sym("q", 6)
    _, p, O, _ = fk.function(qs, ca.SX.sym("x", 0))
    Rb, pb = ca.DM(T[:3, :3]), ca.DM(T[:3, 3])
    sym = caps.casadi_segments(ca, name, Rb @ O + ca.repmat(pb, 1, O.shape[1]), Rb @ p + pb)
    f = ca.Function("caps", [qs], [ca.horzcat(*[ca.horzcat(*sym[s]) for s in SEGMENTS])])
    for q in _random_q(cell, name, 5, 2):
        got = np.array(f(q)).T.reshape(len(SEGMENTS), 2, 3)
        np.testing.assert_allclose(got, caps.segments(name, q)[0], atol=1e-8)


def test_casadi_segment_distance_matches_numpy():
    ca = pytest.importorskip("casadi")
    x = ca.SX.sym("x", 12)
    f = ca.Function("d", [x], [segment_distance_casadi(ca, x[0:3], x[3:6], x[6:9], x[9:12])])
    rng = np.random.default_rng(3)
    for v in rng.normal(scale=500.0, size=(200, 12)):
        np.testing.assert_allclose(float(f(v)), segment_distance(v[0:3], v[3:6], v[6:9], v[9:12]), atol=1e-5)


def test_planner_clearances_are_the_safety_gaps(cell):
    pytest.importorskip("casadi")
    from app.dual.paths import Q_REF_DEG, relative_pose
    from app.dual.planner import DualPlanner, PlannerOptions

    planner = DualPlanner(cell, options=PlannerOptions(compile="off"))
    assert planner.options.pairs == pairs_outside(PROCESS_ZONE)
    assert len(planner.options.pairs) == len(SEGMENTS) ** 2 - len(PROCESS_ZONE) ** 2
    assert not {("wrist", "tool"), ("tool", "tool")} & set(planner.options.pairs)
    safety = CellSafety(cell)
    idx = [(SEGMENTS.index(a), SEGMENTS.index(b)) for a, b in planner.options.pairs]
    rng = np.random.default_rng(4)
    for dq in rng.normal(scale=0.2, size=(4, 12)):
        q = np.radians(Q_REF_DEG) + dq
        c = planner.evaluate(q, relative_pose(planner, q), np.eye(4))["c"]
        gaps = safety.capsule_model.gaps("R1", safety.capsules("R1", q[:6]), "R2", safety.capsules("R2", q[6:])[0])[0]
        np.testing.assert_allclose(c, [gaps[i, j] for i, j in idx], atol=1e-5)


def test_a_radius_changed_in_the_robot_yaml_moves_every_check(cell, tmp_path):
    """The robot YAML is the one source: +30 mm on R2's forearm shrinks safety's and the planner's gaps by 30 mm."""
    data = yaml.safe_load(DEFAULT_CELL.read_text())
    for name in data["robots"]:
        data["robots"][name]["tool"] = str(DEFAULT_CELL.parent / data["robots"][name]["tool"])
        data["robots"][name]["robot"] = str(DEFAULT_CELL.parent / data["robots"][name]["robot"])
    robot = yaml.safe_load((DEFAULT_CELL.parent / "robots/MA1440.yaml").read_text())
    robot["capsules_mm"]["forearm"] += 30.0
    (tmp_path / "MA1440.yaml").write_text(yaml.safe_dump(robot))
    data["robots"]["R2"]["robot"] = str(tmp_path / "MA1440.yaml")
    (tmp_path / "cell.yaml").write_text(yaml.safe_dump(data))
    fat = load_cell(tmp_path / "cell.yaml")
    q1, q2 = np.radians([-10, 70, 60, 0, 0, 0]), np.radians([0, 40, 0, 0, 0, 0])
    gaps = {}
    for c in (cell, fat):
        s = CellSafety(c)
        gaps[c.name if c is cell else "fat"] = s.capsule_model.gaps("R1", s.capsules("R1", q1), "R2", s.capsules("R2", q2)[0])
    delta = gaps["motoman_cell"] - gaps["fat"]
    k = SEGMENTS.index("forearm")
    np.testing.assert_allclose(delta[0, :, k], 30.0, atol=1e-9)
    np.testing.assert_allclose(np.delete(delta[0], k, axis=1), 0.0, atol=1e-9)


def test_preview_draws_the_capsule_radii(cell, tmp_path, monkeypatch):
    pytest.importorskip("meshcat")
    import umsgpack

    import app.dual.preview.page as preview_mod

    windows = []

    class Recording(preview_mod.RecordingWindow):
        def __init__(self):
            super().__init__()
            windows.append(self)

    monkeypatch.setattr(preview_mod, "RecordingWindow", Recording)
    plan = {"schema": "cellcal.plan/1", "kind": "dual",
            "waypoints": [{"R1": [0.0] * 6, "R2": [0.0] * 6}, {"R1": [0.1] * 6, "R2": [-0.1] * 6}]}
    preview_mod.preview(cell, plan, html_out=tmp_path / "p.html")
    caps = CellCapsules(cell)
    segs = {n: caps.segments(n, np.zeros(6))[0] for n in ("R1", "R2")}
    for name in ("R1", "R2"):
        for k, seg in enumerate(SEGMENTS):
            node = windows[0].nodes[f"/meshcat/cellcal/{name}/capsules/{seg}"]
            geom = umsgpack.unpackb(node["object"])["object"]["geometries"][0]
            assert geom["type"] == "CylinderGeometry"
            assert geom["radiusTop"] == pytest.approx(caps.radii(name)[k] * 1e-3)
            assert geom["height"] == pytest.approx(np.linalg.norm(segs[name][k, 1] - segs[name][k, 0]) * 1e-3)


def test_floor_checks_and_a_floor_above_a_base_is_refused(cell):
    caps = CellCapsules(cell)
    segs = caps.segments("R1", np.zeros(6))
    gaps = caps.floor_gaps("R1", segs)
    assert gaps.shape == (1, len(FLOOR_CHECKED)) and np.all(gaps > 0)
    with pytest.raises(ConfigError, match="is not below R1's base"):
        CellSafety(cell, SafetyConfig(floor_z_mm=10.0))
