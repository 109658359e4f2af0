"""Crashes and hangs of issue 30 where one line and exit 2 is promised: every input path reads through one bounded,
regular-file-only reader (a FIFO blocked forever, /dev/zero read until memory ran out), and the data checks that
were missing (a CSV field over csv's limit, one-row and seven-row recordings, copied rows, a plan nested 200,000
deep, a binary path file, a damaged session database, a recording in metres)."""

import json
import os
import sqlite3
import threading

import numpy as np
import pytest

from app.cli.commands import main
from calibration.data.recording import Recording, read_recording, write_recording
from calibration.errors import CellCalError, DataError
from tests.conftest import assert_bad_input, cluster_design, measure


def finishes(call, timeout_s: float = 5.0):
    """``call()``'s exception (or None), failing the test when it is still running after ``timeout_s``: a reader
    blocked on a FIFO never returns."""
    outcome: dict = {}

    def run():
        try:
            call()
            outcome["error"] = None
        except BaseException as e:  # noqa: BLE001 - handed to the test
            outcome["error"] = e

    t = threading.Thread(target=run, daemon=True)
    t.start()
    t.join(timeout_s)
    assert "error" in outcome, f"still running after {timeout_s} s (blocked on the input?)"
    return outcome["error"]


@pytest.fixture(scope="module")
def data(tmp_path_factory, synthetic_arm):
    _, _, truth = synthetic_arm
    root = tmp_path_factory.mktemp("bad-inputs")
    q, cluster = cluster_design(step_deg=30.0)
    rec = measure(truth.fk, q, 0.02, 0.01, 1, cluster)
    write_recording(rec, root / "train.csv")
    assert main(["fit", "--robot", "R1", "--train", str(root / "train.csv"), "--method", "base",
                 "--out", str(root / "m.yaml")]) == 0
    os.mkfifo(root / "fifo")
    return root


def _readers():
    """Every input reader, as (name, call on a path, the error it must raise)."""
    from app.collection.plans.reader import read_plan
    from app.dual.paths import read_pose
    from app.jobs.jbi import JobError, read_job
    from calibration.data.recording import read_joints
    from calibration.errors import ConfigError
    from calibration.models import load_model
    from cell_config import load_cell

    return [("recording", read_recording, DataError), ("joints", read_joints, DataError),
            ("model", load_model, DataError), ("cell", load_cell, ConfigError), ("plan", read_plan, DataError),
            ("pose", lambda p: read_pose(str(p)), DataError), ("job", read_job, JobError)]


@pytest.mark.parametrize("name,read,error", _readers(), ids=[r[0] for r in _readers()])
@pytest.mark.parametrize("special", ["fifo", "/dev/zero"])
def test_every_reader_refuses_a_fifo_or_a_device_at_once(data, name, read, error, special):
    path = data / "fifo" if special == "fifo" else special
    e = finishes(lambda: read(path))
    assert isinstance(e, error), repr(e)
    assert "not a regular file" in str(e) and str(path) in str(e)


def test_the_bounded_reader_reads_a_regular_file_and_refuses_one_over_its_bound(tmp_path):
    from calibration.data.files import InputRefused, read_input_bytes

    f = tmp_path / "f"
    f.write_bytes(b"x" * 100)
    assert read_input_bytes(f, 100) == b"x" * 100
    with pytest.raises(InputRefused, match="over the"):
        read_input_bytes(f, 99)
    with pytest.raises(IsADirectoryError):
        read_input_bytes(tmp_path)
    with pytest.raises(FileNotFoundError):
        read_input_bytes(tmp_path / "missing")


@pytest.mark.parametrize("option", ["--train", "--test"])
def test_cli_names_the_option_of_a_fifo_before_any_work(data, capsys, tmp_path, option):
    argv = ["compare", "--robot", "R1", "--train", str(data / "train.csv"), "--test", str(data / "train.csv"),
            "--json", str(tmp_path / "j.json")]
    argv[argv.index(option) + 1] = str(data / "fifo")
    assert finishes(lambda: assert_bad_input(capsys, argv, str(data / "fifo"), f"{option}:", "FIFO")) is None
    assert not (tmp_path / "j.json").exists()


def test_recording_over_its_size_bound_is_refused(data, monkeypatch):
    import calibration.data.recording as recording

    monkeypatch.setattr(recording, "MAX_RECORDING_BYTES", 1000)
    with pytest.raises(DataError, match="MiB limit"):
        read_recording(data / "train.csv")


