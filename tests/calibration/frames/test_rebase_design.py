"""The rebase design's information (:func:`calibration.frames.rebase_design.rebase_candidates`): the frames and the wrist
offsets, seen only where the wrist moves."""

from __future__ import annotations

import math

import numpy as np

from calibration.frames import rebase_design
from calibration.frames.rebase import rebase_rows
from calibration.identification import design
from calibration.methods.cdc import expand_anchors
from calibration.models import ConstantModel
from cell_config.loader import load_cell


def _nominal() -> ConstantModel:
    return ConstantModel("R1", "nominal", load_cell().robot("R1").model())


def test_rebase_candidates_see_the_wrist_offsets_only_where_the_wrist_moves():
    still = np.zeros((5, 6))
    still[:, 1:3] = np.random.default_rng(1).uniform(-0.8, 0.8, (5, 2))
    q, cluster = expand_anchors(still, math.radians(1.0))
    figs = design.figures(rebase_design.rebase_candidates(_nominal(), q, cluster, still[:, 1:3]), list(range(5)), 0.05)
    assert figs.rank < 14 == len(figs.names)
    wide_anchors = np.random.default_rng(4).uniform(-1.2, 1.2, (40, 6))
    q, cluster = expand_anchors(wide_anchors, math.radians(20.0))
    cands = rebase_design.rebase_candidates(_nominal(), q, cluster, wide_anchors[:, 1:3])
    wide = design.figures(cands, design.select(cands, 3, spread_weight=0.0), 0.05)
    assert wide.rank == wide.n_identifiable == 14


def test_rebase_candidates_information_is_the_rebase_jacobians():
    """Each cluster's information is J^T J of the rebase's own (scaled) pose Jacobian rows, summed over its poses."""
    from calibration.frames.rebase import delta_scale
    from calibration.identification.observability import scaled_rows

    anchors = np.random.default_rng(2).uniform(-1.0, 1.0, (3, 6))
    q, cluster = expand_anchors(anchors, math.radians(20.0))
    cands = rebase_design.rebase_candidates(_nominal(), q, cluster, anchors[:, 1:3])
    rows = scaled_rows(rebase_rows(_nominal(), q, rebase_design.REBASE_OFFSETS), delta_scale(2, 1000.0))
    for c in range(3):
        J = rows[cluster == c].reshape(-1, 14) @ cands.basis
        np.testing.assert_allclose(cands.info[c], J.T @ J, rtol=1e-10, atol=1e-9)
