"""``predict`` and ``evaluate`` say how many poses lie outside the model's training range, and by how much."""

import json

import numpy as np

from app.cli.commands import main
from calibration.data.recording import read_recording, write_recording
from tests.conftest import cluster_design, measure


def test_predict_and_evaluate_report_poses_outside_the_training_range(tmp_path, synthetic_arm, capsys):
    _, _, truth = synthetic_arm
    q, cluster = cluster_design(step_deg=15.0)
    write_recording(measure(truth.fk, q, 0.02, 0.01, 1, cluster), tmp_path / "train.csv")
    lo, hi = read_recording(tmp_path / "train.csv").q.min(axis=0), read_recording(tmp_path / "train.csv").q.max(axis=0)
    q_test = np.tile((lo + hi) / 2, (12, 1))
    q_test[:3, 0] = hi[0] + np.radians([5.0, 10.0, 20.0])  # three poses beyond q1's training range
    write_recording(measure(truth.fk, q_test, 0.02, 0.01, 2), tmp_path / "test.csv")
    np.savetxt(tmp_path / "q.csv", q_test, delimiter=",")
    model = tmp_path / "m.yaml"
    assert main(["fit", "--robot", "R1", "--train", str(tmp_path / "train.csv"), "--method", "nls1",
                 "--out", str(model)]) == 0
    capsys.readouterr()
    assert main(["predict", "--model", str(model), "--joints", str(tmp_path / "q.csv"), "--out",
                 str(tmp_path / "p.csv"), "--json", str(tmp_path / "p.json")]) == 0
    assert "3 of 12 poses lie outside the joint range" in capsys.readouterr().err
    ex = json.loads((tmp_path / "p.json").read_text())["extrapolation"]
    assert ex["region_known"] and ex["poses"] == 12 and ex["outside_training_range"] == 3
    np.testing.assert_allclose(ex["max_excess_deg"], 20.0, atol=1e-6)
    np.testing.assert_allclose(ex["max_excess_deg_per_joint"][0], 20.0, atol=1e-6)
    assert main(["evaluate", "--model", str(model), "--test", str(tmp_path / "test.csv"), "--json",
                 str(tmp_path / "e.json")]) == 0
    ev = json.loads((tmp_path / "e.json").read_text())["extrapolation"]
    assert ev["outside_training_range"] == 3 and ev["max_excess_deg"] == ex["max_excess_deg"]


def counts_of(doc, prefix=""):
    """Every pose count of a predict/evaluate JSON (keys starting with ``outside_``, a number or counts per context
    entry), as dotted keys."""
    found = set()
    for key, value in doc.items():
        if key.startswith("outside_") and key != "outside_tolerance_deg":
            found.add(prefix + key)
        elif isinstance(value, dict) and key != "counts_explained":
            found |= counts_of(value, f"{prefix}{key}.")
    return found


def test_predict_and_evaluate_json_say_what_each_count_counts(tmp_path, synthetic_arm, capsys):
    """predict --json gave outside_fitted_region: 0 next to outside_training_range: 50 and no word on either: every
    count now has a sentence in counts_explained (the keys themselves stay, scripts read them)."""
    _, _, truth = synthetic_arm
    q, cluster = cluster_design(step_deg=30.0)
    write_recording(measure(truth.fk, q, 0.02, 0.01, 1, cluster), tmp_path / "train.csv")
    q_test = q[:5].copy()
    q_test[:, 0] += np.radians(30.0)
    write_recording(measure(truth.fk, q_test, 0.02, 0.01, 2), tmp_path / "test.csv")
    np.savetxt(tmp_path / "q.csv", q_test, delimiter=",", fmt="%.17g")
    model = tmp_path / "m.yaml"
    assert main(["fit", "--robot", "R1", "--train", str(tmp_path / "train.csv"), "--method", "nls1",
                 "--out", str(model)]) == 0
    assert main(["predict", "--model", str(model), "--joints", str(tmp_path / "q.csv"), "--out",
                 str(tmp_path / "p.csv"), "--json", str(tmp_path / "p.json")]) == 0
    assert main(["evaluate", "--model", str(model), "--test", str(tmp_path / "test.csv"), "--json",
                 str(tmp_path / "e.json")]) == 0
    predict, evaluate = (json.loads((tmp_path / n).read_text()) for n in ("p.json", "e.json"))
    assert predict["outside_fitted_region"] == 0 and predict["extrapolation"]["outside_training_range"] == 5
    assert counts_of(predict) == set(predict["counts_explained"]) >= {"outside_fitted_region",
                                                                      "extrapolation.outside_training_range"}
    assert counts_of(evaluate) == set(evaluate["counts_explained"])
    explained = predict["counts_explained"]
    assert "constant geometry" in explained["outside_fitted_region"] and "0" in explained["outside_fitted_region"]
    assert "training data" in explained["extrapolation.outside_training_range"]
    assert f"{predict['extrapolation']['outside_tolerance_deg']:g} deg" in explained[
        "extrapolation.outside_training_range"]