def test_plan_over_its_size_bound_is_refused(tmp_path, monkeypatch):
    import app.collection.plans.reader as plan_file

    monkeypatch.setattr(plan_file, "MAX_PLAN_BYTES", 1000)
    f = tmp_path / "plan.json"
    f.write_text(json.dumps({"schema": "cellcal.plan/1", "kind": "dual", "waypoints": [[0.0] * 10] * 100}))
    with pytest.raises(DataError, match="MiB limit"):
        plan_file.read_plan(f)


def test_csv_field_over_the_csv_limit_is_one_line(data, tmp_path, capsys):
    f = tmp_path / "big.csv"
    f.write_text((data / "train.csv").read_text().splitlines()[0] + "\n" + "1" * 200_000 + "\n")
    assert_bad_input(capsys, ["fit", "--robot", "R1", "--train", str(f), "--method", "nls1", "--out",
                              str(tmp_path / "m.yaml")], str(f), "row 2", "field larger than field limit")
    assert not (tmp_path / "m.yaml").exists()


@pytest.mark.parametrize("rows", [1, 2, 6])
def test_a_recording_of_a_few_rows_fits_or_refuses_in_one_line(data, tmp_path, capsys, rows):
    f = tmp_path / "few.csv"
    write_recording(read_recording(data / "train.csv").subset(np.arange(rows)), f)
    code = main(["fit", "--robot", "R1", "--train", str(f), "--method", "nls1", "--out", str(tmp_path / "m.yaml")])
    assert code in (0, 2)
    err = [line for line in capsys.readouterr().err.splitlines() if not line.startswith("warning:")]
    assert len(err) == (code == 2), err


def test_observability_of_fewer_equations_than_parameters_names_every_direction():
    from calibration.identification.observability import analyse_jacobian

    J = np.random.default_rng(0).normal(size=(1, 6, 12))  # one pose, 12 parameters
    obs = analyse_jacobian(J, np.ones(12), tuple(f"p{i}" for i in range(12)))
    assert obs.V.shape == (12, 12) and len(obs.singular_values) == 12
    assert obs.rank <= 6 and np.all(obs.singular_values[6:] == 0)


