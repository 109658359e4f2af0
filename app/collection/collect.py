"""The guided collection session: visit every target of a plan, measure it, store it durably, export it.

For each target: safety check of the move (limits, floor, other arms), move, wait until settled, read the
joints, collect mocap frames for a dwell window, read the joints again (the arm must not have moved), reject
frames that are not tracking-valid or whose marker error is too large, and average the rest (mean position,
eigenvector quaternion average; :mod:`app.collection.mocap_window`). The sample is committed to the session's SQLite file
at once.

Mocap dropouts, timeouts and dropped connections are retried a bounded number of times (a dropped connection
stops every arm, is recorded and re-established first); then the target is recorded as skipped with the
reason and whether it was transient (a timeout, lost mocap, no fresh status) or lasting (a sample the store
refused, a joint readback outside the limits). A resumed session measures the transient skips again (with
``retry_skipped`` every skip); :attr:`SessionResult.unmeasured` says what is still not measured. An alarm or an e-stop on any arm, non-finite joint feedback, a connection that cannot be restored, or
too many consecutive skips end the run (:class:`SessionAborted`): every arm the session knows is stopped, the
reason is recorded in the session's events, and a resumed session continues at the first target not yet
recorded. Unsafe targets always abort before any motion. Only one process may use a session folder at a time.
"""

from __future__ import annotations

import logging
import math
import sqlite3
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from app.collection.mocap_window import ClockLink, WindowFailed, average_frames, collect_window
from app.collection.motion import NonFiniteFeedback, device_name, move_safely, read_q, stop_all
from app.collection.plan_safety import check_plan_safe
from app.collection.plans.collection import Plan
from app.collection.runtime.cell import Cell
from app.collection.safety import CellSafety
from app.collection.session_store import EventKind, Sample, SessionStore
from calibration.data.recording import Recording, write_recording
from calibration.errors import CellCalError, ConfigError, DataError
from calibration.evaluation.metrics import errors
from drivers.base import MocapSource, RobotDriver
from drivers.errors import DriverDisconnected, DriverError, DriverTimeout, InvalidArgument, RobotFault


def collect_arm(rt: Cell, safety: CellSafety, robot: str, plan: Plan | None, session_dir: Path,
                config: CollectConfig, *, resume: bool = False, retry_skipped: bool = False, progress: bool = True,
                clock: Callable[[], float] | None = None, model: Any = None,
                model_name: str = "the model") -> SessionResult:
    """Collect one arm's session while the other arms stay parked, then park the arm again.

    The other arms' live poses (their drivers) feed every safety check. ``plan`` may be None on resume.
    ``clock`` stamps the samples (default: wall time; the demo passes the simulated clock). ``model`` is the model
    each measured target's residual is logged against with INFO logging on (:func:`target_line`).
    """
    driver = rt.drivers[robot]
    others = rt.others(robot)
    clock_kw: dict[str, Any] = {} if clock is None else {"clock": clock}  # run_session's own default otherwise
    result = run_session(session_dir, driver, rt.mocap_for(robot), safety, body_id=rt.body_ids[robot], plan=plan,
                         other_drivers=others, config=config, resume=resume, retry_skipped=retry_skipped,
                         progress=progress, model=model, model_name=model_name,
                         **clock_kw)
    move_safely(driver, rt.park_q(robot), safety, others, config.speed_fraction, config.settle_timeout_s)
    return result


log = logging.getLogger("cellcal.app")


_MOVE_EPS_RAD = 1e-4  # a joint change below this (several encoder pulses) does not count as a motion


