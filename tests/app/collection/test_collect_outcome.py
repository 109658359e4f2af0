"""What ``cellcal collect`` says and returns when targets stay unmeasured, and when the disk is full (issue 30)."""

from __future__ import annotations

import json

import pytest
from conftest import SIM_FAST

from app.cli.commands import main
from app.collection.session_store import SessionStore
from calibration.errors import DataError


@pytest.fixture(scope="module")
def plan(tmp_path_factory):
    path = tmp_path_factory.mktemp("plan") / "plan.json"
    assert main(["plan", "--robot", "R1", "--out", str(path), "--design", "grid", "--q2-step", "90", "--q3-step", "90"]) == 0
    return path


def collect(session, *extra):
    return main(["collect", "--robot", "R1", "--session", str(session), "--sim", *SIM_FAST, "--no-progress", *extra])


def test_a_run_that_leaves_targets_unmeasured_says_so_and_exits_2_unless_accepted(tmp_path, plan, capsys,
                                                                                    monkeypatch):
    """A collection that skipped targets ended exit 0, and its resume changed nothing (issue 30)."""
    real_add = SessionStore.add_sample

    def refuse_target_2(self, s, *args, **kwargs):  # a lasting cause: the store refuses target 2's sample
        if s.target_index == 2:
            raise DataError(self.path, None, "target 2", "quaternion norm 1.2 is not 1")
        return real_add(self, s, *args, **kwargs)

    session = tmp_path / "s"
    monkeypatch.setattr(SessionStore, "add_sample", refuse_target_2)
    assert collect(session, "--plan", str(plan), "--json", str(tmp_path / "c.json")) == 2
    out, err = capsys.readouterr()
    n = json.loads((tmp_path / "c.json").read_text())["targets"]
    assert f"{n - 1} of {n} targets measured, 1 skipped" in out and "skipped target 2: sample rejected" in out
    last = err.strip().splitlines()[-1]
    assert "Traceback" not in err and last.startswith(f"cellcal collect: R1: 1 of {n} targets not measured")
    assert "--accept-skipped" in last
    assert json.loads((tmp_path / "c.json").read_text())["unmeasured"] == 1
    assert collect(session, "--resume") == 2  # a lasting cause is not measured again by a plain resume
    assert "0 new this run" in capsys.readouterr().out
    assert collect(session, "--resume", "--accept-skipped") == 0
    monkeypatch.setattr(SessionStore, "add_sample", real_add)
    assert collect(session, "--resume", "--retry-skipped", "--json", str(tmp_path / "c.json")) == 0
    assert f"{n} of {n} targets measured, 0 skipped, 1 new" in capsys.readouterr().out
    assert json.loads((tmp_path / "c.json").read_text())["unmeasured"] == 0
    assert collect(tmp_path / "new", "--plan", str(plan), "--retry-skipped") == 2
    assert "--retry-skipped applies to --resume only" in capsys.readouterr().err


def test_a_full_disk_during_collect_is_one_line_and_exit_2_and_the_session_resumes(tmp_path, plan, capsys,
                                                                                  monkeypatch):
    """It was an sqlite3.OperationalError traceback, exit 1 (issue 30). SQLite's own 'database or disk is full'
    (SQLITE_FULL) is raised by capping the file's pages at what it holds once 3 samples are in."""
    real_add = SessionStore.add_sample

    def fill_the_disk(self, s, *args, **kwargs):
        if s.target_index == 3:
            pages = self.conn.execute("PRAGMA page_count").fetchone()[0]
            self.conn.execute(f"PRAGMA max_page_count = {pages}")
            self.conn.execute("PRAGMA wal_checkpoint(TRUNCATE)")  # the WAL's pages count as the file's once written
        return real_add(self, s, *args, **kwargs)

    session = tmp_path / "s"
    monkeypatch.setattr(SessionStore, "add_sample", fill_the_disk)
    assert collect(session, "--plan", str(plan)) == 2
    err = capsys.readouterr().err
    last = err.strip().splitlines()[-1]
    assert "Traceback" not in err and last.startswith("cellcal collect: "), err
    assert f"{session / 'session.sqlite'}: cannot write the session (database or disk is full)" in last
    assert "resume" in last
    monkeypatch.setattr(SessionStore, "add_sample", real_add)  # room again
    assert collect(session, "--resume") == 0
    with SessionStore(session, lock=False) as store:
        assert sorted(r["target_index"] for r in store.rows("ok")) == list(range(len(store.plan())))
