"""Session guards on the simulated cell: one collector per folder, killed creation, faults stop every arm, NaN feedback.

Real processes where it matters: the lock is held by a child process, creation is SIGKILLed in a child.
"""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from sim_cell import FAST, R2_PARK, make_cell, small_plan

from app.collection.collect import SessionAborted, run_session
from app.collection.motion import NonFiniteFeedback, move_safely
from app.collection.plans.poses import build_plan
from app.collection.session_store import SessionLocked, SessionStore
from calibration.errors import DataError
from drivers.base import MocapSource
from drivers.errors import DriverError
from drivers.sim import SimFault, SimRobotConfig, SimRobotDriver, planted_truth
from tests.conftest import SIM_FAST

ROOT = Path(__file__).resolve().parents[3]
OTHERS = {"R2": R2_PARK}
ENV = dict(os.environ, PYTHONPATH=f"{ROOT}{os.pathsep}{ROOT / 'tests/app/collection'}")


def first(n: int):
    return build_plan(small_plan().targets[:n])


def child(code: str, *args: str) -> subprocess.Popen:
    """A Python child process running ``code``; it prints one line when it reached the interesting point."""
    return subprocess.Popen([sys.executable, "-c", code, *args], env=ENV, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def wait_line(proc: subprocess.Popen, expected: str) -> None:
    line = proc.stdout.readline().strip()
    assert line == expected, f"child said {line!r}: {proc.stderr.read()[-2000:] if proc.poll() is not None else ''}"


def kill(proc: subprocess.Popen) -> None:
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    proc.stdout.close()
    proc.stderr.close()


# ---- 1. one collector per session folder ------------------------------------------------------------------

HOLD = """
import sys, time
from app.collection.session_store import SessionStore
store = SessionStore(sys.argv[1], create=sys.argv[2] == "create")
print("locked", flush=True)
time.sleep(60)
"""


def test_a_second_resume_or_collector_is_refused_at_once_before_any_motion(tmp_path):
    session, fresh = tmp_path / "s", tmp_path / "fresh"
    with SessionStore(session, create=True) as store:
        store.init(first(3), {"robot": "R1"})
    holders = [child(HOLD, str(session), "open"), child(HOLD, str(fresh), "create")]
    try:
        for h in holders:
            wait_line(h, "locked")
        _, driver, mocap, _, safety = make_cell()
        with driver, mocap:
            q0 = driver.read_joints().q
            t0 = time.monotonic()
            with pytest.raises(SessionLocked, match=f"in use by process {holders[0].pid}") as e:
                run_session(session, driver, mocap, safety, body_id=1, others=OTHERS, config=FAST, resume=True,
                            progress=False)
            assert e.value.folder == session and e.value.pid == holders[0].pid and str(session) in str(e.value)
            with pytest.raises(SessionLocked, match=f"in use by process {holders[0].pid}"):
                run_session(session, driver, mocap, safety, body_id=1, plan=first(3), others=OTHERS, config=FAST,
                            progress=False)
            with pytest.raises(SessionLocked, match=f"in use by process {holders[1].pid}"):
                run_session(fresh, driver, mocap, safety, body_id=1, plan=first(3), others=OTHERS, config=FAST,
                            progress=False)
            assert time.monotonic() - t0 < 2.0  # refused at once, no waiting on the lock
            assert driver.move_calls == 0
            np.testing.assert_array_equal(driver.read_joints().q, q0)
            kill(holders[0])  # the kernel drops a dead holder's lock: the session can be resumed at once
            res = run_session(session, driver, mocap, safety, body_id=1, others=OTHERS, config=FAST, resume=True,
                              progress=False)
        assert res.complete and res.n_new == 3
    finally:
        for h in holders:
            if h.poll() is None:
                kill(h)


def test_the_lock_is_held_for_the_stores_lifetime_only(tmp_path):
    store = SessionStore(tmp_path / "s", create=True)
    store.init(first(2), {})
    assert (tmp_path / "s" / "session.lock").read_text().strip() == str(os.getpid())
    with pytest.raises(SessionLocked):
        SessionStore(tmp_path / "s")
    SessionStore(tmp_path / "s", lock=False).close()  # a reader (export) does not need the lock
    store.close()
    SessionStore(tmp_path / "s").close()


# ---- 2. a kill during creation ----------------------------------------------------------------------------

CREATE = """
import sys, time
import app.collection.session_store as ss
from app.collection.collect import run_session
from app.collection.plans.poses import build_plan
from sim_cell import FAST, R2_PARK, make_cell, small_plan

def hook(stage):
    if stage == sys.argv[2]:
        print(stage, flush=True)
        time.sleep(60)

ss.creation_hook = hook
_, driver, mocap, _, safety = make_cell()
with driver, mocap:
    run_session(sys.argv[1], driver, mocap, safety, body_id=1, plan=build_plan(small_plan().targets[:3]),
                others={"R2": R2_PARK}, config=FAST, progress=False)
"""


@pytest.mark.parametrize("stage", ["schema", "init"])
def test_a_kill_during_creation_leaves_a_folder_a_new_collect_takes_over(tmp_path, stage):
    session = tmp_path / "s"
    proc = child(CREATE, str(session), stage)
    try:
        wait_line(proc, stage)
        assert (session / "session.sqlite").exists()
    finally:
        kill(proc)
    assert not SessionStore.exists(session)
    _, driver, mocap, _, safety = make_cell()
    with driver, mocap:
        with pytest.raises(DataError, match="nothing to resume; start a new collect"):
            run_session(session, driver, mocap, safety, body_id=1, others=OTHERS, config=FAST, resume=True,
                        progress=False)
        assert driver.move_calls == 0
        res = run_session(session, driver, mocap, safety, body_id=1, plan=first(3), others=OTHERS, config=FAST,
                          progress=False)
    assert res.complete and res.n_ok == 3 and SessionStore.exists(session)
    with SessionStore(session) as store:
        assert store.plan().to_dict() == first(3).to_dict() and store.info()["robot"] == "R1"
    with sqlite3.connect(session / "session.sqlite") as con:
        assert con.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
        assert con.execute("SELECT COUNT(*) FROM meta WHERE key = 'plan'").fetchone()[0] == 1


# ---- 3. faults stop every arm, are recorded, and the session stays resumable ---------------------------------

class AfterMoves(MocapSource):
    """Runs ``action`` once, as soon as ``driver`` has made ``n`` moves (read during the next dwell window)."""

    def __init__(self, inner: MocapSource, driver, n: int, action) -> None:
        self.inner, self.driver, self.n, self.action = inner, driver, n, action

    def connect(self) -> None:
        self.inner.connect()

    def close(self) -> None:
        self.inner.close()

    def read(self, timeout_s: float):
        if self.action is not None and self.driver.move_count >= self.n:
            self.action, action = None, self.action
            action()
        return self.inner.read(timeout_s)


def two_arms():
    """The R1 cell plus a simulated R2 on the same clock, turning its wrist slowly (it is moving when a fault hits)."""
    cell, r1, mocap, _, safety = make_cell()
    r2_spec = cell.robot("R2")
    r2 = SimRobotDriver("R2", r2_spec.robot, planted_truth(r2_spec.model(), seed=2), q0=R2_PARK, clock=r1.clock,
                        config=SimRobotConfig(settle_time_s=0.2))
    r2.connect()
    r2.move_to(R2_PARK + np.radians([0, 0, 0, 0, 0, 90]), 0.002)  # ~100 simulated seconds
    return r1, r2, mocap, safety


def halted(driver) -> bool:
    t = driver.clock.now()
    q = driver.true_joints(np.array([t, t + 5.0]))
    return bool(np.all(q[0] == q[1]))


def resume_finishes(session: Path, r1, r2, mocap, safety, n: int):
    r1.clear_faults()
    r2.clear_faults()
    r2.connect()
    res = run_session(session, r1, mocap, safety, body_id=1, other_drivers={"R2": r2}, config=FAST, resume=True,
                      progress=False)
    assert res.complete and res.n_ok == n and res.n_skipped == 0
    with SessionStore(session) as store:
        assert [r["target_index"] for r in store.rows()] == list(range(n))
    return res


@pytest.mark.parametrize("fault, kind", [(SimFault.ALARM, "alarm"), (SimFault.ESTOP, "e-stop")])
def test_an_alarm_of_the_arm_stops_both_arms_is_recorded_and_resumable(tmp_path, fault, kind):
    r1, r2, mocap, safety = two_arms()
    r1.schedule_fault(fault, at_call=3)
    t0 = time.time()
    with r1, mocap:
        with pytest.raises(SessionAborted, match=f"R1 {kind} at target 2: .*every arm stopped") as e:
            run_session(tmp_path / "s", r1, mocap, safety, body_id=1, plan=first(6), other_drivers={"R2": r2},
                        config=FAST, progress=False)
        assert (e.value.robot, e.value.kind) == ("R1", kind) and r1.move_calls == 3  # not retried
        assert halted(r2) and halted(r1) and r2.move_count == 1
        with SessionStore(tmp_path / "s") as store:
            (ev,), done = store.events(), store.done()
        assert (ev.robot, ev.kind, ev.target_index) == ("R1", kind, 2) and t0 <= ev.t_wall <= time.time()
        assert fault.value in ev.reason and done == {0, 1}
        res = resume_finishes(tmp_path / "s", r1, r2, mocap, safety, 6)
    assert res.n_new == 4


@pytest.mark.parametrize("fault, kind", [(SimFault.ALARM, "alarm"), (SimFault.DISCONNECT, "connection-lost"),
                                         (SimFault.NAN_FEEDBACK, "bad-feedback")])
def test_a_fault_of_the_other_arm_stops_both_arms_and_is_recorded(tmp_path, fault, kind):
    r1, r2, mocap, safety = two_arms()
    flaky = AfterMoves(mocap, r1, 2, lambda: r2.inject_fault(fault))
    with r1, flaky:
        with pytest.raises(SessionAborted, match=f"R2 {kind} at target 2"):
            run_session(tmp_path / "s", r1, flaky, safety, body_id=1, plan=first(5), other_drivers={"R2": r2},
                        config=FAST, progress=False)
        assert r1.move_calls == 2 and halted(r1) and halted(r2)
        with SessionStore(tmp_path / "s") as store:
            assert [(e.robot, e.kind) for e in store.events()] == [("R2", kind)]
        resume_finishes(tmp_path / "s", r1, r2, mocap, safety, 5)


def test_a_dropped_connection_stops_both_arms_is_recorded_and_the_session_carries_on(tmp_path):
    r1, r2, mocap, safety = two_arms()
    r1.schedule_fault(SimFault.DISCONNECT, at_call=2)
    with r1, mocap:
        res = run_session(tmp_path / "s", r1, mocap, safety, body_id=1, plan=first(4), other_drivers={"R2": r2},
                          config=FAST, progress=False)
        assert res.complete and res.n_ok == 4 and halted(r2)
        with SessionStore(tmp_path / "s") as store:
            (ev,) = store.events()
    assert (ev.robot, ev.kind, ev.target_index) == ("R1", "connection-lost", 1) and "connection lost" in ev.reason


# ---- 4. non-finite joint feedback ---------------------------------------------------------------------------

@pytest.mark.parametrize("at_call", [None, 2])
def test_nan_joint_feedback_is_a_driver_error_and_never_reaches_move_to(tmp_path, at_call):
    _, driver, mocap, _, safety = make_cell()
    with driver, mocap:
        if at_call is None:
            driver.inject_fault(SimFault.NAN_FEEDBACK)  # before the first move
        else:
            driver.schedule_fault(SimFault.NAN_FEEDBACK, at_call=at_call)  # that move happens, then NaN
        with pytest.raises(SessionAborted, match="R1 bad-feedback.*not 6 finite numbers") as e:
            run_session(tmp_path / "s", driver, mocap, safety, body_id=1, plan=first(4), others=OTHERS,
                        config=FAST, progress=False)
        assert isinstance(e.value.__cause__, NonFiniteFeedback) and isinstance(e.value.__cause__, DriverError)
        assert driver.move_calls == (at_call or 0)
        with pytest.raises(NonFiniteFeedback, match="R1 joint feedback is not 6 finite numbers"):
            move_safely(driver, first(1).targets[0].q, safety, {}, FAST.speed_fraction)
        assert driver.move_calls == (at_call or 0)
        with SessionStore(tmp_path / "s") as store:
            assert [e.kind for e in store.events()] == ["bad-feedback"] and not store.rows("skipped")
        driver.clear_faults()
        res = run_session(tmp_path / "s", driver, mocap, safety, body_id=1, others=OTHERS, config=FAST, resume=True,
                          progress=False)
    assert res.complete and res.n_ok == 4


# ---- the CLI ------------------------------------------------------------------------------------------------

def test_cli_collect_prints_the_recorded_stops_and_refuses_a_locked_session(tmp_path, capsys):
    import json

    from app.cli.commands import main
    from tests.conftest import assert_bad_input

    session = tmp_path / "s"
    _, driver, mocap, _, safety = make_cell()
    driver.schedule_fault(SimFault.ALARM, at_call=2)
    with driver, mocap:
        with pytest.raises(SessionAborted):
            run_session(session, driver, mocap, safety, body_id=1, plan=first(2), others=OTHERS, config=FAST,
                        progress=False)
        driver.clear_faults()
        run_session(session, driver, mocap, safety, body_id=1, others=OTHERS, config=FAST, resume=True,
                    progress=False)
    argv = ["collect", "--robot", "R1", "--session", str(session), "--resume", "--sim", *SIM_FAST, "--no-progress"]
    holder = child(HOLD, str(session), "open")
    try:
        wait_line(holder, "locked")
        assert_bad_input(capsys, argv, f"in use by process {holder.pid}", str(session))
    finally:
        kill(holder)
    assert main(argv + ["--json", str(tmp_path / "out.json")]) == 0
    out = capsys.readouterr().out
    assert "2 of 2 targets measured" in out and "1 stop(s) recorded" in out
    assert "R1 alarm at target 1: sim:R1: alarm (injected)" in out
    (event,) = json.loads((tmp_path / "out.json").read_text())["events"]
    assert (event["robot"], event["kind"], event["target_index"]) == ("R1", "alarm", 1)


def test_export_of_an_empty_session_file_writes_nothing_into_it(tmp_path, capsys):
    """Issue 12: `export` on an empty session.sqlite used to create the session tables in it."""
    from tests.conftest import assert_bad_input

    session = tmp_path / "s"
    session.mkdir()
    (session / "session.sqlite").touch()
    assert_bad_input(capsys, ["export", "--session", str(session), "--out", str(tmp_path / "r.csv")],
                     "no session here", "empty", "nothing to export")
    assert (session / "session.sqlite").stat().st_size == 0
    assert sorted(p.name for p in session.iterdir()) == ["session.sqlite"]  # no lock, no WAL, no journal
    assert not (tmp_path / "r.csv").exists()


def test_export_of_a_folder_without_a_session_says_so_for_export(tmp_path, capsys):
    """export of a mistyped session folder said 'nothing to resume; start a new collect', worded for collect."""
    from app.cli import main
    from tests.conftest import assert_bad_input

    assert_bad_input(capsys, ["export", "--session", str(tmp_path / "nosuch"), "--out", str(tmp_path / "r.csv")],
                     "nosuch", "no session here (session.sqlite not found): nothing to export", "cellcal collect")
    assert main(["export", "--session", str(tmp_path / "nosuch"), "--out", str(tmp_path / "r.csv")]) == 2
    assert "resume" not in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_collect_into_a_session_path_that_is_a_file_is_one_line_before_any_motion(tmp_path, capsys):
    """A new session at a path holding a file: FileExistsError from mkdir, a traceback after the cell had opened (and
    --dry-run passed it as 'every check')."""
    import json

    from tests.conftest import assert_bad_input

    plan = tmp_path / "plan.json"
    plan.write_text(json.dumps(first(2).to_dict()))
    session = tmp_path / "s.csv"
    session.write_text("q1,q2\n")
    for extra in (["--dry-run"], []):
        assert_bad_input(capsys, ["collect", "--robot", "R1", "--plan", str(plan), "--session", str(session),
                                  "--sim", *SIM_FAST, "--no-progress", *extra], str(session), "is a file")
        assert session.read_text() == "q1,q2\n"


def test_dry_run_resume_of_a_finished_session_says_nothing_is_left(tmp_path, capsys):
    """It said 'summarize_plan: plan: expected targets of one robot, got no target', exit 2."""
    from app.cli import main

    session = tmp_path / "s"
    _, driver, mocap, _, safety = make_cell()
    with driver, mocap:
        run_session(session, driver, mocap, safety, body_id=1, plan=first(2), others=OTHERS, config=FAST,
                    progress=False)
    assert main(["collect", "--robot", "R1", "--session", str(session), "--resume", "--dry-run", "--sim", *SIM_FAST,
                 "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert f"every one of the 2 targets of {session} is measured or skipped; nothing left to collect" in out