@pytest.mark.parametrize("case", ["seven rows", "copied rows"])
def test_diagnose_refuses_too_little_data_in_one_line(data, tmp_path, capsys, case):
    rec = read_recording(data / "train.csv")
    if case == "seven rows":
        rec = rec.subset(np.arange(7))
    else:
        rec = rec.subset(np.zeros(70, dtype=int))
        rec = Recording(rec.q, rec.p, rec.quat, {"cluster": np.arange(70) // 7}, rec.source)
    f = tmp_path / "d.csv"
    write_recording(rec, f)
    assert_bad_input(capsys, ["diagnose", "--robot", "R1", "--train", str(f), "--json", str(tmp_path / "j.json")],
                     str(f), "too few clusters" if case == "seven rows" else "no scatter")
    assert not (tmp_path / "j.json").exists()


def test_plan_nested_very_deep_is_one_line(tmp_path, capsys):
    f = tmp_path / "deep.json"
    f.write_text('{"schema": "cellcal.plan/1", "kind": "dual", "waypoints": ' + "[" * 200_000 + "]" * 200_000 + "}")
    assert_bad_input(capsys, ["export-targets", "--plan", str(f), "--out", str(tmp_path / "t.csv")],
                     str(f), "nested too deep")
    assert not (tmp_path / "t.csv").exists()


@pytest.mark.parametrize("content", [bytes(range(256)) * 4, b"[" * 200_000])
def test_binary_or_deep_path_file_is_one_line(tmp_path, capsys, content):
    f = tmp_path / "path.csv"
    f.write_bytes(content)
    assert_bad_input(capsys, ["plan-dual", "--path", str(f), "--out", str(tmp_path / "p.json")], str(f))
    assert not (tmp_path / "p.json").exists()


def _session(tmp_path, data):
    """A session folder with one measured sample, made through the store's own API."""
    from app.collection.plans.collection import Plan, Target
    from app.collection.session_store import Sample, SessionStore

    rec = read_recording(data / "train.csv")
    plan = Plan.from_dict({"schema": "cellcal.plan/1", "kind": "collection", "robot": "R1", "targets": [
        {"robot": "R1", "q_rad": list(rec.q[i]), "cluster": 0, "kind": "anchor"} for i in range(2)]}, "<plan>")
    with SessionStore(tmp_path / "s", create=True) as store:
        store.init(plan, {"robot": "R1"})
        for i in range(2):
            store.add_sample(Sample(i, rec.q[i], rec.p[i], rec.quat[i], 0.01, 0.01, 0.1, 10, float(i), np.zeros(6)),
                             "R1", "anchor", 0)
    del Target
    return tmp_path / "s"


@pytest.mark.parametrize("sql,fragment", [
    ("UPDATE samples SET x = 'abc' WHERE target_index = 1", "column x"),
    ("UPDATE samples SET q3 = NULL WHERE target_index = 0", "column q3"),
    ("UPDATE samples SET qw = 9e999 WHERE target_index = 1", "column qw"),
    ("UPDATE samples SET qw = 3.0 WHERE target_index = 1", "quaternion norm"),
    ("UPDATE samples SET cluster = 'a' WHERE target_index = 0", "column cluster"),
    ("UPDATE meta SET value = '{not json' WHERE key = 'info'", "'info'"),
    ("UPDATE meta SET value = '[1, 2]' WHERE key = 'info'", "'info'"),
    ("UPDATE meta SET value = '{\"schema\": 3}' WHERE key = 'plan'", "plan"),
    ("UPDATE meta SET value = 'nope' WHERE key = 'plan'", "'plan'"),
])
def test_export_of_a_damaged_session_database_is_one_line(data, tmp_path, capsys, sql, fragment):
    session = _session(tmp_path, data)
    with sqlite3.connect(session / "session.sqlite") as con:
        con.execute(sql)
    out = tmp_path / "out.csv"
    assert_bad_input(capsys, ["export", "--session", str(session), "--out", str(out)], "session.sqlite", fragment)
    assert not out.exists()


def test_an_undamaged_session_exports(data, tmp_path):
    session = _session(tmp_path, data)
    assert main(["export", "--session", str(session), "--out", str(tmp_path / "out.csv")]) == 0
    assert len(read_recording(tmp_path / "out.csv")) == 2


@pytest.mark.parametrize("factor,unit", [(1e-3, "metres"), (1 / 25.4, "inches"), (0.1, "centimetres")])
def test_a_recording_in_other_units_is_refused_before_any_fit(data, tmp_path, capsys, factor, unit):
    rec = read_recording(data / "train.csv")
    f = tmp_path / "units.csv"
    write_recording(Recording(rec.q, rec.p * factor, rec.quat, rec.extra, ""), f)
    for argv in (["rebase", "--model", str(data / "m.yaml"), "--data", str(f), "--out", str(tmp_path / "r.yaml")],
                 ["fit", "--robot", "R1", "--train", str(f), "--method", "nls1", "--out", str(tmp_path / "r.yaml")]):
        assert_bad_input(capsys, argv, str(f), unit, "millimetres")
        assert not (tmp_path / "r.yaml").exists()


def test_units_check_passes_a_recording_in_millimetres(data):
    from calibration.frames.rebase import check_units
    from calibration.models import load_model

    check_units(load_model(data / "m.yaml"), read_recording(data / "train.csv"))
    with pytest.raises(CellCalError):
        rec = read_recording(data / "train.csv")
        check_units(load_model(data / "m.yaml"), Recording(rec.q, rec.p * 10, rec.quat, {}, "x"))


@pytest.mark.parametrize("kind,key", [("dual", "waypoints"), ("collection", "targets")])
def test_plan_with_more_entries_than_the_limit_is_refused_before_they_are_read(tmp_path, monkeypatch, kind, key):
    import app.collection.plans.reader as plan_file

    monkeypatch.setattr(plan_file, "MAX_PLAN_ENTRIES", 5)
    f = tmp_path / "plan.json"
    f.write_text(json.dumps({"schema": "cellcal.plan/1", "kind": kind, key: [{}] * 6}))
    with pytest.raises(DataError, match="more than the limit of 5"):
        plan_file.read_plan(f)


@pytest.mark.parametrize("argv", [["export", "--out", "{T}/out.csv"], ["collect", "--robot", "R1", "--sim", "--resume"]])
def test_a_session_database_that_is_a_fifo_is_refused_at_once(tmp_path, capsys, argv):
    (tmp_path / "s").mkdir()
    os.mkfifo(tmp_path / "s" / "session.sqlite")
    argv = [a.replace("{T}", str(tmp_path)) for a in argv] + ["--session", str(tmp_path / "s")]
    assert finishes(lambda: assert_bad_input(capsys, argv, "session.sqlite", "FIFO"), 20.0) is None
    assert not (tmp_path / "out.csv").exists()
