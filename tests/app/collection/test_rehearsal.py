"""The real-cell workflow end to end with separate OS processes: fake controller, fake Motive, bridge, collector.

Nothing here uses ``--sim``: the collector builds the real MotoROS driver, the Zenoh subscriber and the
registration from the cell file, exactly as on the real cell. The fake Motive reports the arms in a hidden
world frame derived from its seed; only this test (playing the part of the truth) reads it, to check what the
registration and the recordings recovered.
"""

from __future__ import annotations

import contextlib
import io
import json
import signal
import sqlite3
import time
from pathlib import Path

import numpy as np
import pytest

from app.collection.rehearsal import Process, Rehearsal, run_cellcal, sample_count, small_plan, write_rehearsal_cell
from calibration.data.recording import read_recording
from calibration.frames.registration import transform_difference
from calibration.physics import PlantedErrors
from cell_config import load_cell
from drivers.sim.rehearsal import hidden_frames, rehearsal_truths

SEED = 5
PURE = ("--origin-std-mm", "0", "--tilt-std-deg", "0", "--compliance-mm", "0")  # a twin with no kinematic error
#: Measurement window of the collections here [s]: 24 frames at the fake Motive's 240 Hz instead of the default
#: 0.5 s's 120, above the collector's min_frames of 10 (every window waits in real time; each claim holds for any
#: window that meets min_frames; the 0.02 mm frame noise averages to ~0.004 mm over 24 frames).
DWELL_S = 0.1


@pytest.fixture(scope="module")
def plans(tmp_path_factory) -> dict[str, Path]:
    """Each arm's 14-target plan, planned once for the module (read-only; a plan depends on the arms, joint
    limits and parked poses of rehearsal.yaml, not on the ports or the registration a test's copy has)."""
    folder = tmp_path_factory.mktemp("rehearsal_plans")
    cell_path = write_rehearsal_cell(folder)
    return {robot: small_plan(cell_path, robot, folder / f"{robot}_plan.json") for robot in ("R1", "R2")}


