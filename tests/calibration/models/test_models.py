"""Every model kind saves to one file and loads back to bit-identical predictions."""

import numpy as np
import pytest

from calibration.errors import DataError
from calibration.method_names import METHODS
from calibration.methods.fitter import Fitter
from calibration.methods.options import FitOptions
from calibration.models import load_model, save_model
from tests.conftest import cluster_design, measure


@pytest.fixture(scope="module")
def fitter(synthetic_arm, r1_nominal):
    _, _, truth = synthetic_arm
    q, cluster = cluster_design(step_deg=30.0)  # 12 anchors: every method fits; a round trip does not need more
    rec = measure(truth.fk, q, 0.02, 0.01, 1, cluster)
    return Fitter("R1", r1_nominal, rec, FitOptions())


@pytest.fixture(scope="module")
def fitted(fitter):
    cache = {}

    def get(method):
        if method not in cache:
            cache[method] = fitter.fit(method)[0]
        return cache[method]
    return get


@pytest.mark.parametrize("method", [m for m in METHODS if m != "cpa"])
@pytest.mark.parametrize("suffix", [".yaml", ".json"])
def test_round_trip_bit_identical(tmp_path, fitted, method, suffix):
    model = fitted(method)
    path = tmp_path / f"model{suffix}"
    save_model(model, path)
    back = load_model(path)
    q = np.random.default_rng(0).uniform(-1, 1, (50, 6))
    R0, p0 = model.fk(q)
    R1, p1 = back.fk(q)
    assert np.array_equal(p0, p1) and np.array_equal(R0, R1)
    assert back.method == method and back.robot == "R1"


def test_bad_model_files(tmp_path):
    path = tmp_path / "m.yaml"
    path.write_text("schema: other/1\n")
    with pytest.raises(DataError, match="unsupported model schema"):
        load_model(path)
    path.write_text("[1, 2")
    with pytest.raises(DataError, match="not a valid model file"):
        load_model(path)
    with pytest.raises(DataError, match="not found"):
        load_model(tmp_path / "none.yaml")


def test_a_model_file_that_does_not_parse_is_named_with_its_line_and_column_on_one_line(tmp_path):
    # it said "not a valid model file (ParserError)": no place in the file
    path = tmp_path / "m.yaml"
    path.write_text("schema: cellcal.model/2\nkind: constant\nrobot: [R1\n")
    with pytest.raises(DataError) as e:
        load_model(path)
    assert str(e.value) == f"{path}: not a valid model file (line 4, column 1: did not find expected ',' or ']')"
    path = tmp_path / "m.json"
    path.write_text('{"schema": "cellcal.model/2",\n "kind": }')
    with pytest.raises(DataError, match=r"m.json: not a valid model file \(line 2, column 10: Expecting value\)$"):
        load_model(path)


def test_files_are_written_as_schema_2_and_schema_1_files_still_load(tmp_path, fitted):
    """A /1 reader ignores the training region's guard rule and would mispredict a new file, so new files say /2;
    files written before keep loading, with the guard they had."""
    import yaml

    model = fitted("pi")
    path = tmp_path / "m.yaml"
    save_model(model, path)
    data = yaml.safe_load(path.read_text())
    assert data["schema"] == "cellcal.model/2"
    data["schema"] = "cellcal.model/1"
    data["info"]["training_region"].pop("rule", None)
    old = tmp_path / "old.yaml"
    old.write_text(yaml.safe_dump(data))
    q = np.random.default_rng(1).uniform(-1, 1, (20, 6))
    np.testing.assert_array_equal(load_model(old).fk(q)[1], model.fk(q)[1])
