"""The two CDC constructions: the paper's (geometric reference, bare names) and the one built on pi (``pi+``)."""

import numpy as np
import pytest

from calibration.errors import ModelError, ModelFileError
from calibration.interpolation.fourier import Fourier13Interpolator
from calibration.method_names import CDC_INTERPOLATORS, CDC_METHODS, METHODS, cdc_method
from calibration.methods.cdc import geometric_cdc
from calibration.methods.fitter import Fitter
from calibration.methods.options import FitOptions
from calibration.models import load_model, save_model
from calibration.models.base import KinematicModel
from calibration.models.cdc import CdcModel
from tests.calibration.models.kinds import models_of_every_kind
from tests.conftest import cluster_design, measure


def test_every_interpolator_has_both_constructions():
    assert set(CDC_METHODS) == set(CDC_INTERPOLATORS) | {f"pi+{k}" for k in CDC_INTERPOLATORS}
    assert set(CDC_METHODS) <= set(METHODS)
    assert cdc_method("fbf13") == ("geometric", "fbf13")
    assert cdc_method("pi+fbf13") == ("pi", "fbf13")
    for bad in ("pi", "nls1", "pi+magic", "geo+fbf13"):
        with pytest.raises(ModelError, match="not a CDC method"):
            cdc_method(bad)


@pytest.fixture(scope="module")
def fitter(synthetic_arm, r1_nominal):
    _, _, truth = synthetic_arm
    q, cluster = cluster_design(step_deg=15.0)
    return Fitter("R1", r1_nominal, measure(truth.fk, q, 0.02, 0.01, 1, cluster), FitOptions())


def test_the_paper_construction_varies_the_geometry_around_the_geometric_fit(fitter):
    model, _ = fitter.fit("fbf13")
    g = fitter.par.size
    assert model.reference == "geometric" and model.info["reference"] == "geometric"
    np.testing.assert_array_equal(model.theta_ref[g:], 0.0)
    np.testing.assert_array_equal(model.theta_ref[:g], fitter.global_fit())


def test_the_pi_construction_varies_the_geometry_around_pi(fitter):
    model, _ = fitter.fit("pi+fbf13")
    assert model.method == "pi+fbf13" and model.reference == "pi"
    np.testing.assert_array_equal(model.theta_ref, fitter.physics_informed().theta)
    assert model.interpolator.__class__ is Fourier13Interpolator


@pytest.mark.parametrize("reference", ["geometric", "pi"])
def test_the_file_records_the_reference_and_round_trips(tmp_path, reference):
    kinds = models_of_every_kind()
    model = kinds.cdc if reference == "pi" else CdcModel("R1", "fbf13", *geometric_cdc(kinds.par), kinds.cdc.interpolator)
    data = model.to_dict()
    assert data["reference"] == reference
    save_model(model, tmp_path / "m.json")
    loaded = load_model(tmp_path / "m.json")
    assert loaded.reference == reference
    np.testing.assert_array_equal(loaded.theta_ref, model.theta_ref)


def test_a_file_without_the_reference_key_loads_with_the_reference_its_theta_implies():
    data = models_of_every_kind().cdc.to_dict()
    del data["reference"]  # written before the key existed: every such cdc file was built on pi
    assert KinematicModel.from_dict(data).reference == "pi"


def test_a_reference_that_contradicts_theta_ref_is_refused():
    data = models_of_every_kind().cdc.to_dict()
    data["reference"] = "geometric"
    with pytest.raises(ModelFileError, match="reference"):
        KinematicModel.from_dict(data)
