"""Contact validation on the simulated cell, and the physics model's casadi path it plans with."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("casadi")
pytest.importorskip("can")

from app.dual.sim import TrainingGrid, fit_model_sets, make_twins  # noqa: E402
from app.dual.validate import DeviationStats, relative_position, run_sim_validation  # noqa: E402
from calibration.errors import ModelError  # noqa: E402
from cell_config.loader import load_cell  # noqa: E402

FAST = TrainingGrid(grid_step_deg=15.0)


@pytest.fixture(scope="module")
def cell():
    return load_cell()


@pytest.fixture(scope="module")
def result(cell):
    return run_sim_validation(cell, 4, methods=("nominal", "cpa", "fbf13", "pi"), grid=FAST,
                              channel="test-validate-dual")


def test_calibrated_sets_are_closer_to_contact_than_nominal(result):
    assert result.configurations == 4 and result.unconfirmed == 0
    assert list(result.models) == ["nominal", "cpa", "fbf13", "pi"]
    nominal = result.models["nominal"].mean_mm
    assert result.models["fbf13"].mean_mm < nominal
    assert result.models["pi"].mean_mm < 0.5 * nominal
    assert result.truth.max_mm <= 0.1  # the probe confirmed contact within its tolerance
    for s in result.models.values():
        assert 0 <= s.std_mm <= s.max_mm and s.mean_mm <= s.max_mm
    js = result.to_json()
    assert set(js["models"]["nominal"]) == {"mean_mm", "std_mm", "max_mm"} and js["configurations"] == 4
    assert "nominal" in result.table() and "pi" in result.table()


def test_relative_position_is_the_gun_point_in_the_workpiece_frame(cell):
    twins = make_twins(cell)
    q = np.radians([[0, 15, 5, 0, 30, 0, 0, 0, 0, 0, -30, 0]])
    p = relative_position(cell, twins["R1"].pose, twins["R2"].pose, q)
    R1, p1 = twins["R1"].pose(q[:, :6])
    R2, p2 = twins["R2"].pose(q[:, 6:])
    T = [cell.robot(n).T_cell_base for n in ("R1", "R2")]
    T1, T2 = np.eye(4), np.eye(4)
    T1[:3, :3], T1[:3, 3] = T[0][:3, :3] @ R1[0], T[0][:3, :3] @ p1[0] + T[0][:3, 3]
    T2[:3, :3], T2[:3, 3] = T[1][:3, :3] @ R2[0], T[1][:3, :3] @ p2[0] + T[1][:3, 3]
    np.testing.assert_allclose(p[0], (np.linalg.inv(T2) @ T1)[:3, 3], atol=1e-9)
    with pytest.raises(ModelError, match=r"\(N, 12\)"):
        relative_position(cell, twins["R1"].pose, twins["R2"].pose, np.zeros((2, 6)))


def test_physics_model_plans_through_its_exact_expression(cell):
    from app.dual.casadi_kinematics import casadi_fk
    from calibration.models.physics import PhysicsModel

    twin = make_twins(cell)["R1"]
    model = PhysicsModel("R1", "twin", twin.geometry, twin.effects)
    fk = casadi_fk(model)
    assert fk.kind == "physics" and fk.n_frozen == 0 and not fk.frozen  # the deflection is a function of q
    q = np.radians([5.0, 20.0, -10.0, 3.0, 25.0, -4.0])
    R, p, _, _ = fk.function(q, fk.x0(q))
    R_np, p_np = model.fk(q[None])
    np.testing.assert_allclose(np.asarray(p).ravel(), p_np[0], atol=1e-9)
    np.testing.assert_allclose(np.asarray(R), R_np[0], atol=1e-12)


def test_bad_requests(cell):
    with pytest.raises(ModelError, match="at least 2"):
        run_sim_validation(cell, 1)
    with pytest.raises(ModelError, match="unknown model set 'bogus'; valid: .*fbf13.*pi"):
        fit_model_sets(cell, make_twins(cell), ("bogus",), grid=FAST)
    assert DeviationStats.of(np.array([1.0, 3.0])) == DeviationStats(2.0, 1.0, 3.0)
