"""Several recordings in one fit: per-recording frames are recovered, a day whose arm changed is flagged, and the
pooled recording keeps the clusters of each recording apart."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.arm import Arm
from calibration.data.recording import put_in
from calibration.errors import ModelError
from calibration.frames.multiday import KINEMATICS_RATIO_LIMIT, fit_days, pool
from calibration.kinematics import so3
from calibration.kinematics.parameterisation import MinimalParameterisation
from calibration.kinematics.so3 import make_T
from calibration.methods.options import FitOptions
from tests.conftest import cluster_design, measure, planted_parameters

T_BASE = make_T(so3.exp(np.radians(0.1) * np.array([0.0, 0.6, 0.8])), np.array([1.5, -1.0, 0.8]))


@pytest.fixture(scope="module")
def days(r1_nominal):
    """Three recordings: day 0, day 1 = the same arm in a moved mocap frame, day 2 = an arm whose joint 2 moved."""
    par = MinimalParameterisation(r1_nominal, fit_tool=True)
    x = planted_parameters(par, 1, 0.5, 5e-4)
    changed = x.copy()
    changed[2:4] += 0.6  # joint 2's origin moved by 0.85 mm
    q, cluster = cluster_design(step_deg=15.0)
    recs = [measure(par.model(x).fk, q, 0.02, 0.01, 1, cluster),
            put_in(measure(par.model(x).fk, q, 0.02, 0.01, 2, cluster), T_BASE, np.eye(4)),
            measure(par.model(changed).fk, q, 0.02, 0.01, 3, cluster)]
    return [type(r)(r.q, r.p, r.quat, r.extra, f"day{i}") for i, r in enumerate(recs)]


def test_pool_keeps_clusters_apart(days):
    pooled = pool(days[:2])
    assert len(pooled) == 2 * len(days[0])
    assert len(np.unique(pooled.clusters())) == 2 * len(np.unique(days[0].clusters()))


def _fit(days, r1_nominal):
    return fit_days(Arm("R1", "MA2010", r1_nominal), days, reference="nls1",
                    options=FitOptions(reject_gross_rows=False))


def test_the_frames_of_a_moved_mocap_are_recovered(days, r1_nominal):
    fit = _fit(days[:2], r1_nominal)
    d0, d1 = fit.days
    assert d0.frames is None
    np.testing.assert_allclose(d1.frames.result.T_base_correction[:3, 3], T_BASE[:3, 3], atol=0.05)
    assert abs(d1.frames.base_deg - 0.1) < 0.01
    assert d1.ratio < 1.1 and not fit.kinematics_changed
    model, _ = fit.fitter.fit("nls1")
    assert len(fit.fitter.train) == 2 * len(days[0]) and model.method == "nls1"


def test_a_day_whose_arm_changed_is_flagged(days, r1_nominal):
    fit = _fit(days, r1_nominal)
    assert fit.kinematics_changed and fit.worst == "day2"
    assert max(d.ratio for d in fit.days) > KINEMATICS_RATIO_LIMIT
    assert "day2 differs most" in fit.summary()


def test_one_recording_is_refused(days, r1_nominal):
    with pytest.raises(ModelError, match="at least two recordings"):
        fit_days(Arm("R1", "MA2010", r1_nominal), days[:1])


def test_the_joint_fit_says_which_parameters_differ(days, r1_nominal):
    """Per parameter: day1 differs by its frames only, day2 by its kinematics (joint 2's origin), beyond the noise."""
    diff = _fit(days, r1_nominal).differences
    d1, d2 = diff.days
    assert d1.frames_differ and not d1.kinematics_differ
    assert d2.kinematics_differ
    moved = {p.name for p in d2.parameters if p.differs}
    assert moved and moved <= {"origin2_a_mm", "origin2_b_mm"}
    assert "day2 against day0" in diff.summary()


def test_days_are_named_by_their_folder_names(days, r1_nominal):
    named = [type(r)(r.q, r.p, r.quat, r.extra, f"/data/welding/test{i}_R1") for i, r in enumerate(days[:2])]
    fit = _fit(named, r1_nominal)
    assert [d.name for d in fit.days] == ["test0_R1", "test1_R1"]
    assert "/data/welding" not in fit.summary() and "test1_R1 against test0_R1" in fit.summary()


@pytest.mark.parametrize("ratios, significant, says", [
    ((1.0, 1.06), True, "Both hold: the kinematics did change beyond the measurement noise, but by too little"),
    ((1.0, 1.6), False, "Both hold: no parameter differs beyond the noise"),
    ((1.0, 1.06), False, None), ((1.0, 1.6), True, None)])
def test_the_summary_relates_the_accuracy_and_the_significance_verdicts(ratios, significant, says):
    from types import SimpleNamespace

    from calibration.frames.multiday import Day, MultiDayFit

    days = tuple(Day(f"d{i}", 10, None, 0.1 * r, 0.1) for i, r in enumerate(ratios))
    verdict = "differ beyond the measurement noise" if significant else "same within the measurement noise"
    diff = SimpleNamespace(kinematics_changed=significant, summary=lambda: f"Significance: parameters {verdict}.")
    text = MultiDayFit(None, days, "pi", diff).summary()
    assert text.count("Accuracy:") == 1 and text.count("Significance:") == 1
    assert (says in text) if says else "Both hold" not in text


def test_a_first_recording_off_by_a_frame_gives_a_base_free_pooled_fit(days, r1_nominal):
    """As the frames-first fit of one recording (calibration.frames.check.base_free): the pooled fit behind a first
    recording the frame check finds off leaves its pi's rigid part free; one that passes keeps the damped pi."""
    from calibration.frames.check import FramedFit

    T_far = make_T(so3.exp(np.radians(1.0) * np.array([0.6, -0.8, 0.0])), np.array([12.0, -8.0, 5.0]))
    off = [put_in(days[0], T_far, np.eye(4)), days[1]]
    fit = _fit(off, r1_nominal)
    assert isinstance(fit.fitter, FramedFit) and fit.fitter.inner.options.pi_base_free
    assert not _fit(days[:2], r1_nominal).fitter.options.pi_base_free
