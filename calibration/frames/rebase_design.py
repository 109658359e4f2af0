"""The rebase design: which clusters of a recording best determine a rebase (the base and tool-marker frames and
the joint offsets ``REBASE_OFFSETS``, :mod:`calibration.frames.rebase`), by the D criterion of
:mod:`calibration.identification.design` applied to the rebase's parameters instead of the geometry."""

from __future__ import annotations

from typing import Any

import numpy as np

from calibration.data.recording import Recording
from calibration.frames.rebase import delta_scale, direction_names, rebase_rows
from calibration.identification.design import Candidates, RecordingSelection, candidates_from_rows, recording_selection
from calibration.identification.geometric import DEFAULT_ORIENTATION_WEIGHT
from calibration.identification.observability import DEFAULT_REACH_MM, scaled_rows
from calibration.kinematics.parameterisation import MinimalParameterisation
from calibration.models.constant import ConstantModel

#: The joint offsets a rebase refits with the frames: the wrist's 4 and 5. Joint 1's and 6's are rotations of the
#: base and tool frames; 2 and 3 are left out because what changes between the shared days appears to lie along
#: joints 1 and 4-6 (issue 10), and in the simulated cell (``scripts/benchmarks/bench_rebase_design.py``, 6 noise draws of one
#: day) refitting 2-5 instead of 4-5 costs 0.055 against 0.048 mm mean over the workspace.
REBASE_OFFSETS = (4, 5)


def rebase_candidates(model: Any, q: np.ndarray, cluster: np.ndarray, anchors: np.ndarray,
                      offsets: tuple[int, ...] = REBASE_OFFSETS, a: float = DEFAULT_ORIENTATION_WEIGHT,
                      reach_mm: float = DEFAULT_REACH_MM, reference_q: np.ndarray | None = None) -> Candidates:
    """The candidate clusters' information about a rebase of ``model`` (a fitted or nominal
    :class:`~calibration.models.base.KinematicModel`): its 12 frame directions and the ``offsets`` (1-based)."""

    scale = delta_scale(len(offsets), reach_mm)
    rows = scaled_rows(rebase_rows(model, np.asarray(q, dtype=float), offsets), scale, a)
    ref = None if reference_q is None else scaled_rows(rebase_rows(model, reference_q, offsets), scale, a)
    return candidates_from_rows(rows, cluster, anchors, scale, direction_names(offsets), ref)


def select_rebase_recording(par: MinimalParameterisation, rec: Recording, budget: int, noise_mm: float,
                            cluster_size: int = 7, a: float = DEFAULT_ORIENTATION_WEIGHT,
                            rebase_offsets: tuple[int, ...] = ()) -> RecordingSelection:
    """The ``budget`` clusters of ``rec`` for a rebase: D on the rebase's frame directions and the joint offsets
    ``rebase_offsets`` (``()`` for the frames alone) at the nominal arm ``par.nominal``, no spread term (a rebase
    interpolates nothing). The rebase counterpart of :func:`calibration.identification.design.select_recording`."""
    ids = rec.clusters(cluster_size)
    uniq, first, index = np.unique(ids, return_index=True, return_inverse=True)
    nominal = ConstantModel("nominal", "nominal", par.nominal)  # its robot name is a label only here
    cands = rebase_candidates(nominal, rec.q, index, rec.q[first][:, 1:3], tuple(rebase_offsets), a=a)
    return recording_selection(cands, rec, uniq, index, budget, noise_mm, spread_weight=0.0)