def test_predict_and_evaluate_count_a_pose_a_rounding_past_the_edge_alike(tmp_path, synthetic_arm, capsys):
    """Poses 0.02 deg past q1's training range made predict and evaluate warn '... (by up to 0.0 deg)': neither
    counts them now, and both count the pose 0.5 deg past by the same rule."""
    _, _, truth = synthetic_arm
    q, cluster = cluster_design(step_deg=30.0)
    write_recording(measure(truth.fk, q, 0.02, 0.01, 1, cluster), tmp_path / "train.csv")
    hi = q.max(axis=0)
    q_test = np.tile((q.min(axis=0) + hi) / 2, (4, 1))
    q_test[:3, 0] = hi[0] + np.radians([0.02, 0.04, 0.5])
    write_recording(measure(truth.fk, q_test, 0.02, 0.01, 2), tmp_path / "test.csv")
    np.savetxt(tmp_path / "q.csv", q_test, delimiter=",", fmt="%.17g")
    model = tmp_path / "m.yaml"
    assert main(["fit", "--robot", "R1", "--train", str(tmp_path / "train.csv"), "--method", "nls1",
                 "--out", str(model)]) == 0
    capsys.readouterr()
    for argv, name in ((["predict", "--joints", str(tmp_path / "q.csv"), "--out", str(tmp_path / "p.csv")], "p.json"),
                       (["evaluate", "--test", str(tmp_path / "test.csv")], "e.json")):
        assert main([*argv, "--model", str(model), "--json", str(tmp_path / name)]) == 0
        err = capsys.readouterr().err
        assert "1 of 4 poses lie outside the joint range" in err and "by up to 0.5 deg" in err, err
        assert json.loads((tmp_path / name).read_text())["extrapolation"]["outside_training_range"] == 1


