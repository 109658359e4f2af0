"""Atomic output files: umask and existing modes kept, symlinks and devices refused, failures leave no trace."""

import json
import os
import stat

import pytest

from calibration.data.files import atomic_open, atomic_write_bytes, atomic_write_text, check_output_path
from calibration.errors import OutputError


def _mode(path):
    return stat.S_IMODE(os.stat(path).st_mode)


@pytest.mark.parametrize("umask", [0o022, 0o027, 0o077])
def test_new_file_mode_follows_the_umask_like_open(tmp_path, umask):
    old = os.umask(umask)
    try:
        atomic_write_text(tmp_path / "new.json", "{}\n")
        with open(tmp_path / "plain.json", "w") as f:
            f.write("{}\n")
    finally:
        os.umask(old)
    assert _mode(tmp_path / "new.json") == _mode(tmp_path / "plain.json") == 0o666 & ~umask


def test_existing_file_keeps_its_mode_and_gets_the_new_content(tmp_path):
    path = tmp_path / "report.md"
    path.write_text("old")
    os.chmod(path, 0o644)
    old = os.umask(0o077)
    try:
        atomic_write_text(path, "new")
    finally:
        os.umask(old)
    assert _mode(path) == 0o644 and path.read_text() == "new"
    os.chmod(path, 0o600)
    atomic_write_bytes(path, b"\x89PNG")
    assert _mode(path) == 0o600 and path.read_bytes() == b"\x89PNG"


def test_a_symlink_is_refused_and_left_untouched(tmp_path):
    real = tmp_path / "real.json"
    real.write_text("keep")
    link = tmp_path / "link.json"
    link.symlink_to(real)
    with pytest.raises(OutputError, match="is a symbolic link; refusing to replace it") as e:
        atomic_write_text(link, "new")
    assert e.value.path == str(link)
    dangling = tmp_path / "dangling.json"
    dangling.symlink_to(tmp_path / "nowhere.json")
    with pytest.raises(OutputError, match="symbolic link"):
        atomic_write_text(dangling, "new")
    assert link.is_symlink() and os.readlink(link) == str(real) and real.read_text() == "keep"
    assert dangling.is_symlink() and not (tmp_path / "nowhere.json").exists()
    assert sorted(os.listdir(tmp_path)) == ["dangling.json", "link.json", "real.json"]


def test_devices_fifos_and_folders_are_refused(tmp_path):
    fifo = tmp_path / "out.fifo"
    os.mkfifo(fifo)
    with pytest.raises(OutputError, match="is a FIFO; refusing to replace it"):
        atomic_write_text(fifo, "x")
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    with pytest.raises(OutputError, match="/dev/null: is a character device; refusing to replace it"):
        check_output_path("/dev/null")
    assert stat.S_ISCHR(os.lstat("/dev/null").st_mode)
    with pytest.raises(OutputError, match="is a folder; refusing .*give a file name inside it"):
        atomic_write_text(tmp_path, "x")
    assert sorted(os.listdir(tmp_path)) == ["out.fifo"]


def test_empty_paths_and_paths_under_a_file_are_refused(tmp_path):
    with pytest.raises(OutputError, match="empty output path"):
        atomic_write_text("", "x")
    (tmp_path / "file").write_text("keep")
    for bad in (tmp_path / "file" / "out.json", tmp_path / "file" / "sub" / "out.json"):
        with pytest.raises(OutputError, match="not a folder"):
            atomic_write_text(bad, "x")
    assert (tmp_path / "file").read_text() == "keep"
    atomic_write_text(tmp_path / "new" / "deeper" / "out.json", "x")  # missing folders are created
    assert (tmp_path / "new" / "deeper" / "out.json").read_text() == "x"


def test_a_failed_serialisation_midway_leaves_the_old_file_and_no_temporary(tmp_path):
    path = tmp_path / "plan.json"
    path.write_text('{"old": true}\n')
    with pytest.raises(TypeError):
        with atomic_open(path) as f:
            json.dump({"a": list(range(1000)), "b": object()}, f)  # fails after writing part of the document
    assert path.read_text() == '{"old": true}\n'
    assert os.listdir(tmp_path) == ["plan.json"]


@pytest.mark.parametrize("failing", ["replace", "fsync"])
def test_a_failed_write_is_an_output_error_and_leaves_the_old_file(tmp_path, monkeypatch, failing):
    path = tmp_path / "out.csv"
    path.write_text("old")

    def fail(*args, **kwargs):
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(os, failing, fail)
    with pytest.raises(OutputError, match="out.csv: cannot write .No space left on device."):
        atomic_write_text(path, "new")
    monkeypatch.undo()
    assert path.read_text() == "old" and os.listdir(tmp_path) == ["out.csv"]


# -- the exclusive lock: never follows a planted link, never widens a mode ---------------------------------------


@pytest.mark.parametrize("plant", ["symlink", "hardlink", "fifo"])
def test_a_lock_refuses_anything_but_its_own_regular_file_and_leaves_it_untouched(tmp_path, plant):
    """A symlink planted where a lock goes made a root collector truncate its target, write into it and make it
    world-writable (issue 30): the lock is opened with O_NOFOLLOW and must be a regular file with one link."""
    from calibration.data.files import ExclusiveLock

    victim = tmp_path / "victim.conf"
    victim.write_text("precious\n")
    victim.chmod(0o600)
    lock = tmp_path / "x.lock"
    {"symlink": lambda: lock.symlink_to(victim), "hardlink": lambda: os.link(victim, lock),
     "fifo": lambda: os.mkfifo(lock)}[plant]()
    with pytest.raises(OSError, match="symbolic link|links|not a regular file"):
        ExclusiveLock(lock, "pid 1: cellcal collect")
    assert victim.read_text() == "precious\n" and _mode(victim) == 0o600


def test_a_lock_file_is_created_with_the_given_mode_and_an_existing_one_keeps_its_mode(tmp_path):
    from calibration.data.files import ExclusiveLock, LockHeld

    old = os.umask(0o022)
    try:
        first = ExclusiveLock(tmp_path / "a.lock", "pid 1", mode=0o600)
    finally:
        os.umask(old)
    assert _mode(tmp_path / "a.lock") == 0o600 and (tmp_path / "a.lock").read_text() == "pid 1"
    with pytest.raises(LockHeld) as held:
        ExclusiveLock(tmp_path / "a.lock", "pid 2", mode=0o666)
    assert held.value.holder == "pid 1" and _mode(tmp_path / "a.lock") == 0o600  # never widened to 0666
    first.release()


def test_a_private_folder_is_created_0700_and_a_shared_or_linked_one_is_refused(tmp_path):
    from calibration.data.files import private_folder

    made = private_folder(tmp_path / "mine" / "locks")
    assert _mode(made) == 0o700
    shared = tmp_path / "shared"
    shared.mkdir()
    shared.chmod(0o1777)  # the old claim folder's mode
    with pytest.raises(OSError, match=r"writable by other users \(mode 1777\)"):
        private_folder(shared)
    (tmp_path / "link").symlink_to(made)
    with pytest.raises(OSError, match="not a folder"):
        private_folder(tmp_path / "link")
