"""The guided collection session: visit every target of a plan, measure it, store it durably, export it.

For each target: safety check of the move (limits, floor, other arms), move, wait until settled, read the
joints, collect mocap frames for a dwell window, read the joints again (the arm must not have moved), reject
frames that are not tracking-valid or whose marker error is too large, and average the rest (mean position,
eigenvector quaternion average; :mod:`app.mocap_window`). The sample is committed to the session's SQLite file
at once.

Mocap dropouts and driver faults are retried a bounded number of times; then the target is recorded as
skipped with the reason. Too many consecutive skips abort the session (:class:`SessionAborted`); a resumed
session continues at the first target not yet recorded. Unsafe targets always abort before any motion.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from app.mocap_window import WindowFailed, average_frames, collect_window
from app.planning import Plan
from app.safety import CellSafety
from app.session_store import Sample, SessionStore
from calibration.errors import CellCalError, ConfigError, DataError
from calibration.recording import Recording, write_recording
from drivers.base import MocapSource, RobotDriver
from drivers.errors import DriverDisconnected, DriverError, DriverTimeout

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
        complete: every target is recorded.
        elapsed_s: wall time of this run [s].
    """

    session_dir: Path
    n_targets: int
    n_ok: int
    n_skipped: int
    n_new: int
    skipped: tuple[tuple[int, str], ...]
    complete: bool
    elapsed_s: float


class SessionAborted(CellCalError):
    """The session stopped early (too many consecutive skips); everything recorded so far is kept."""


class _MeasureFailed(Exception):
    """A measurement attempt failed for a reason worth retrying."""


