"""A data set that never moves the wrist cannot see wrist parameters; fits must hold them."""

import numpy as np

from calibration.identification import GeometricProblem
from calibration.identification.observability import analyse
from calibration.kinematics.poe import pose_error
from tests.conftest import cluster_design, measure


def test_hidden_wrist_directions_are_reported_and_held(synthetic_arm):
    par, _, truth = synthetic_arm
    q, cluster = cluster_design(step_deg=15.0, spread_wrist=False)  # joints 1, 4, 5, 6 stay near 1 deg

    def sagging_truth(q):  # geometry plus a gravity-like sag the geometric model cannot represent
        sag = np.zeros_like(q)
        sag[:, 1] = 3e-4 * np.cos(q[:, 1])
        sag[:, 2] = 3e-4 * np.cos(q[:, 1] + q[:, 2])
        return truth.fk(q + sag)

    rec = measure(sagging_truth, q, noise_mm=0.03, noise_deg=0.02, seed=5, cluster=cluster)
    free = analyse(par, q, tolerance=0.0)
    held = analyse(par, q)
    assert held.rank < par.size
    assert free.condition_number > 1e3
    text = held.summary()
    assert "cannot see" in text and "joints" in text
    assert set(held.hidden_joints()) & {4, 5, 6}
    assert len(held.unobservable()) == par.size - held.rank
    # Holding the hidden directions keeps the fit better than nominal under wide wrist motion. (Whether a
    # free fit would be worse depends on the data: on the real R1 set it is, see tests/app/workflows/test_real_data.py.)
    q_wide = np.random.default_rng(2).uniform(-1.0, 1.0, (400, 6))
    x_held = GeometricProblem(par, q, rec.R, rec.p, basis=held.basis).solve().x[0]
    err_held = pose_error(*sagging_truth(q_wide), *par.model(x_held).fk(q_wide))[0]
    err_nominal = pose_error(*sagging_truth(q_wide), *par.nominal.fk(q_wide))[0]
    assert err_held.mean() < err_nominal.mean()
    assert err_held.max() < err_nominal.max()


def test_full_design_is_well_conditioned(synthetic_arm):
    par, _, _ = synthetic_arm
    q, _ = cluster_design(step_deg=15.0, spread_wrist=True)
    obs = analyse(par, q)
    assert obs.rank == par.size
    assert obs.summary() == ""
    np.testing.assert_allclose(obs.basis.shape, (par.size, par.size))
