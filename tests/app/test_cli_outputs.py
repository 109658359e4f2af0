"""Every output path of the CLI: atomic, the user's umask, never over a symlink, a device, a FIFO or a folder."""

import json
import os
import stat

import pytest

from app.cli.commands import main
from tests.conftest import assert_bad_input

PLAN = ["plan", "--robot", "R1", "--q2-step", "30", "--q3-step", "30", "--out"]


def _mode(path):
    return stat.S_IMODE(os.stat(path).st_mode)


def test_plan_out_follows_the_umask_and_keeps_an_existing_mode(tmp_path):
    old = os.umask(0o027)
    try:
        assert main(PLAN + [str(tmp_path / "new.json")]) == 0
    finally:
        os.umask(old)
    assert _mode(tmp_path / "new.json") == 0o640
    existing = tmp_path / "existing.json"
    existing.write_text("{}")
    os.chmod(existing, 0o644)
    old = os.umask(0o077)
    try:
        assert main(PLAN + [str(existing)]) == 0
    finally:
        os.umask(old)
    assert _mode(existing) == 0o644 and json.loads(existing.read_text())["targets"]


def test_plan_out_over_a_symlink_fifo_or_folder_is_refused_and_nothing_changes(tmp_path, capsys):
    real = tmp_path / "real.json"
    real.write_text("keep")
    link = tmp_path / "link.json"
    link.symlink_to(real)
    assert_bad_input(capsys, PLAN + [str(link)], "link.json", "is a symbolic link; refusing to replace it")
    assert link.is_symlink() and real.read_text() == "keep"
    fifo = tmp_path / "plan.fifo"
    os.mkfifo(fifo)
    assert_bad_input(capsys, PLAN + [str(fifo)], "plan.fifo", "is a FIFO; refusing to replace it")
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    assert_bad_input(capsys, PLAN + [str(tmp_path)], "is a folder")
    assert_bad_input(capsys, PLAN + [str(real / "under.json")], "not a folder")
    assert_bad_input(capsys, PLAN + [""], "empty output path")
    assert sorted(os.listdir(tmp_path)) == ["link.json", "plan.fifo", "real.json"]


def test_json_to_a_device_is_refused_before_any_work(tmp_path, capsys):
    # --json /dev/full used to replace the device node with a regular file when run as root
    assert_bad_input(capsys, ["evaluate", "--model", str(tmp_path / "missing.yaml"), "--test",
                              str(tmp_path / "missing.csv"), "--json", "/dev/null"],
                     "/dev/null: is a character device; refusing to replace it")
    assert stat.S_ISCHR(os.lstat("/dev/null").st_mode)


def test_a_failed_plan_write_leaves_the_old_plan_whole_and_no_temporary(tmp_path, capsys, monkeypatch):
    path = tmp_path / "plan.json"
    assert main(PLAN + [str(path)]) == 0
    before = path.read_bytes()

    def full(*args, **kwargs):
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(os, "fsync", full)
    assert_bad_input(capsys, PLAN[:4] + ["15", "--q3-step", "15", "--out", str(path)],
                     "plan.json: cannot write (No space left on device)")
    monkeypatch.undo()
    assert path.read_bytes() == before and os.listdir(tmp_path) == ["plan.json"]