@dataclass(frozen=True)
class CollectConfig:
    """Motion, measurement and retry options of a session. Times are on the devices' clocks [s].

    Attributes:
        speed_fraction: fraction (0, 1] of the maximum joint speeds.
        settle_timeout_s: longest wait for the arm to settle after a move.
        settle_tolerance_rad: standstill tolerance passed to the driver.
        dwell_s: length of the mocap averaging window (source capture time).
        discard_s: frames at the start of the window dropped (mocap latency, residual vibration).
        frame_timeout_s: a read with no frame for this long is a dropout.
        min_frames: fewest usable frames for a sample.
        min_valid_fraction: fewest usable frames as a fraction of the frames expected in the window.
        max_marker_error_mm: frames with a larger mean marker error are rejected.
        still_tolerance_deg: largest joint change between the readings before and after the dwell.
        mocap_retries: re-measurements after a failed measurement before the target is skipped.
        driver_retries: retries after a driver fault (reconnect, stop) before the target is skipped.
        max_consecutive_skips: this many skipped targets in a row abort the session.
    """

    speed_fraction: float = 0.2
    settle_timeout_s: float = 60.0
    settle_tolerance_rad: float = 1e-4
    dwell_s: float = 0.5
    discard_s: float = 0.05
    frame_timeout_s: float = 0.5
    min_frames: int = 10
    min_valid_fraction: float = 0.8
    max_marker_error_mm: float = 0.5
    still_tolerance_deg: float = 0.01
    mocap_retries: int = 2
    driver_retries: int = 2
    max_consecutive_skips: int = 5


#: Collection settings of the demo: short dwell windows, generous frame timeout (the clock runs fast).
DEMO_COLLECT = CollectConfig(speed_fraction=0.5, settle_timeout_s=60.0, dwell_s=0.2, discard_s=0.03,
                             frame_timeout_s=5.0, min_frames=8)


@dataclass(frozen=True)
class SessionResult:
    """What a run of :func:`run_session` did.

    Attributes:
        session_dir: the session folder.
        n_targets: targets in the plan.
        n_ok: targets measured (in the whole session).
        n_skipped: targets recorded as skipped (in the whole session).
        n_new: rows (measured or skipped) written by this run.
        skipped: ``(target index, reason)`` of every skipped target in the session.
        complete: every target is recorded (measured or skipped).
        elapsed_s: wall time of this run [s].
        n_retried: targets skipped earlier that this run (a resume) set out to measure again.
    """

    session_dir: Path
    n_targets: int
    n_ok: int
    n_skipped: int
    n_new: int
    skipped: tuple[tuple[int, str], ...]
    complete: bool
    elapsed_s: float
    n_retried: int = 0

    @property
    def unmeasured(self) -> int:
        """Targets of the plan not measured (skipped, or not yet visited)."""
        return self.n_targets - self.n_ok


class SessionAborted(CellCalError):
    """The session stopped early; every arm was stopped, everything recorded so far is kept, and the session can
    be resumed (it continues at the first target not recorded).

    Attributes:
        robot: the robot whose fault ended the run (None when the session itself gave up, e.g. too many skips).
        kind: the recorded event kind (``alarm``, ``e-stop``, ``connection-lost``, ``bad-feedback``, ``aborted``...).
        reason: why, as recorded in the session's events.
    """

    def __init__(self, message: str, *, robot: str | None = None, kind: str = "aborted", reason: str = "") -> None:
        self.robot = robot
        self.kind = kind
        self.reason = reason or message
        super().__init__(message)


class _MeasureFailed(Exception):
    """A measurement attempt failed for a reason worth retrying; ``transient`` False when it would fail again."""

    def __init__(self, reason: str, transient: bool = True) -> None:
        self.transient = transient
        super().__init__(reason)


class _Halt(Exception):
    """A fault that ends the run: every arm is stopped and the reason recorded (never escapes run_session)."""

    def __init__(self, robot: str, error: BaseException, index: int | None, kind: EventKind | None = None) -> None:
        self.robot, self.error, self.index, self.kind = robot, error, index, kind
        super().__init__(f"{robot}: {error}")


