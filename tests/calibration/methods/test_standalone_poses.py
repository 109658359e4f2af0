"""Stand-alone training poses (``--add``, :func:`calibration.data.recording.with_added`): global fits use them, local
(per-cluster) fits never group them into a cluster, and every method keeps working with them."""

import numpy as np
import pytest

from calibration.data.recording import STANDALONE, Recording, standalone_mask, with_added
from calibration.evaluation.metrics import errors
from calibration.methods.cdc import cluster_anchors, fit_local
from calibration.methods.fitter import Fitter
from calibration.methods.options import FitOptions
from tests.conftest import cluster_design, measure


def wide_poses(n: int, seed: int = 5) -> np.ndarray:
    """``n`` configurations far from the cluster design's still wrist: q1 and q4..q6 over +-60 deg."""
    rng = np.random.default_rng(seed)
    q = rng.uniform(np.radians(-60), np.radians(60), (n, 6))
    q[:, 1] = rng.uniform(np.radians(-30), np.radians(30), n)
    q[:, 2] = rng.uniform(np.radians(-30), np.radians(20), n)
    return q


@pytest.fixture(scope="module")
def grid_and_wide(synthetic_arm):
    """A 7-row-block training grid without a cluster column (still wrist) and 21 wide poses of the same arm."""
    _, _, truth = synthetic_arm
    q, _ = cluster_design(step_deg=15.0, spread_wrist=False)
    grid = measure(truth.fk, q, 0.02, 0.01, 1)  # no cluster column: consecutive 7-row blocks
    wide = measure(truth.fk, wide_poses(21), 0.02, 0.01, 2)
    test = measure(truth.fk, wide_poses(60, seed=9), 0.0, 0.0, 3)
    return grid, wide, test


@pytest.mark.parametrize("n_added", [1, 6, 7, 8, 14, 21])
def test_added_poses_are_never_grouped_into_clusters(grid_and_wide, n_added):
    grid, wide, _ = grid_and_wide
    both = with_added(grid, [wide.subset(np.arange(n_added))])
    ids = both.clusters()
    n_grid = len(np.unique(grid.clusters()))
    np.testing.assert_array_equal(ids[: len(grid)], grid.clusters())  # the grid's clusters as they were
    assert len(np.unique(ids)) == n_grid + n_added  # each added pose a unit of its own
    assert standalone_mask(both).sum() == n_added and not standalone_mask(both)[: len(grid)].any()
    np.testing.assert_array_equal(both.extra["cluster"][len(grid):], STANDALONE - np.arange(n_added))


@pytest.mark.parametrize("weight", [1, 3, 7])
def test_a_weighted_pose_is_repeated_under_one_id_and_stays_one_unit(grid_and_wide, weight):
    grid, wide, _ = grid_and_wide
    once = with_added(grid, [wide.subset(np.arange(5))])
    both = with_added(once, [wide.subset(np.arange(5, 9))], weight=weight)  # added to a recording holding some
    assert len(both) == len(grid) + 5 + 4 * weight
    ids = both.clusters()
    assert len(np.unique(ids)) == len(np.unique(grid.clusters())) + 5 + 4
    tail = both.extra["cluster"][len(grid) + 5:]
    assert len(np.unique(tail)) == 4 and np.all(tail < once.extra["cluster"].min())
    np.testing.assert_array_equal(both.q[len(grid) + 5:], np.repeat(wide.q[5:9], weight, axis=0))


@pytest.mark.parametrize("weight", [0, -1, 1.5, True])
def test_a_bad_weight_is_refused(grid_and_wide, weight):
    from calibration.errors import ModelError

    grid, wide, _ = grid_and_wide
    with pytest.raises(ModelError, match="weight"):
        with_added(grid, [wide], weight=weight)


def test_an_added_recording_with_its_own_cluster_column_still_stands_alone(grid_and_wide):
    grid, wide, _ = grid_and_wide
    tagged = Recording(wide.q, wide.p, wide.quat, {"cluster": np.zeros(len(wide))}, "tagged")
    both = with_added(grid, [tagged, tagged])
    assert len(np.unique(both.clusters())) == len(np.unique(grid.clusters())) + 2 * len(wide)


def test_local_fits_use_the_clusters_only(grid_and_wide, r1_nominal):
    grid, wide, _ = grid_and_wide
    both = with_added(grid, [wide])
    fitter = Fitter("R1", r1_nominal, grid, FitOptions())
    kin, theta = fitter.reference("pi")
    alone = fit_local(kin, grid, theta, 1641.0, 1.0)
    added = fit_local(kin, both, theta, 1641.0, 1.0)
    assert len(added.anchors) == len(np.unique(grid.clusters()))
    np.testing.assert_allclose(added.x, alone.x, atol=1e-9)


def test_global_fits_use_the_added_poses(grid_and_wide, r1_nominal):
    """nls1 and pi fitted on grid + 21 wide poses are better on other wide poses than on the grid alone (the still
    wrist hides what the wide poses show); so the added poses reach the global fits."""
    grid, wide, test = grid_and_wide
    both = with_added(grid, [wide])
    for method in ("nls1", "pi"):
        before = errors(Fitter("R1", r1_nominal, grid).fit(method)[0], test).position_mm.mean()
        after = errors(Fitter("R1", r1_nominal, both).fit(method)[0], test).position_mm.mean()
        assert after < 0.5 * before, (method, before, after)


def test_every_cheap_method_and_the_held_out_figures_work_with_stand_alone_poses(grid_and_wide, r1_nominal):
    grid, wide, test = grid_and_wide
    both = with_added(grid, [wide])
    fitter = Fitter("R1", r1_nominal, both)
    for method in ("nls1", "pi", "nls0", "pi+linear", "pi+fbf13"):
        model, _ = fitter.fit(method)
        assert np.isfinite(errors(model, test).position_mm).all(), method
    assert fitter.local_fits("pi").anchors.shape[0] == len(np.unique(grid.clusters()))
    groups, _ = cluster_anchors(both)
    held = fitter.held_out_errors("pi")
    assert held.shape == (len(both),) and np.isfinite(held).all()
    assert len(np.unique(groups)) == len(np.unique(grid.clusters())) + len(wide)
    nls0 = fitter.fit("nls0")[0]
    grid_units = set(np.unique(grid.clusters()).tolist())
    assert set(nls0.info["clusters"]) <= grid_units  # nls0 fits clusters near q = 0, never a stand-alone pose
