"""A command's set of outputs takes its names together or not at all (issue 30): on a full disk
``evaluate --report R --json J`` had left J and half of R (a PNG, no report.html), and export empty folders."""

from __future__ import annotations

import errno
import json
import os

import numpy as np
import pytest

import calibration.data.files as files
from app.cli.commands import main
from calibration.data.files import atomic_write_text, staged_outputs
from calibration.data.recording import write_recording
from calibration.errors import OutputError
from tests.conftest import cluster_design, measure


def disk_full_at(monkeypatch, k: int) -> None:
    """The k-th file written from now on (counted at its fsync) fails as a full disk does (ENOSPC)."""
    real = os.fsync
    seen = {"files": 0}

    def fsync(fd: int) -> None:
        if os.path.isfile(f"/proc/self/fd/{fd}"):
            seen["files"] += 1
            if seen["files"] == k:
                raise OSError(errno.ENOSPC, "No space left on device")
        real(fd)

    monkeypatch.setattr(files.os, "fsync", fsync)


def left_in(folder) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


@pytest.mark.parametrize("fail_at", [1, 2, 3])
def test_a_staged_set_is_all_or_nothing_and_leaves_no_folder_or_temporary(tmp_path, monkeypatch, fail_at):
    (tmp_path / "old.json").write_text("old\n")
    disk_full_at(monkeypatch, fail_at)
    with pytest.raises(OutputError, match="No space left on device"):
        with staged_outputs():
            atomic_write_text(tmp_path / "old.json", "new\n")
            files.make_folders(tmp_path / "r" / "deep")
            atomic_write_text(tmp_path / "r" / "deep" / "a.png", "a")
            atomic_write_text(tmp_path / "r" / "report.html", "<html>")
    assert left_in(tmp_path) == ["old.json"] and (tmp_path / "old.json").read_text() == "old\n"


def test_a_staged_set_takes_its_names_only_at_the_end(tmp_path):
    with staged_outputs():
        atomic_write_text(tmp_path / "r" / "a.txt", "a")
        assert not (tmp_path / "r" / "a.txt").exists()  # still under its temporary name
        with staged_outputs():  # nested: the outer block commits
            atomic_write_text(tmp_path / "b.txt", "b")
        assert not (tmp_path / "b.txt").exists()
    assert (tmp_path / "r" / "a.txt").read_text() == "a" and (tmp_path / "b.txt").read_text() == "b"
    assert left_in(tmp_path) == ["b.txt", "r", "r/a.txt"]


def test_a_failed_single_write_removes_the_folders_it_made(tmp_path, monkeypatch):
    disk_full_at(monkeypatch, 1)
    with pytest.raises(OutputError, match="No space left"):
        atomic_write_text(tmp_path / "new" / "deeper" / "x.csv", "x")
    assert left_in(tmp_path) == []


@pytest.fixture(scope="module")
def fitted(tmp_path_factory, synthetic_arm):
    _, _, truth = synthetic_arm
    root = tmp_path_factory.mktemp("fitted")
    q, cluster = cluster_design(step_deg=30.0)
    write_recording(measure(truth.fk, q, 0.02, 0.01, 1, cluster), root / "train.csv")
    q_test = np.random.default_rng(3).uniform(-0.8, 0.8, (40, 6))
    write_recording(measure(truth.fk, q_test, 0.02, 0.01, 2), root / "test.csv")
    assert main(["fit", "--robot", "R1", "--train", str(root / "train.csv"), "--method", "nls1", "--out",
                 str(root / "m.yaml")]) == 0
    return root


@pytest.mark.parametrize("fail_at", [1, 2, 4])
def test_evaluate_on_a_full_disk_leaves_neither_the_json_nor_part_of_the_report(tmp_path, fitted, capsys,
                                                                                monkeypatch, fail_at):
    out = tmp_path / "out"
    args = ["evaluate", "--model", str(fitted / "m.yaml"), "--test", str(fitted / "test.csv"), "--json",
            str(out / "e.json"), "--report", str(out / "report")]
    disk_full_at(monkeypatch, fail_at)  # 1: the JSON; 2: the first plot; 4: a later one
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "No space left on device" in err and "Traceback" not in err
    assert left_in(tmp_path) == []  # not even the folders
    monkeypatch.setattr(files.os, "fsync", os.fsync)  # room again
    assert main(args) == 0
    assert (out / "report" / "report.html").exists() and json.loads((out / "e.json").read_text())["samples"] == 40