def _check_readback(q: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> None:
    bad = np.flatnonzero((q < lower) | (q > upper))
    if bad.size:
        j = int(bad[0])
        raise _MeasureFailed(f"joint readback q{j + 1} = {math.degrees(q[j]):.6g} deg is outside the limits",
                             transient=False)


def target_line(robot: str, index: int, n_targets: int, kind: str, cluster: int, sample: Sample, model: Any,
                model_name: str, max_marker_error_mm: float) -> str:
    """One line on a measured target (``collect -v``): its residual against ``model`` and the mocap's health.

    Args:
        robot, index, n_targets, kind, cluster: which target (0-based ``index`` of ``n_targets``).
        sample: the averaged measurement.
        model: the model the residual is taken against (``fk(q) -> (R, p)``); None for no residual.
        model_name: how the line names it (e.g. ``nominal``, a model file).
        max_marker_error_mm: the frame rejection threshold, shown beside the marker error.
    """
    if model is None:
        residual = "no model to compare with"
    else:
        rec = Recording(sample.q[None, :], np.asarray(sample.p, dtype=float)[None, :],
                        np.asarray(sample.quat, dtype=float)[None, :], {}, f"target {index}")
        e = errors(model, rec)
        residual = (f"residual {float(e.position_mm[0]):.3f} mm / {float(e.orientation_deg[0]):.3f} deg against "
                    f"{model_name}")
    again = f", {sample.attempts} attempts" if sample.attempts > 1 else ""
    return (f"{robot} target {index + 1}/{n_targets} ({kind}, cluster {cluster}): {residual}; mocap {sample.frames} "
            f"frames in the window, tracking spread {sample.std_pos_mm:.3f} mm / {sample.std_rot_deg:.3f} deg, marker "
            f"error {sample.marker_err:.3f} mm (frames above {max_marker_error_mm:g} mm rejected){again}")


class _Session:
    """State of one run: devices, store, direction memory, counters."""

    def __init__(self, store: SessionStore, plan: Plan, driver: RobotDriver, mocap: MocapSource, body_id: int,
                 safety: CellSafety, others: Mapping[str, np.ndarray], other_drivers: Mapping[str, RobotDriver],
                 config: CollectConfig, clock: Callable[[], float] = time.monotonic,
                 retry: set[int] | None = None, model: Any = None, model_name: str = "the model") -> None:
        self.store, self.plan, self.driver, self.mocap = store, plan, driver, mocap
        self.model, self.model_name = model, model_name  # each target's residual in the -v line
        self.retry = set(retry or ())  # skipped targets this run measures again (a new row replaces the skip)
        self.body_id, self.safety, self.config = body_id, safety, config
        self.static_others = {k: np.asarray(v, dtype=float) for k, v in others.items()}
        self.other_drivers = dict(other_drivers)
        spec = safety.cell.robot(driver.name).robot
        self.lower, self.upper = spec.lower_rad, spec.upper_rad
        self.dirs = np.zeros(6, dtype=int)
        self.index: int | None = None  # the target being visited
        # sample stamps: seconds since the session was created (0 for the first run: it was created just now)
        self.t_offset = time.time() - store.created_wall() if store.done() else 0.0
        self.clock = clock
        # the mocap's capture clock against the host's (a simulated source's own), learned from every window
        self.link = ClockLink(mocap.stamp_clock() or clock)
        self.t_start = clock()
        self.moved = False  # no move commanded yet in this run

    def all_drivers(self) -> dict[str, RobotDriver]:
        """Every arm this session knows: its own and the others."""
        return {self.driver.name: self.driver, **self.other_drivers}

    def own_q(self) -> np.ndarray:
        """The arm's joint angles; non-finite feedback ends the run."""
        try:
            return read_q(self.driver)
        except NonFiniteFeedback as e:
            raise _Halt(self.driver.name, e, self.index, "bad-feedback") from e

    def others(self) -> dict[str, np.ndarray]:
        """The other arms' poses [rad]; any fault reading one ends the run (its pose is unknown)."""
        out = dict(self.static_others)
        for name, d in self.other_drivers.items():
            try:
                out[name] = read_q(d)
            except DriverError as e:
                raise _Halt(name, e, self.index) from e
        return out

    def check_ready(self) -> None:
        """No arm reports an alarm or an e-stop (each would end the run).

        Before the run's first move an alarm that was already standing is not a halt: the operator has just
        started (or resumed) the session, and the controller's START_TRAJ_MODE resets alarms and turns the servos
        on (MotoROS does; if it cannot, the driver's move is refused with the controller's reason). An e-stop is
        always a halt.
        """
        for name, d in self.all_drivers().items():
            try:
                st = d.status()
            except DriverError as e:
                if d is self.driver:
                    raise  # the arm's own connection faults are retried
                raise _Halt(name, e, self.index) from e
            if st.alarm and not st.e_stopped and not self.moved:
                log.warning("%s: alarm %d standing at the start of the run; the controller resets it on "
                            "START_TRAJ_MODE", name, st.error_code)
                continue
            if st.alarm or st.e_stopped:
                what = "e-stop pressed" if st.e_stopped else f"alarm active (code {st.error_code})"
                raise _Halt(name, RobotFault(device_name(d), what), self.index)

    def measure(self, index: int, attempts: int) -> Sample:
        target = self.plan.targets[index]
        c = self.config
        self.check_ready()
        q_now = self.own_q()
        self.safety.check_motion(self.driver.name, q_now, target.q, self.others(), index)
        self.driver.move_to(target.q, c.speed_fraction)
        self.moved = True
        self.driver.wait_settled(c.settle_timeout_s, c.settle_tolerance_rad)
        moved = np.abs(target.q - q_now) > _MOVE_EPS_RAD
        self.dirs = np.where(moved, np.sign(target.q - q_now).astype(int), self.dirs)
        return self.measure_here(index, attempts)

    def measure_here(self, index: int, attempts: int) -> Sample:
        c = self.config
        settled_at = self.link.clock()  # the arm is settled by now (measure waited, or a resume finds it still)
        q_before = self.own_q()
        _check_readback(q_before, self.lower, self.upper)
        try:
            frames = collect_window(self.mocap, self.body_id, c, self.link, settled_at)
        except WindowFailed as e:
            raise _MeasureFailed(str(e)) from e
        except DriverError as e:
            raise _MeasureFailed(f"mocap: {e}") from e
        q_after = self.own_q()
        _check_readback(q_after, self.lower, self.upper)
        drift = float(np.max(np.abs(q_after - q_before)))
        if drift > math.radians(c.still_tolerance_deg):
            raise _MeasureFailed(f"the arm moved {math.degrees(drift):.4f} deg during the dwell")
        p, quat, std_p, std_r, err = average_frames(frames)
        return Sample(index, q_before, p, quat, std_p, std_r, err, len(frames),
                      self.t_offset + self.clock() - self.t_start, self.dirs.copy(), attempts)

    def visit(self, index: int) -> str | None:
        """Measure and store one target; returns the skip reason, or None when measured.

        Raises:
            _Halt: an alarm, an e-stop, non-finite feedback or a connection that cannot be restored.
        """
        c = self.config
        self.index = index
        target = self.plan.targets[index]
        again = index in self.retry  # skipped before: the new row replaces the skip (kept on record until then)
        driver_faults = measure_faults = 0
        at_target = False
        transient = True
        while True:
            attempts = driver_faults + measure_faults + 1
            try:
                sample = self.measure_here(index, attempts) if at_target else self.measure(index, attempts)
                self.store.add_sample(sample, target.robot, target.kind, target.cluster, self.lower, self.upper,
                                      replace_skip=again)
                if log.isEnabledFor(logging.INFO):  # collect -v: one line per target
                    log.info(target_line(target.robot, index, len(self.plan), target.kind, target.cluster, sample,
                                         self.model, self.model_name, c.max_marker_error_mm))
                return None
            except _MeasureFailed as e:
                measure_faults += 1
                reason, transient = str(e), e.transient
                log.warning("target %d: %s (attempt %d)", index, reason, attempts)
                at_target = True
                self._reconnect_mocap()
                if measure_faults > c.mocap_retries:
                    break
            except DataError as e:
                reason, transient = f"sample rejected: {e.reason}", False
                break
            except RobotFault as e:  # alarm / e-stop: not the target's fault, never retried
                raise _Halt(self.driver.name, e, index) from e
            except DriverError as e:
                driver_faults += 1
                reason, transient = str(e), not isinstance(e, InvalidArgument)
                log.warning("target %d: driver fault: %s (attempt %d)", index, reason, attempts)
                at_target = False
                self._recover(e)
                if driver_faults > c.driver_retries:
                    break
        self.store.add_skipped(index, target.robot, target.kind, target.cluster, reason, attempts, transient,
                               replace_skip=again)
        log.warning("target %d skipped%s: %s", index, "" if transient else " (lasting cause)", reason)
        return reason

    def _recover(self, e: DriverError) -> None:
        """After a driver fault: a lost connection stops every arm, is recorded, and is re-established."""
        if isinstance(e, DriverDisconnected):
            stop_all(self.all_drivers())
            self.record(self.driver.name, "connection-lost", f"{e}; every arm stopped, reconnecting", self.index)
            try:
                self.driver.connect()
            except DriverError as again:
                raise _Halt(self.driver.name, again, self.index, "connection-lost") from again
        elif isinstance(e, DriverTimeout):
            try:
                self.driver.stop()
            except DriverError as again:
                log.warning("recovery failed: %s", again)

    def _reconnect_mocap(self) -> None:
        try:
            self.mocap.read(0.0)
        except DriverDisconnected:
            try:
                self.mocap.connect()
            except DriverError as again:
                log.warning("mocap reconnection failed: %s", again)

    def record(self, robot: str, kind: EventKind, reason: str, index: int | None) -> None:
        """Commit an event; a failing store is logged, never masks the fault being recorded."""
        try:
            self.store.add_event(robot, kind, reason, index)
        except (sqlite3.Error, CellCalError) as e:
            log.error("could not record %s of %s in the session: %s", kind, robot, e)

    def run(self, pending: list[int], n_done: int, progress: bool) -> int:
        """Visit the pending targets in order (the whole remaining plan checked first); returns rows written."""
        c = self.config
        name = self.driver.name
        if pending:
            check_plan_safe(self.safety.cell, Plan(tuple(self.plan.targets[i] for i in pending), self.plan.params),
                            "the plan", safety=self.safety, others=self.others(), q_start={name: self.own_q()},
                            numbers=pending)
        n_new = consecutive = 0
        with tqdm(total=len(self.plan), initial=n_done, unit="target", desc=f"{name} collect",
                  disable=not progress) as bar:
            for index in pending:
                reason = self.visit(index)
                n_new += 1
                bar.update(1)
                consecutive = consecutive + 1 if reason else 0
                if consecutive >= c.max_consecutive_skips:
                    raise SessionAborted(f"{consecutive} targets in a row skipped (last: {reason}); fix the cause "
                                         f"and resume the session in {self.store.dir}", reason=str(reason))
        return n_new

    def halt(self, h: _Halt) -> SessionAborted:
        """Stop every arm, record why, and build the error that ends the run."""
        failed = stop_all(self.all_drivers())
        kind = h.kind or _fault_kind(self.all_drivers().get(h.robot), h.error)
        self.record(h.robot, kind, str(h.error), h.index)
        stopped = "every arm stopped" if not failed else f"could NOT stop {', '.join(failed)}"
        at = f" at target {h.index}" if h.index is not None else ""
        return SessionAborted(f"{h.robot} {kind}{at}: {h.error}; {stopped}; clear the cause and resume the session "
                              f"in {self.store.dir}", robot=h.robot, kind=kind, reason=str(h.error))

    def abandon(self, e: BaseException) -> None:
        """Any other end of the run (too many skips, unsafe target, interrupt): stop every arm, record it."""
        stop_all(self.all_drivers())
        # an interrupt's str() is empty: it was recorded as 'KeyboardInterrupt: '
        why = "interrupted (Ctrl-C)" if isinstance(e, KeyboardInterrupt) else f"{type(e).__name__}: {e}"
        self.record(self.driver.name, "aborted", why, self.index)


def _fault_kind(driver: RobotDriver | None, e: BaseException) -> EventKind:
    if isinstance(e, NonFiniteFeedback):
        return "bad-feedback"
    if isinstance(e, DriverDisconnected):
        return "connection-lost"
    if not isinstance(e, RobotFault):
        return "driver-fault"
    try:
        st = driver.status() if driver is not None else None
    except DriverError:
        st = None
    if st is not None and st.e_stopped:
        return "e-stop"
    if st is not None and st.alarm:
        return "alarm"
    return "robot-fault"


def _open_store(session_dir: Path, driver: RobotDriver, plan: Plan | None, info: dict[str, Any],
                resume: bool) -> tuple[SessionStore, Plan]:
    """Lock and open (resume) or create the session; refused at once when another process holds the folder."""
    if resume:
        store = SessionStore(session_dir)
        try:
            store.check_robot(driver.name)
        except DataError:
            store.close()
            raise
        stored = store.plan()
        if plan is not None and plan.to_dict()["targets"] != stored.to_dict()["targets"]:
            store.close()
            raise DataError(store.path, None, "plan", "the given plan differs from the session's plan")
        plan = stored
    else:
        if plan is None:
            raise ConfigError("run_session", "plan", "a new session needs a plan")
        store = SessionStore(session_dir, create=True)
        try:
            store.init(plan, info)
        except BaseException:
            store.close()
            raise
    if plan.robots != (driver.name,):
        store.close()
        raise ConfigError("run_session", "plan", f"the plan moves {', '.join(plan.robots)} but the driver is "
                                                 f"{driver.name}; one robot per session")
    return store, plan


def run_session(session_dir: str | Path, driver: RobotDriver, mocap: MocapSource, safety: CellSafety, *,
                body_id: int, plan: Plan | None = None, others: Mapping[str, np.ndarray] | None = None,
                other_drivers: Mapping[str, RobotDriver] | None = None, config: CollectConfig = CollectConfig(),
                resume: bool = False, retry_skipped: bool = False, progress: bool = True,
                clock: Callable[[], float] = time.monotonic, model: Any = None,
                model_name: str = "the model") -> SessionResult:
    """Run (or resume) a guided collection session. Devices must be connected.

    Args:
        session_dir: the session folder; a new session needs a fresh folder (or one whose creation was killed).
        driver: the arm being calibrated; ``driver.name`` must match the plan's robot.
        mocap: any mocap source (simulated, NatNet, Zenoh subscriber).
        safety: the cell's safety checker; every target is checked before any motion.
        body_id: rigid-body id of the arm's tool marker in ``mocap``.
        plan: the targets; required for a new session, optional on resume (must equal the stored plan).
        others: joint angles [rad] (6,) of the other arms, held still during the session.
        other_drivers: drivers of the other arms, read before every move (takes precedence over ``others``);
            they are stopped too when the run ends on a fault.
        config: motion, measurement and retry options.
        resume: continue an existing session: the targets not yet recorded and those skipped for a transient
            reason (a timeout, lost mocap, no fresh status) are measured.
        retry_skipped: on resume, also try the targets skipped for a lasting reason again.
        progress: show a progress bar with an ETA.
        clock: time source of the sample stamps [s] (a simulated cell passes its simulated clock, so a seeded
            run stamps the same times).
        model: the model in use for this arm (``fk(q) -> (R, p)``): with INFO logging on (``collect -v``) each
            measured target logs one line with its residual against it and the mocap's health (:func:`target_line`).
        model_name: how that line names the model.

    Raises:
        SessionLocked: another process uses the folder (refused before anything is read or moved).
        UnsafeTarget: a target or a path is unsafe (checked for the whole plan before the first motion).
        SessionAborted: an alarm, an e-stop, non-finite joint feedback or a connection that could not be restored
            on any arm, or ``max_consecutive_skips`` targets in a row skipped. Every arm is stopped, the reason is
            recorded in the session (:meth:`SessionStore.events`) and the session stays resumable.
        DataError: the folder already holds a session (without resume) or holds none (with resume).
    """
    t_run = time.monotonic()
    session_dir = Path(session_dir)
    info = {"robot": driver.name, "body_id": body_id, "config": asdict(config)}
    store, plan = _open_store(session_dir, driver, plan, info, resume)
    with store:
        retry = store.retriable(lasting_too=retry_skipped) if resume else set()
        if retry:
            log.warning("%d target(s) skipped earlier are measured again", len(retry))
        done = store.done() - retry
        pending = [i for i in range(len(plan)) if i not in done]
        session = _Session(store, plan, driver, mocap, body_id, safety, others or {}, other_drivers or {}, config,
                           clock, retry, model, model_name)
        try:
            n_new = session.run(pending, len(done), progress)
        except _Halt as h:
            raise session.halt(h) from h.error
        except BaseException as e:
            session.abandon(e)
            raise
        skipped = tuple((r["target_index"], r["reason"]) for r in store.rows("skipped"))
        n_ok = len(store.rows("ok"))
    return SessionResult(session_dir, len(plan), n_ok, len(skipped), n_new, skipped,
                         n_ok + len(skipped) == len(plan), time.monotonic() - t_run, len(retry))


def export(session_dir: str | Path, out_csv: str | Path, kinds: Sequence[str] | None = None) -> int:
    """Write the session's measured samples as a recording CSV (extra columns: cluster, t, dir1..dir6,
    marker_err, frames), in the order they were measured (``t`` is monotonic, as the recording format wants; a
    skipped target measured on a resume comes after the targets measured before it).

    Args:
        session_dir: the session folder.
        out_csv: the recording file to write (atomically).
        kinds: target kinds to include (``anchor``, ``perturb``, ``cpa``, ``validation``); all when None.

    Returns:
        The number of samples written.

    Raises:
        DataError: no session, a session naming several robots, or no measured sample of the requested kinds
            (nothing is written).
    """
    with SessionStore(session_dir, lock=False, purpose="export") as store:  # reading: allowed while a collector runs
        robots = store.robots()
        if len(robots) > 1:
            raise DataError(store.path, None, "robot", f"the session names several robots ({', '.join(robots)}); "
                                                       "a recording holds one arm's samples")
        rows = [r for r in store.rows("ok") if kinds is None or r["kind"] in kinds]
    rows.sort(key=lambda r: r["t"])  # measurement order: a target a resume measured again comes after the others
    if not rows:
        raise DataError(Path(session_dir), None, None,
                        f"no measured samples{'' if kinds is None else ' of kind ' + ', '.join(kinds)} to export")

    def col(*names: str) -> np.ndarray:
        return np.array([[r[n] for n in names] for r in rows], dtype=float)

    extra = {"cluster": col("cluster")[:, 0], "t": col("t")[:, 0]}
    extra.update({f"dir{i}": col(f"dir{i}")[:, 0] for i in range(1, 7)})
    extra.update({"marker_err": col("marker_err")[:, 0], "frames": col("frames")[:, 0]})
    rec = Recording(col(*(f"q{i}" for i in range(1, 7))), col("x", "y", "z"), col("qw", "qx", "qy", "qz"), extra,
                    str(session_dir))
    write_recording(rec, out_csv)
    log.info("exported %d samples from %s to %s", len(rows), session_dir, out_csv)
    return len(rows)