def test_evaluate_says_when_poses_are_later_than_the_training_data_and_holds_a_short_warm_up(tmp_path, capsys):
    """A warm-up drift fitted on ten minutes of a one-hour time constant: evaluate on poses taken hours later names
    the time range and says the guard held the drift at its edge (:mod:`calibration.models.guard`)."""
    from calibration.data.recording import Recording
    from calibration.kinematics import so3
    from calibration.models import save_model
    from calibration.models.guard import REGION_KEY, Region
    from calibration.models.physics import PhysicsModel
    from calibration.physics import ThermalDrift
    from cell_config import load_cell

    spec = load_cell().robot("R1")
    q = np.radians(np.random.default_rng(3).uniform(-20, 20, (5, 6)))
    region = Region.of(q, context={"t": np.array([0.0, 600.0])})
    drift = (ThermalDrift(("p34",), np.array([2.0]), "warmup", tau_s=3600.0),)
    save_model(PhysicsModel("R1", "diagnose", spec.model(), drift, 0, {REGION_KEY: region.to_dict()}),
               tmp_path / "m.yaml")
    t = np.array([60.0, 300.0, 900.0, 3600.0, 14400.0])
    R, p = spec.model().fk(q)
    write_recording(Recording(q, p, so3.R_to_quat(R), {"t": t}), tmp_path / "late.csv")
    capsys.readouterr()
    assert main(["evaluate", "--model", str(tmp_path / "m.yaml"), "--test", str(tmp_path / "late.csv"),
                 "--json", str(tmp_path / "e.json")]) == 0
    err = capsys.readouterr().err
    assert "poses lie beyond the diagnose model's training data in t (3 of 5 poses, by up to 1.38e+04 s; " \
           "trained on 0 to 600 s); the guard held its effects whose shape was fitted over too short a span of them " \
           "at the edge of that range (moving the position by up to" in err
    assert "outside the joint range" not in err
    ex = json.loads((tmp_path / "e.json").read_text())["extrapolation"]
    assert ex["outside_context_range"]["t"] == {"poses": 3, "max_excess": 13800.0, "unit": "s", "range": [0.0, 600.0]}
    assert ex["guard_acted"] and ex["guard_shift_context_mm_max"] == ex["guard_shift_mm_max"] > 0.5


def test_evaluate_tells_the_joint_hold_from_the_time_hold(tmp_path, capsys):
    """A gear error held in q1 beside a warm-up recorded for longer than its time constant (not held): the time line
    must not borrow the joint hold's shift, and a model without time effects says nothing of time."""
    from calibration.data.recording import Recording
    from calibration.kinematics import so3
    from calibration.models import save_model
    from calibration.models.guard import REGION_KEY, Region
    from calibration.models.physics import PhysicsModel
    from calibration.physics import GearTransmission, ThermalDrift
    from cell_config import load_cell

    spec = load_cell().robot("R1")
    q_train = np.radians(np.random.default_rng(4).uniform(-1, 1, (20, 6)))
    region = Region.of(q_train, context={"t": np.array([0.0, 600.0])})
    effects = (GearTransmission(((1, (1,)),), np.array([2e-3, 1e-3])),
               ThermalDrift(("p34",), np.array([0.5]), "warmup", tau_s=100.0))
    save_model(PhysicsModel("R1", "diagnose", spec.model(), effects, 0, {REGION_KEY: region.to_dict()}),
               tmp_path / "m.yaml")
    q = q_train[:4].copy()
    q[0, 0] = np.radians(30.0)  # far beyond q1's 2 deg band: the gear error is held there
    R, p = spec.model().fk(q)
    write_recording(Recording(q, p, so3.R_to_quat(R), {"t": np.array([60.0, 300.0, 900.0, 3600.0])}),
                    tmp_path / "late.csv")
    capsys.readouterr()
    assert main(["evaluate", "--model", str(tmp_path / "m.yaml"), "--test", str(tmp_path / "late.csv"),
                 "--json", str(tmp_path / "e.json")]) == 0
    err = capsys.readouterr().err
    assert "1 of 4 poses lie outside the joint range" in err and "the guard held its effects fitted in narrowly" in err
    assert "in t (2 of 4 poses, by up to 3e+03 s; trained on 0 to 600 s); the guard did not change its prediction" in err
    ex = json.loads((tmp_path / "e.json").read_text())["extrapolation"]
    assert ex["guard_shift_mm_max"] > 0.1 and ex["guard_shift_context_mm_max"] == 0.0
    # a model whose effects read no time: the recording's late t is no concern of it
    save_model(PhysicsModel("R1", "diagnose", spec.model(), effects[:1], 0, {REGION_KEY: region.to_dict()}),
               tmp_path / "gear.yaml")
    assert main(["evaluate", "--model", str(tmp_path / "gear.yaml"), "--test", str(tmp_path / "late.csv"),
                 "--json", str(tmp_path / "g.json")]) == 0
    assert "training data in t" not in capsys.readouterr().err
    assert json.loads((tmp_path / "g.json").read_text())["extrapolation"]["outside_context_range"] == {}
