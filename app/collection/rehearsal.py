"""The one-machine rehearsal as real OS processes: a private copy of rehearsal.yaml and process handles.

:func:`write_rehearsal_cell` writes a copy of ``cell_config/rehearsal.yaml`` with free loopback ports (so
several rehearsals, the tests and a developer's own never collide) and a speed cap of 1 (the fakes run in real
time). :class:`Process` starts a long-running ``cellcal`` command (fake-controller, fake-motive, mocap-bridge,
router, collect) as its own OS process and waits for its ready line; :func:`run_cellcal` runs one to its end.
Used by ``tests/app/collection/test_rehearsal.py`` and ``scripts/studies/rehearsal.py``.
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import yaml

from app.collection.plans.collection import Plan
from app.collection.plans.reader import read_plan
from cell_config.loader import PACKAGE_DIR

REPO = Path(__file__).resolve().parents[2]


def free_port(kind: int = socket.SOCK_STREAM) -> int:
    return free_ports(kind)[0]


def free_ports(*kinds: int) -> list[int]:
    """One free port per socket kind in ``kinds``, all different: every socket stays bound until all are picked
    (ports picked one after the other can repeat: the OS may hand a just-released port out again, and a rehearsal
    cell once got the same port for the controller's motion and state connections)."""
    with contextlib.ExitStack() as stack:
        socks = [stack.enter_context(socket.socket(socket.AF_INET, kind)) for kind in kinds]
        for s in socks:
            s.bind(("127.0.0.1", 0))
        return [int(s.getsockname()[1]) for s in socks]


def write_rehearsal_cell(folder: Path, via_router: bool = False, dwell_s: float | None = None,
                         stream_wait_s: float | None = None, first_frame_s: float | None = None,
                         **controller: Any) -> Path:
    """A copy of ``cell_config/rehearsal.yaml`` in ``folder`` with free ports; ``controller`` overrides keys.

    ``via_router``: the bridge and the collector both connect (as clients) to ``cellcal router`` instead of the
    collector connecting to the bridge. ``dwell_s``: the measurement window (``mocap.dwell_s``), when given;
    ``stream_wait_s``: how long the collector waits for a stopped mocap stream (``mocap.stream_wait_s``);
    ``first_frame_s``: how long opening the cell waits for each arm's first mocap frame (``mocap.first_frame_s``).
    """
    data = yaml.safe_load((PACKAGE_DIR / "rehearsal.yaml").read_text())
    for entry in data["robots"].values():
        entry["robot"] = str(PACKAGE_DIR / entry["robot"])
        entry["tool"] = str(PACKAGE_DIR / entry["tool"])
    tcp, udp = socket.SOCK_STREAM, socket.SOCK_DGRAM
    motion, state, bridge, router, command, data_port = free_ports(tcp, tcp, tcp, tcp, udp, udp)
    data["controller"].update({"motion_port": motion, "state_port": state, "max_speed_fraction": 1.0,
                               **controller})
    data["mocap"].update(command_port=command, data_port=data_port)
    if dwell_s is not None:
        data["mocap"]["dwell_s"] = dwell_s
    if stream_wait_s is not None:
        data["mocap"]["stream_wait_s"] = stream_wait_s
    if first_frame_s is not None:
        data["mocap"]["first_frame_s"] = first_frame_s
    data["zenoh"]["roles"]["bridge"]["listen"] = [f"tcp/127.0.0.1:{bridge}"]
    data["zenoh"]["roles"]["collector"]["connect"] = [f"tcp/127.0.0.1:{bridge}"]
    data["zenoh"]["roles"]["router"]["listen"] = [f"tcp/127.0.0.1:{router}"]
    if via_router:
        for role in ("bridge", "collector"):
            data["zenoh"]["roles"][role] = {"mode": "client", "connect": [f"tcp/127.0.0.1:{router}"]}
    path = folder / "rehearsal.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def cellcal_argv(cell: Path, *args: str) -> list[str]:
    return [sys.executable, "-m", "app.cli", "--cell", str(cell), *args]


def run_cellcal(cell: Path, *args: str, timeout_s: float = 180.0) -> subprocess.CompletedProcess[str]:
    """Run one cellcal command to its end (a separate OS process); stdin is closed, as in CI."""
    return subprocess.run(cellcal_argv(cell, *args), cwd=REPO, capture_output=True, text=True,
                          timeout=timeout_s, stdin=subprocess.DEVNULL, env=_env())


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    return env


class Process:
    """A long-running cellcal process (fake-controller, fake-motive, mocap-bridge, router, collect).

    ``start`` waits for the process's ready line (its first stdout line) when ``ready`` is True.
    """

    def __init__(self, cell: Path, *args: str) -> None:
        self.argv = cellcal_argv(cell, *args)
        self.name = args[0]
        self.proc: subprocess.Popen[str] | None = None
        self.lines: list[str] = []
        self._reader: threading.Thread | None = None
        self._terminated = False  # SIGTERM sent to the running process

    def start(self, ready: bool = True, timeout_s: float = 30.0) -> Process:
        self.lines = []
        self._terminated = False
        self.proc = subprocess.Popen(self.argv, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                     stdin=subprocess.DEVNULL, text=True, env=_env())
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()
        if ready:
            self.wait_ready(timeout_s)
        return self

    def wait_ready(self, timeout_s: float = 30.0) -> Process:
        """Wait for the started process's ready line (its first stdout line)."""
        if self.proc is None or self._reader is None:
            raise RuntimeError(f"{self.name} was never started")
        deadline = time.monotonic() + timeout_s
        while not self.lines:
            if self.proc.poll() is not None or time.monotonic() > deadline:
                self._reader.join(timeout=2)
                raise RuntimeError(f"{self.name} did not start: {''.join(self.lines)[-2000:]}")
            time.sleep(0.05)
        return self

    def _read(self) -> None:
        if self.proc is None or self.proc.stdout is None:
            return
        for line in self.proc.stdout:
            self.lines.append(line)

    @property
    def output(self) -> str:
        return "".join(self.lines)

    def signal(self, sig: int) -> None:
        if self.proc is not None:
            self.proc.send_signal(sig)

    def kill(self) -> None:
        """SIGKILL: the process gets no chance to clean up (a crash, a pulled plug)."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=10)

    def terminate(self) -> None:
        """SIGTERM, once, without waiting: the process closes its sockets and sessions and exits (see :meth:`stop`)."""
        if self.proc is not None and self.proc.poll() is None and not self._terminated:
            self.proc.send_signal(signal.SIGTERM)
            self._terminated = True

    def stop(self, timeout_s: float = 15.0) -> int:
        """SIGTERM and wait; returns the exit code."""
        if self.proc is None:
            return 0
        self.terminate()
        try:
            code = self.proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            code = self.proc.wait(timeout=5)
        if self._reader is not None:
            self._reader.join(timeout=5)
        return code

    def wait(self, timeout_s: float) -> int:
        if self.proc is None:
            raise RuntimeError(f"{self.name} was never started")
        code = self.proc.wait(timeout=timeout_s)
        if self._reader is not None:
            self._reader.join(timeout=5)
        return code


def small_plan(cell: Path, robot: str, out: Path, n: int = 14) -> Path:
    """The first ``n`` targets (two clusters) of the coarsest anchor grid."""

    full = out.with_suffix(".full.json")
    done = run_cellcal(cell, "plan", "--design", "grid", "--robot", robot, "--q2-step", "50", "--q3-step", "50",
                       "--out", str(full))
    if done.returncode != 0:
        raise RuntimeError(f"cellcal plan failed: {done.stderr}")
    plan = read_plan(full, "collection")
    Plan(plan.targets[:n], plan.params).save(out)
    return out


class Rehearsal:
    """The three device processes of the rehearsal: the controller and Motive, then the bridge that reads Motive."""

    def __init__(self, cell: Path, *motive_args: str, seed: int = 5) -> None:
        self.cell = cell
        self.controller = Process(cell, "fake-controller")
        self.motive = Process(cell, "fake-motive", "--seed", str(seed), *motive_args)
        self.bridge = Process(cell, "mocap-bridge")

    def __enter__(self) -> Rehearsal:
        try:
            self.controller.start(ready=False)  # the controller and Motive do not know of each other: start both
            self.motive.start(ready=False)
            self.controller.wait_ready()
            self.motive.wait_ready()
            self.bridge.start()  # after Motive serves, so its first connection attempt is answered
        except BaseException:
            self.__exit__()  # no device process outlives a failed start
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        processes = (self.bridge, self.motive, self.controller)
        for p in processes:  # all told at once: each takes a few tenths of a second to close its sockets and exit
            p.terminate()
        for p in processes:
            p.stop()


def sample_count(session: Path) -> int:
    """Samples measured so far in a session folder (read-only, while a collector may be writing)."""
    import sqlite3

    db = session / "session.sqlite"
    if not db.exists():
        return 0
    with sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=5) as con:
        try:
            return int(con.execute("SELECT COUNT(*) FROM samples WHERE status = 'ok'").fetchone()[0])
        except sqlite3.OperationalError:
            return 0
