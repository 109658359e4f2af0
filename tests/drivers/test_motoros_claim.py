"""The controller claim (drivers.motoros.link.claim_controller) lives in a folder of this user only and never
follows a link planted there (issue 30: a symlink planted by user nobody made a root collect truncate its target,
write the command line into it and make it world-writable)."""

from __future__ import annotations

import os
import stat
import tempfile

import pytest

from drivers.errors import DriverError
from drivers.motoros.link import claim_controller, lock_dir


def _mode(path) -> int:
    return stat.S_IMODE(os.lstat(path).st_mode)


def test_a_symlink_planted_in_the_claim_folder_is_refused_and_its_target_untouched(tmp_path, monkeypatch) -> None:
    folder = tmp_path / "claims"
    folder.mkdir(mode=0o700)
    monkeypatch.setenv("CELLCAL_LOCK_DIR", str(folder))
    victim = tmp_path / "shadow"
    victim.write_text("root:x:0:0\n")
    victim.chmod(0o640)
    (folder / "motoros-127.0.0.1-50240.lock").symlink_to(victim)
    with pytest.raises(DriverError, match="motoros-127.0.0.1-50240.lock: the lock file is a symbolic link"):
        claim_controller("127.0.0.1", 50240, "motoros@127.0.0.1:50240")
    assert victim.read_text() == "root:x:0:0\n" and _mode(victim) == 0o640


def test_a_claim_folder_others_can_write_is_refused_before_any_file_is_made(tmp_path, monkeypatch) -> None:
    folder = tmp_path / "claims"
    folder.mkdir()
    folder.chmod(0o1777)  # the old shared default
    monkeypatch.setenv("CELLCAL_LOCK_DIR", str(folder))
    with pytest.raises(DriverError, match=r"claims: writable by other users \(mode 1777\)"):
        claim_controller("127.0.0.1", 50240, "x")
    assert list(folder.iterdir()) == []


def test_the_default_claim_folder_is_this_users_own_and_the_claim_is_private(tmp_path, monkeypatch) -> None:
    monkeypatch.delenv("CELLCAL_LOCK_DIR", raising=False)
    monkeypatch.delenv("XDG_RUNTIME_DIR", raising=False)
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    assert lock_dir() == tmp_path / f"cellcal-locks-{os.geteuid()}"
    claim = claim_controller("127.0.0.1", 50240, "x")
    try:
        assert _mode(lock_dir()) == 0o700
        assert _mode(lock_dir() / "motoros-127.0.0.1-50240.lock") == 0o600  # the command line: this user only
    finally:
        claim.release()
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path / "run"))
    (tmp_path / "run").mkdir(mode=0o700)
    assert lock_dir() == tmp_path / "run" / "cellcal-locks"