def _check_readback(q: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> None:
    if q.shape != (6,) or not np.all(np.isfinite(q)):
        raise _MeasureFailed(f"joint readback not 6 finite numbers: {q!r}")
    bad = np.flatnonzero((q < lower) | (q > upper))
    if bad.size:
        j = int(bad[0])
        raise _MeasureFailed(f"joint readback q{j + 1} = {math.degrees(q[j]):.3f} deg is outside the limits")


class _Session:
    """State of one run: devices, store, direction memory, counters."""

    def __init__(self, store: SessionStore, plan: Plan, driver: RobotDriver, mocap: MocapSource, body_id: int,
                 safety: CellSafety, others: Mapping[str, np.ndarray], other_drivers: Mapping[str, RobotDriver],
                 config: CollectConfig) -> None:
        self.store, self.plan, self.driver, self.mocap = store, plan, driver, mocap
        self.body_id, self.safety, self.config = body_id, safety, config
        self.static_others = {k: np.asarray(v, dtype=float) for k, v in others.items()}
        self.other_drivers = dict(other_drivers)
        spec = safety.cell.robot(driver.name).robot
        self.lower, self.upper = spec.lower_rad, spec.upper_rad
        self.dirs = np.zeros(6, dtype=int)
        self.t_offset = time.time() - store.created_wall()
        self.t_start = time.monotonic()

    def others(self) -> dict[str, np.ndarray]:
        out = dict(self.static_others)
        out.update({name: d.read_joints().q for name, d in self.other_drivers.items()})
        return out

    def measure(self, index: int, attempts: int) -> Sample:
        target = self.plan.targets[index]
        c = self.config
        q_now = self.driver.read_joints().q
        self.safety.check_motion(self.driver.name, q_now, target.q, self.others(), index)
        self.driver.move_to(target.q, c.speed_fraction)
        self.driver.wait_settled(c.settle_timeout_s, c.settle_tolerance_rad)
        moved = np.abs(target.q - q_now) > _MOVE_EPS_RAD
        self.dirs = np.where(moved, np.sign(target.q - q_now).astype(int), self.dirs)
        return self.measure_here(index, attempts)

    def measure_here(self, index: int, attempts: int) -> Sample:
        c = self.config
        q_before = np.asarray(self.driver.read_joints().q, dtype=float)
        _check_readback(q_before, self.lower, self.upper)
        try:
            frames = collect_window(self.mocap, self.body_id, c)
        except WindowFailed as e:
            raise _MeasureFailed(str(e)) from e
        except DriverError as e:
            raise _MeasureFailed(f"mocap: {e}") from e
        q_after = np.asarray(self.driver.read_joints().q, dtype=float)
        _check_readback(q_after, self.lower, self.upper)
        drift = float(np.max(np.abs(q_after - q_before)))
        if drift > math.radians(c.still_tolerance_deg):
            raise _MeasureFailed(f"the arm moved {math.degrees(drift):.4f} deg during the dwell")
        p, quat, std_p, std_r, err = average_frames(frames)
        return Sample(index, q_before, p, quat, std_p, std_r, err, len(frames),
                      self.t_offset + time.monotonic() - self.t_start, self.dirs.copy(), attempts)

    def visit(self, index: int) -> str | None:
        """Measure and store one target; returns the skip reason, or None when measured."""
        c = self.config
        target = self.plan.targets[index]
        driver_faults = measure_faults = 0
        at_target = False
        while True:
            attempts = driver_faults + measure_faults + 1
            try:
                sample = self.measure_here(index, attempts) if at_target else self.measure(index, attempts)
                self.store.add_sample(sample, target.robot, target.kind, target.cluster, self.lower, self.upper)
                return None
            except _MeasureFailed as e:
                measure_faults += 1
                reason = str(e)
                log.warning("target %d: %s (attempt %d)", index, reason, attempts)
                at_target = True
                self._reconnect_mocap()
                if measure_faults > c.mocap_retries:
                    break
            except DataError as e:
                reason = f"sample rejected: {e.reason}"
                break
            except DriverError as e:
                driver_faults += 1
                reason = str(e)
                log.warning("target %d: driver fault: %s (attempt %d)", index, reason, attempts)
                at_target = False
                self._recover(e)
                if driver_faults > c.driver_retries:
                    break
        self.store.add_skipped(index, target.robot, target.kind, target.cluster, reason, attempts)
        log.warning("target %d skipped: %s", index, reason)
        return reason

    def _recover(self, e: DriverError) -> None:
        try:
            if isinstance(e, DriverDisconnected):
                self.driver.connect()
            elif isinstance(e, DriverTimeout):
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


def run_session(session_dir: str | Path, driver: RobotDriver, mocap: MocapSource, safety: CellSafety, *,
                body_id: int, plan: Plan | None = None, others: Mapping[str, np.ndarray] | None = None,
                other_drivers: Mapping[str, RobotDriver] | None = None, config: CollectConfig = CollectConfig(),
                resume: bool = False, retry_skipped: bool = False, progress: bool = True) -> SessionResult:
    """Run (or resume) a guided collection session. Devices must be connected.

    Args:
        session_dir: the session folder; a new session needs a fresh folder.
        driver: the arm being calibrated; ``driver.name`` must match the plan's robot.
        mocap: any mocap source (simulated, NatNet, Zenoh subscriber).
        safety: the cell's safety checker; every target is checked before any motion.
        body_id: rigid-body id of the arm's tool marker in ``mocap``.
        plan: the targets; required for a new session, optional on resume (must equal the stored plan).
        others: joint angles [rad] (6,) of the other arms, held still during the session.
        other_drivers: drivers of the other arms, read before every move (takes precedence over ``others``).
        config: motion, measurement and retry options.
        resume: continue an existing session at the first target not yet recorded.
        retry_skipped: on resume, also try the targets recorded as skipped again.
        progress: show a progress bar with an ETA.

    Raises:
        UnsafeTarget: a target or a path is unsafe (checked for the whole plan before the first motion).
        SessionAborted: ``max_consecutive_skips`` targets in a row were skipped.
        DataError: the folder already holds a session (without resume) or holds none (with resume).
    """
    t_run = time.monotonic()
    session_dir = Path(session_dir)
    if resume:
        store = SessionStore(session_dir)
        stored = store.plan()
        if plan is not None and plan.to_dict()["targets"] != stored.to_dict()["targets"]:
            store.close()
            raise DataError(store.path, None, "plan", "the given plan differs from the session's plan")
        plan = stored
    else:
        if plan is None:
            raise ConfigError("run_session", "plan", "a new session needs a plan")
        store = SessionStore(session_dir, create=True)
        store.init(plan, {"robot": driver.name, "body_id": body_id, "config": asdict(config)})
    with store:
        if plan.robots != (driver.name,):
            raise ConfigError("run_session", "plan", f"the plan moves {', '.join(plan.robots)} but the driver is "
                                                     f"{driver.name}; one robot per session")
        if resume and retry_skipped:
            store.forget_skipped()
        done = store.done()
        pending = [i for i in range(len(plan)) if i not in done]
        session = _Session(store, plan, driver, mocap, body_id, safety, others or {}, other_drivers or {}, config)
        if pending:
            safety.check_plan(driver.name, plan.q[pending], session.others(), driver.read_joints().q)
        n_new = 0
        consecutive = 0
        bar = tqdm(total=len(plan), initial=len(done), unit="target", desc=f"{driver.name} collect",
                   disable=not progress)
        try:
            for index in pending:
                reason = session.visit(index)
                n_new += 1
                bar.update(1)
                consecutive = consecutive + 1 if reason else 0
                if consecutive >= config.max_consecutive_skips:
                    raise SessionAborted(f"{consecutive} targets in a row skipped (last: {reason}); fix the cause "
                                         f"and resume the session in {session_dir}")
        except BaseException:
            try:
                driver.stop()
            except DriverError as e:
                log.warning("could not stop %s after the session failed: %s", driver.name, e)
            raise
        finally:
            bar.close()
        skipped = tuple((r["target_index"], r["reason"]) for r in store.rows("skipped"))
        n_ok = len(store.rows("ok"))
    return SessionResult(session_dir, len(plan), n_ok, len(skipped), n_new, skipped,
                         n_ok + len(skipped) == len(plan), time.monotonic() - t_run)


def export(session_dir: str | Path, out_csv: str | Path, kinds: Sequence[str] | None = None) -> int:
    """Write the session's measured samples as a recording CSV (extra columns: cluster, t, dir1..dir6,
    marker_err, frames).

    Args:
        session_dir: the session folder.
        out_csv: the recording file to write (atomically).
        kinds: target kinds to include (``anchor``, ``perturb``, ``cpa``, ``validation``); all when None.

    Returns:
        The number of samples written.

    Raises:
        DataError: no session, or no measured sample of the requested kinds (nothing is written).
    """
    with SessionStore(session_dir) as store:
        rows = [r for r in store.rows("ok") if kinds is None or r["kind"] in kinds]
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