def wait_for_samples(session: Path, n: int, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while sample_count(session) < n:
        assert time.monotonic() < deadline, f"fewer than {n} samples in {session} after {timeout_s} s"
        time.sleep(0.2)


def check_recording(cell_path: Path, session: Path, out_csv: Path, n_targets: int, robot: str,
                    truths: dict) -> float:
    """Export the session; every target once; returns the largest distance from the truth in the base frame [mm].

    The export runs in this process (``main``): it reads the session file only, no device, and a process of its
    own would cost its start-up and imports (~1 s) per call."""
    from app.cli.commands import main

    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        code = main(["--cell", str(cell_path), "export", "--session", str(session), "--out", str(out_csv)])
    assert code == 0, printed.getvalue()
    cell = load_cell(cell_path)
    spec = cell.robot(robot).robot
    rec = read_recording(out_csv, spec.lower_rad, spec.upper_rad)
    assert len(rec) == n_targets
    with sqlite3.connect(session / "session.sqlite") as con:
        indices = [r[0] for r in con.execute("SELECT target_index FROM samples WHERE status = 'ok'")]
    assert sorted(indices) == list(range(n_targets))  # each target exactly once
    R, p = truths[robot].pose(rec.q)
    T_marker = hidden_frames(cell, SEED)[robot].T_tool_marker
    p_true = p + np.einsum("nij,j->ni", R, T_marker[:3, 3])
    return float(np.max(np.linalg.norm(rec.p - p_true, axis=1)))


def test_register_then_collect_both_arms_in_separate_processes(tmp_path: Path, plans: dict[str, Path]) -> None:
    cell_path = write_rehearsal_cell(tmp_path, dwell_s=DWELL_S)
    truths = rehearsal_truths(load_cell(cell_path), SEED, PlantedErrors(0.0, 0.0, 0.0))
    with Rehearsal(cell_path, *PURE, seed=SEED):
        for robot in ("R1", "R2"):
            done = run_cellcal(cell_path, "register", "--robot", robot, "--yes", "--speed", "1", "--no-progress",
                               "--json", str(tmp_path / f"reg_{robot}.json"))
            assert done.returncode == 0, done.stdout + done.stderr
        cell = load_cell(cell_path)
        hidden = hidden_frames(cell, SEED)
        for robot in ("R1", "R2"):
            d_mm, d_deg = transform_difference(cell.registration[robot].T_world_base, hidden[robot].T_world_base)
            assert d_mm < 0.05 and d_deg < 0.005, (robot, d_mm, d_deg)
        report = json.loads((tmp_path / "reg_R2.json").read_text())
        T_true = np.linalg.inv(hidden["R1"].T_world_base) @ hidden["R2"].T_world_base
        d_true_mm, _ = transform_difference(T_true, cell.robot("R2").T_cell_base)
        found_mm = report["relative_bases"]["R2"]["cell_yaml_diff_mm"]
        assert d_true_mm > 0.5 and abs(found_mm - d_true_mm) < 0.1, (found_mm, d_true_mm)  # hidden survey error
        assert f"in {cell_path}, replace robots.R2.T_cell_base with" in done.stdout, done.stdout  # what to do
        assert "T_cell_base" in report["relative_bases"]["R2"]["hint"]
        for robot in ("R1", "R2"):
            session = tmp_path / f"s_{robot}"
            done = run_cellcal(cell_path, "collect", "--robot", robot, "--plan", str(plans[robot]), "--session",
                               str(session), "--yes", "--speed", "1", "--no-progress")
            assert done.returncode == 0, done.stdout + done.stderr
            worst = check_recording(cell_path, session, tmp_path / f"{robot}.csv", 14, robot, truths)
            assert worst < 0.1, (robot, worst)  # 0.02 mm frame noise averaged over the window, plus the frame error


def test_collection_without_registration_is_refused_before_motion(tmp_path: Path, plans: dict[str, Path]) -> None:
    cell_path = write_rehearsal_cell(tmp_path)
    done = run_cellcal(cell_path, "collect", "--robot", "R1", "--plan", str(plans["R1"]), "--session",
                       str(tmp_path / "s"), "--yes")
    assert done.returncode == 2
    assert "R1 has no registration" in done.stderr and "cellcal register" in done.stderr
    assert not (tmp_path / "s").exists()


# -- faults, each with real processes ---------------------------------------------------------------------------


def registered_cell(tmp_path: Path, robot: str = "R1", **options: float) -> Path:
    """A rehearsal cell whose registration is the hidden truth (the fault tests are about collection, not
    registration: writing it directly saves the registration's motion); ``options`` go to write_rehearsal_cell."""
    from cell_config.registration import RobotRegistration, save_registration

    cell_path = write_rehearsal_cell(tmp_path, dwell_s=DWELL_S, **options)
    cell = load_cell(cell_path)
    hf = hidden_frames(cell, SEED)[robot]
    tool = cell.robot(robot).tool
    T_fm = np.eye(4)
    T_fm[:3, :3], T_fm[:3, 3] = tool.R_flange_tool, tool.p_flange_tool
    save_registration(cell.registration_path, robot, RobotRegistration(
        T_world_base=hf.T_world_base, T_flange_marker=T_fm @ hf.T_tool_marker, date="2026-12-01T00:00:00+00:00",
        rms_mm=0.0, rms_deg=0.0, n_samples=21, sigma_world_base=np.zeros(6), sigma_flange_marker=np.zeros(6)))
    return cell_path


def collector(cell_path: Path, plan: Path, session: Path, *extra: str) -> Process:
    return Process(cell_path, "collect", "--robot", "R1", "--plan", str(plan), "--session", str(session), "--yes",
                   "--speed", "1", "--no-progress", *extra)


def test_bridge_and_controller_killed_mid_collection_are_waited_for_and_reconnected(
        tmp_path: Path, plans: dict[str, Path]) -> None:
    """One collection, two crashes (SIGKILL, restarted later): the bridge after 3 samples (down 2 s, so the stream
    is silent longer than the collector tolerates), then the controller after 6 (down 0.5 s). The collector waits
    for the one and reconnects to the other; every target is recorded once, at the truth."""
    cell_path = registered_cell(tmp_path)
    truths = rehearsal_truths(load_cell(cell_path), SEED, PlantedErrors(0.0, 0.0, 0.0))
    session = tmp_path / "s"
    with Rehearsal(cell_path, *PURE, seed=SEED) as r:
        c = collector(cell_path, plans["R1"], session).start(ready=False)
        try:
            for victim, after, down_s in ((r.bridge, 3, 2.0), (r.controller, 6, 0.5)):
                wait_for_samples(session, after)
                assert sample_count(session) < 14, "the collection ended before the crash"
                victim.kill()
                time.sleep(down_s)
                victim.start()
            assert c.wait(120) == 0, c.output
        finally:
            c.kill()
    assert "mocap stream silent" in c.output and "mocap stream is back" in c.output  # the bridge: waited for
    assert "connection-lost" in c.output  # the controller: recorded and printed
    assert check_recording(cell_path, session, tmp_path / "r1.csv", 14, "R1", truths) < 0.1


def test_alarm_during_a_move_stops_both_arms_and_the_session_resumes(tmp_path: Path, plans: dict[str, Path]) -> None:
    cell_path = registered_cell(tmp_path)
    truths = rehearsal_truths(load_cell(cell_path), SEED, PlantedErrors(0.0, 0.0, 0.0))
    plan, session = plans["R1"], tmp_path / "s"
    with Rehearsal(cell_path, *PURE, seed=SEED) as r:
        c = collector(cell_path, plan, session).start(ready=False)
        try:
            wait_for_samples(session, 3)
            r.controller.signal(signal.SIGUSR1)  # the fake raises alarm 4107
            assert c.wait(60) == 2, c.output
        finally:
            c.kill()
        assert "alarm" in c.output and "every arm stopped" in c.output and "resume" in c.output
        done_before = sample_count(session)
        assert 3 <= done_before < 14
        refused = run_cellcal(cell_path, "collect", "--robot", "R1", "--session", str(session), "--resume", "--yes",
                              "--speed", "1", "--no-progress")  # the alarm still stands: no motion without a reset
        assert refused.returncode == 2 and "alarm 4107" in refused.stderr, refused.stdout + refused.stderr
        assert sample_count(session) == done_before
        again = run_cellcal(cell_path, "collect", "--robot", "R1", "--session", str(session), "--resume", "--yes",
                            "--speed", "1", "--no-progress", "--reset-alarms")  # START_TRAJ_MODE resets it
        assert again.returncode == 0, again.stdout + again.stderr
    assert check_recording(cell_path, session, tmp_path / "r1.csv", 14, "R1", truths) < 0.1


def test_non_finite_joint_feedback_is_refused_before_any_point(tmp_path: Path, plans: dict[str, Path]) -> None:
    cell_path = registered_cell(tmp_path)
    plan, session = plans["R1"], tmp_path / "s"
    with Rehearsal(cell_path, *PURE, seed=SEED) as r:
        r.controller.signal(signal.SIGUSR2)  # the fake now reports NaN joint angles
        time.sleep(0.5)
        done = run_cellcal(cell_path, "collect", "--robot", "R1", "--plan", str(plan), "--session", str(session),
                           "--yes", "--speed", "1", "--no-progress")
        assert done.returncode == 2, done.stdout + done.stderr
        assert "finite" in done.stderr
        assert r.controller.stop() == 0
    assert sample_count(session) == 0
    assert "trajectory points received: 0" in r.controller.output


def read_health(cell_path: Path, timeout_s: float, until) -> dict:  # noqa: ANN001 - a predicate on the message
    """Health messages of the bridge, read as any machine on the network would, until ``until(msg)``."""
    import queue

    from app.collection.mocap_bridge import health_key
    from drivers.bus import open_session

    cell = load_cell(cell_path)
    got: queue.Queue = queue.Queue()
    session = open_session(cell.zenoh_for("collector"))
    sub = session.declare_subscriber(health_key(cell.name, "mocap-bridge"),
                                     lambda s: got.put(json.loads(s.payload.to_bytes())))
    try:
        deadline = time.monotonic() + timeout_s
        last = None
        while time.monotonic() < deadline:
            try:
                last = got.get(timeout=0.5)
            except queue.Empty:
                continue
            if until(last):
                return last
        raise AssertionError(f"no matching health message within {timeout_s} s; last: {last}")
    finally:
        sub.undeclare()
        session.close()


def test_bridge_reconnects_to_a_restarted_motive_and_publishes_its_health(tmp_path: Path) -> None:
    cell_path = write_rehearsal_cell(tmp_path)
    with Rehearsal(cell_path, *PURE, seed=SEED) as r:
        first = read_health(cell_path, 15, lambda h: h["state"] == "streaming" and h["frames_published"] > 100)
        assert first["connections"] == 1 and first["handshakes"] == 1 and first["natnet_version"] == "4.1"
        assert sorted(first["bodies"].values()) == ["mti", "weldgun"]  # resolved from Motive's model definitions
        r.motive.kill()
        read_health(cell_path, 15, lambda h: h["state"] == "connecting" or h["last_frame_age_s"] > 1.0)
        r.motive.start()
        again = read_health(cell_path, 20, lambda h: h["handshakes"] >= 2 and h["state"] == "streaming"
                            and h["last_frame_age_s"] < 0.5)
        assert again["frames_published"] > first["frames_published"]
        r.bridge.signal(signal.SIGINT)
        assert r.bridge.wait(15) == 0, r.bridge.output
    assert "handshake(s) with Motive" in r.bridge.output


def test_a_zenoh_router_relays_the_mocap_between_machines(tmp_path: Path) -> None:
    from drivers.bus import ZenohMocapSource

    cell_path = write_rehearsal_cell(tmp_path, via_router=True)
    cell = load_cell(cell_path)
    router = Process(cell_path, "router").start()
    try:
        with Rehearsal(cell_path, *PURE, seed=SEED):
            with ZenohMocapSource(cell.name, config=cell.zenoh_for("collector"), rigid_bodies=["weldgun"]) as sub:
                frames, deadline = [], time.monotonic() + 15
                while len(frames) < 50 and time.monotonic() < deadline:
                    frames += sub.read(0.5)
        assert len(frames) >= 50 and {f.body_id for f in frames} == {11}
    finally:
        assert router.stop() == 0, router.output


def test_operator_checks_refuse_or_only_look_and_nothing_moves(tmp_path: Path, plans: dict[str, Path]) -> None:
    cell_path = registered_cell(tmp_path)
    text = cell_path.read_text().replace("max_speed_fraction: 1.0", "max_speed_fraction: 0.25")
    cell_path.write_text(text)
    plan, session = plans["R1"], tmp_path / "s"
    base = ("collect", "--robot", "R1", "--plan", str(plan), "--session", str(session), "--no-progress")
    with Rehearsal(cell_path, *PURE, seed=SEED) as r:
        asked = run_cellcal(cell_path, *base)  # no terminal to ask on, no --yes
        assert asked.returncode == 2 and "needs confirmation" in asked.stderr and "--yes" in asked.stderr
        fast = run_cellcal(cell_path, *base, "--yes", "--speed", "0.5")
        assert fast.returncode == 2 and "above the cell's cap" in fast.stderr and "0.25" in fast.stderr
        looked = run_cellcal(cell_path, *base, "--dry-run", "--json", str(tmp_path / "dry.json"))
        assert looked.returncode == 0, looked.stderr
        assert "dry run, no motion" in looked.stdout and "14 targets" in looked.stdout
        assert json.loads((tmp_path / "dry.json").read_text())["safe"] is True
        reg = run_cellcal(cell_path, "register", "--robot", "R2", "--dry-run")
        assert reg.returncode == 0 and "dry run" in reg.stdout, reg.stderr
        recal = run_cellcal(cell_path, "recalibrate", "--robot", "R1", "--plan", str(plan), "--model-dir",
                            str(tmp_path / "models"), "--validation", "5", "--dry-run")
        assert recal.returncode == 0 and "dry run, no motion" in recal.stdout, recal.stderr
        assert r.controller.stop() == 0
    assert "trajectory points received: 0" in r.controller.output
    assert not session.exists()


def test_a_silent_mocap_is_refused_before_any_motion(tmp_path: Path, plans: dict[str, Path]) -> None:
    """Without the bridge, register and collect moved the arm to its first target and waited 30 s there for a
    mocap frame before failing (new-user run): the cell now waits for each arm's first frame when it opens, here
    0.5 s (mocap.first_frame_s; 5 s by default: this test is about the refusal, not the length of the wait)."""
    cell_path = registered_cell(tmp_path, first_frame_s=0.5)
    session = tmp_path / "s"
    with Rehearsal(cell_path, *PURE, seed=SEED) as r:
        r.bridge.stop()
        started = time.monotonic()
        for args in (("collect", "--robot", "R1", "--plan", str(plans["R1"]), "--session", str(session)),
                     ("register", "--robot", "R1")):
            done = run_cellcal(cell_path, *args, "--yes", "--no-progress")
            assert done.returncode == 2, done.stdout + done.stderr
            assert "no frames of R1's rigid body 'weldgun' in 0.5 s" in done.stderr and "before any motion" in done.stderr, \
                done.stderr
        assert time.monotonic() - started < 30.0
        assert r.controller.stop() == 0
    assert "trajectory points received: 0" in r.controller.output



def stall_then_resume(tmp_path: Path, plans: dict[str, Path], victim: str, cell_path: Path,
                      stall_s: float | None) -> str:
    """Collect R1's plan; after 3 samples stop ``victim`` (SIGSTOP) for ``stall_s`` seconds (None: until the
    collector ends), expect the run to end exit 2 with targets unmeasured, then resume: exit 0, and every target is
    measured exactly once, at the truth. Returns the stalled run's output."""
    truths = rehearsal_truths(load_cell(cell_path), SEED, PlantedErrors(0.0, 0.0, 0.0))
    session = tmp_path / "s"
    with Rehearsal(cell_path, *PURE, seed=SEED) as r:
        stalled = getattr(r, victim)
        c = collector(cell_path, plans["R1"], session).start(ready=False)
        try:
            wait_for_samples(session, 3)
            stalled.signal(signal.SIGSTOP)
            if stall_s is not None:
                time.sleep(stall_s)
                stalled.signal(signal.SIGCONT)
            code = c.wait(120)
        finally:
            stalled.signal(signal.SIGCONT)
            c.kill()
        assert code == 2 and "skipped" in c.output, c.output
        assert sample_count(session) < 14
        again = run_cellcal(cell_path, "collect", "--robot", "R1", "--session", str(session), "--resume", "--yes",
                            "--speed", "1", "--no-progress")
        assert again.returncode == 0, again.stdout + again.stderr
        assert "14 of 14 targets measured, 0 skipped" in again.stdout
    assert check_recording(cell_path, session, tmp_path / "r1.csv", 14, "R1", truths) < 0.1
    return c.output


def test_a_stalled_controller_skips_targets_and_the_resume_measures_each_once(tmp_path: Path,
                                                                             plans: dict[str, Path]) -> None:
    """A controller stalled 36 s (SIGSTOP) made collect skip 5 targets and abort, and `collect --resume` then
    ended '57 of 62 targets measured, 5 skipped', exit 0, for good (issue 30): the resume measures them again. The
    controller stays stopped until the collector gives up (5 skips in a row); replies time out after 0.5 s here."""
    cell_path = registered_cell(tmp_path, reply_timeout_s=0.5)
    output = stall_then_resume(tmp_path, plans, "controller", cell_path, None)
    assert "5 targets in a row skipped" in output and "fresh robot status" in output


def test_a_stalled_bridge_skips_a_target_and_the_resume_measures_each_once(tmp_path: Path,
                                                                          plans: dict[str, Path]) -> None:
    """A bridge stalled 70 s made collect skip a target and end '61 of 62', exit 0 (issue 30). The collector waits
    1 s (mocap.stream_wait_s) for a stopped stream here; the bridge is stopped 6 s, longer than a target's three
    attempts."""
    cell_path = registered_cell(tmp_path, stream_wait_s=1.0)
    output = stall_then_resume(tmp_path, plans, "bridge", cell_path, 6.0)
    assert "targets not measured" in output and "mocap" in output