def test_export_on_a_full_disk_leaves_no_csv_and_no_folder(tmp_path, capsys, monkeypatch):
    from app.collection.plans.poses import build_plan, plan_anchor_grid
    from app.collection.session_store import Sample, SessionStore

    plan = build_plan(plan_anchor_grid(q2_range_deg=(-55.0, 35.0), q2_step_deg=45.0, q3_step_deg=30.0))
    with SessionStore(tmp_path / "s", create=True) as store:
        store.init(plan, {"robot": "R1"})
        store.add_sample(Sample(0, plan.q[0], np.ones(3), np.array([1.0, 0, 0, 0]), 0.01, 0.001, 0.1, 20, 1.0,
                                np.zeros(6)), "R1", "anchor", 0)
    out = tmp_path / "new" / "deeper"
    disk_full_at(monkeypatch, 2)  # the recording is written, the JSON is not
    assert main(["export", "--session", str(tmp_path / "s"), "--out", str(out / "x.csv"), "--json",
                 str(out / "x.json")]) == 2
    assert "No space left on device" in capsys.readouterr().err
    assert not (tmp_path / "new").exists()


def test_fit_on_a_full_disk_leaves_no_model_without_its_json(tmp_path, fitted, capsys, monkeypatch):
    """The class, not the instance: every command of app.cli.commands.STAGED_COMMANDS writes its set staged."""
    disk_full_at(monkeypatch, 2)  # the model is written, the JSON is not
    assert main(["fit", "--robot", "R1", "--train", str(fitted / "train.csv"), "--method", "nls1", "--out",
                 str(tmp_path / "m" / "m.yaml"), "--json", str(tmp_path / "m" / "fit.json")]) == 2
    assert "No space left on device" in capsys.readouterr().err
    assert left_in(tmp_path) == []


@pytest.fixture(scope="module")
def dual_plan(tmp_path_factory):
    root = tmp_path_factory.mktemp("dual")
    assert main(["plan-dual", "--path", "sweep:20", "--out", str(root / "plan.json")]) == 0
    return root / "plan.json"


def _job(tmp_path) -> str:
    from cell_config import load_cell

    spec = load_cell().robot("R1").robot
    pulses = ",".join(str(int(v)) for v in spec.to_pulses(np.radians([[5.0, 10.0, -5.0, 20.0, -30.0, 10.0]]))[0])
    job = tmp_path / "IN.JBI"
    job.write_bytes("\r\n".join(["/JOB", "//NAME T", "//POS", "///NPOS 1,0,0,0,0,0", "///TOOL 0", "///POSTYPE PULSE",
                                 "///PULSE", f"C00000={pulses}", "//INST", "///DATE 2026/12/01 12:00", "///ATTR SC,RW",
                                 "///GROUP1 RB1", "NOP", "MOVJ C00000 VJ=10.00", "END", ""]).encode())
    return str(job)


@pytest.mark.parametrize("command", ["diagnose", "plan-dual", "export-targets", "export-urdf", "compensate-job"])
def test_every_command_writing_a_set_leaves_nothing_on_a_full_disk(tmp_path, fitted, dual_plan, capsys, monkeypatch,
                                                                  command):
    """The class: each command of STAGED_COMMANDS that writes more than one file, its second file failing."""
    from app.cli.commands import STAGED_COMMANDS

    assert command in STAGED_COMMANDS
    out = tmp_path / "new" / "out"
    model = str(fitted / "m.yaml")
    argv = {"diagnose": ["diagnose", "--robot", "R1", "--data", str(fitted / "train.csv"), "--report",
                         str(out / "report"), "--json", str(out / "d.json")],
            "plan-dual": ["plan-dual", "--path", "sweep:20", "--out", str(out / "p.json"), "--json",
                          str(out / "s.json")],
            "export-targets": ["export-targets", "--plan", str(dual_plan), "--out", str(out / "t.csv"), "--json",
                               str(out / "t.json")],
            "export-urdf": ["export-urdf", "--model", model, "--out", str(out / "r1.urdf"), "--json",
                            str(out / "u.json")],
            "compensate-job": ["compensate-job", "--model", model, "--job", _job(tmp_path), "--out",
                               str(out / "OUT.JBI"), "--json", str(out / "c.json")]}[command]
    disk_full_at(monkeypatch, 2)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "No space left on device" in err and "Traceback" not in err
    assert not (tmp_path / "new").exists()
    monkeypatch.setattr(files.os, "fsync", os.fsync)  # room again
    assert main(argv) == 0
    assert sum(1 for p in out.rglob("*") if p.is_file()) >= 2
