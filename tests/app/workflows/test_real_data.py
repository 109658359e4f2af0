"""The paper's comparison on the real MA2010 (R1) recordings in ../shared (skipped when absent)."""

import numpy as np
import pytest

from calibration.data.recording import read_recording
from calibration.evaluation.metrics import errors
from calibration.method_names import PI_CDC_METHODS
from calibration.methods.fitter import Fitter
from calibration.methods.options import FitOptions
from cell_config import load_cell
from tests.conftest import R1_TEST, R1_TRAIN, needs_shared_data

pytestmark = needs_shared_data()


@pytest.fixture(scope="module")
def data():
    robot = load_cell().robot("R1")
    train = read_recording(R1_TRAIN, robot.robot.lower_rad, robot.robot.upper_rad)
    test = read_recording(R1_TEST, robot.robot.lower_rad, robot.robot.upper_rad)
    return robot.model(), train, test


@pytest.fixture(scope="module")
def table(data):
    nominal, train, test = data
    fitter = Fitter.for_arm(load_cell().robot("R1").arm(), train)
    out = {}
    for method in ("nominal", "base", "nls0", "nls1", "pi") + PI_CDC_METHODS:
        e = errors(fitter.fit(method)[0], test).position_mm
        out[method] = (e.mean(), e.std(), e.max())
    return out


def test_nominal_row_matches_the_published_figures(table):
    np.testing.assert_allclose(table["nominal"], (1.290, 0.207, 1.721), atol=1e-3)


def test_fourier_cdc_at_least_as_good_as_the_paper(table):
    # The Fourier CDC built on pi (named fbf13 before the paper's construction took that name, see
    # calibration.methods.fitter); the paper's construction itself does not reach its figure (issue 10).
    mean, _, worst = table["pi+fbf13"]
    assert mean <= 0.31 and worst <= 0.74, table["pi+fbf13"]


def test_configuration_dependent_methods_beat_every_constant_method_on_max(table):
    best_constant = min(table[m][2] for m in ("nominal", "base", "nls0", "nls1"))
    for m in PI_CDC_METHODS + ("pi",):
        assert table[m][2] < best_constant, (m, table[m], best_constant)


def test_global_fit_no_worse_than_nominal_because_hidden_directions_are_held(data, table):
    assert table["nls1"][0] <= table["nominal"][0] and table["nls1"][2] <= table["nominal"][2]
    nominal, train, test = data
    free, _ = Fitter("R1", nominal, train, FitOptions(tolerance=0.0)).fit("nls1")
    e = errors(free, test).position_mm
    assert e.mean() > table["nominal"][0]  # every direction free: the fit extrapolates worse than nominal

