"""diagnose's held-out check makes each joint fit once and the independent ones in forked workers: the same
diagnosis, bit for bit, as every fit made in order in one process."""

from __future__ import annotations

import json
import multiprocessing as mp

import numpy as np
import pytest

from calibration.diagnosis import core, diagnose
from calibration.diagnosis.fits import JointFits
from calibration.diagnosis.synthetic import Design, make_case, perturbed_gravity
from calibration.physics import GravityModel
from cell_config import load_cell

needs_fork = pytest.mark.skipif("fork" not in mp.get_all_start_methods(), reason="no fork start method")


class Template:
    """An effect template stand-in (fits key on the templates' identity)."""

    def __init__(self, value: float) -> None:
        self.value = value


def slow_sum(chosen):
    return sum(e.value for e, _ in chosen) + 0.5


def test_each_set_is_fitted_once_here_without_workers():
    calls = []

    def fit(chosen):
        calls.append([e.value for e, _ in chosen])
        return slow_sum(chosen)

    a, b = Template(1.0), Template(2.0)
    B = np.eye(1)
    with JointFits(fit, workers=1) as fits:
        fits.start([(a, B)])  # no workers: nothing made ahead
        assert calls == []
        assert fits.get([(a, B), (b, B)]) == 3.5
        assert fits.get([(a, B), (b, B)]) == 3.5
        assert fits.get([(b, B), (a, B)]) == 3.5  # another order is another set of columns: fitted again
        assert fits.get([]) == 0.5
    assert calls == [[1.0, 2.0], [2.0, 1.0], []]


@needs_fork
def test_fits_started_ahead_come_from_the_workers_of_their_own_fits_object():
    calls = []

    def fit(chosen):
        calls.append(len(chosen))
        return slow_sum(chosen)

    a, b = Template(1.0), Template(2.0)
    B = np.eye(1)
    with JointFits(fit, workers=2) as fits:
        with JointFits(lambda chosen: -1.0, workers=2) as other:  # two open at once: each forks with its own fit
            other.start([(a, B), (b, B)])
            assert other.get([(a, B), (b, B)]) == -1.0
        fits.start([(a, B)], [(a, B), (b, B)], [(a, B)])
        assert fits.get([(a, B), (b, B)]) == 3.5 and fits.get([(a, B)]) == 1.5
        assert calls == []  # both made in the workers
        assert fits.get([(b, B)]) == 2.5  # never started: made here
        assert calls == [1]
    with JointFits(fit, workers=2) as again:  # closed: a new one may open
        assert again.get([]) == 0.5


@needs_fork
def test_diagnosis_with_workers_is_the_diagnosis_made_in_one_process(monkeypatch):
    # Two kinds and the mass-free form: the check starts trial and flexible-form fits ahead and reuses one.
    cr = load_cell().robot("R1")
    nominal = cr.model()
    gravity = GravityModel.from_spec(cr.robot, nominal)
    truth = perturbed_gravity(gravity, nominal, 0.3, 1)
    _, fit, ho = make_case(nominal, truth, {"joint_compliance": 0.3, "payload_compliance": 0.3}, 1, Design())
    limits = (cr.robot.lower_rad, cr.robot.upper_rad)
    made = []
    real = core.joint_fit
    monkeypatch.setattr(core, "joint_fit", lambda *a, **k: made.append(1) or real(*a, **k))
    reports = {}
    for workers in (1, 2):
        monkeypatch.setattr(core, "usable_workers", lambda workers=workers: workers)
        made.clear()
        res = diagnose("R1", nominal, fit, ho, gravity=gravity, joint_limits=limits)
        reports[workers] = (json.dumps(res.to_json(), sort_keys=True), len(made))
    assert sorted(e.kind for e in res.effects) == ["joint_compliance", "payload_compliance"]
    assert reports[2][0] == reports[1][0]
    assert reports[2][1] < reports[1][1]  # fits made in the workers, not here
