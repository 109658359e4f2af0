"""Every cellcal error pickles as itself: a worker process's error reaches the parent with its message and data."""

from __future__ import annotations

import pickle

import pytest

from calibration.errors import ConfigError, DataError, ModelError, ModelFileError, OutputError, UnsafeTarget
from drivers.errors import DriverTimeout, InvalidArgument, RobotFault


@pytest.mark.parametrize("error", [
    DataError("train.csv", 4, "q2", "not a number"), ConfigError("cell.yaml", "mocap.dwell_s", "must be > 0"),
    ModelFileError("m.yaml", "theta_ref", "not finite"), OutputError("out.csv", "is a folder"),
    UnsafeTarget("R1", 2, 1.0, 0.5, "limit"), InvalidArgument("sim:R1", "speed_fraction", 2.0, "in (0, 1]"),
    DriverTimeout("motoros@10.0.0.2", "settle", 60.0), RobotFault("motoros@10.0.0.2", "alarm 4107"),
    ModelError("unknown method 'x'"),
], ids=lambda e: type(e).__name__)
def test_an_error_round_trips_through_pickle(error):
    back = pickle.loads(pickle.dumps(error))
    assert type(back) is type(error) and str(back) == str(error) and back.__dict__ == error.__dict__
