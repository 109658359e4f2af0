"""The physics behind the one-machine rehearsal of the real cell: what only the fake peers know.

``cellcal fake-controller`` and ``cellcal fake-motive`` run as separate processes. The fake controller moves
simulated arms; the fake Motive watches them the way a real motion-capture system watches real arms: it reads
their joint angles from the controller's state port (as any MotoROS state client may), puts each arm's
physics twin at those angles, and reports the tool markers **in a mocap world frame that is neither robot's
base frame**. Everything here is derived from one seed, so both processes and a test that knows the seed
agree on it; no workflow of cellcal reads it (they must find the frames by ``cellcal register``).

* :func:`hidden_frames`: per robot the mocap-world -> base transform and a small marker offset on the tool.
* :func:`rehearsal_truths`: per robot the physics twin (planted geometry and gravity compliance).
* :class:`StateReader`: a MotoROS state-port client that keeps the latest joint feedback per group.
* :class:`RehearsalMocap`: marker poses in the mocap world for the current joint angles.
"""

from __future__ import annotations

import logging
import math
import socket
import threading
import time
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from calibration import so3
from calibration.physics import PlantedErrors
from drivers.errors import ProtocolError

log = logging.getLogger("cellcal.drivers")


def rigid(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Homogeneous transform (4, 4) from a rotation (3, 3) and a translation (3,) [mm]."""
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, p
    return T


@dataclass(frozen=True)
class HiddenFrames:
    """What the fake Motive knows about one arm and cellcal must find.

    Attributes:
        T_world_base: the robot base in the mocap world (4, 4) [mm].
        T_tool_marker: the marker rigid body relative to the twin's tool frame (4, 4) [mm]: Motive's rigid
            body is defined by where its markers happen to be, never exactly where the tool YAML says.
    """

    T_world_base: np.ndarray
    T_tool_marker: np.ndarray


def hidden_frames(cell: Any, seed: int) -> dict[str, HiddenFrames]:
    """The hidden mocap world of a rehearsal, derived from ``seed``.

    R1's base is placed anywhere (any heading, a tilt of up to 0.5 deg, metres away); every other arm sits where
    ``cell.yaml`` says relative to R1, off by a hidden 1-3 mm and 0.02-0.05 deg (a real cell survey is never
    exact, and ``cellcal register`` reports that difference). Each marker is 1-4 mm and 0.2-0.8 deg off the
    tool YAML.
    """
    rng = np.random.default_rng(np.random.SeedSequence([seed, 7141]))
    heading = rng.uniform(-math.pi, math.pi)
    tilt = np.radians(rng.uniform(0.1, 0.5)) * _unit(rng.normal(size=2))
    R_w1 = so3.exp(np.array([tilt[0], tilt[1], heading]))
    p_w1 = np.array([rng.uniform(-3000, 3000), rng.uniform(-3000, 3000), rng.uniform(300, 1500)])
    T_world_r1 = rigid(R_w1, p_w1)
    out: dict[str, HiddenFrames] = {}
    for name in cell.robots:
        T_cell_base = np.asarray(cell.robot(name).T_cell_base, dtype=float)
        if np.allclose(T_cell_base, np.eye(4)):
            T_survey = np.eye(4)
        else:
            T_survey = rigid(so3.exp(np.radians(rng.uniform(0.02, 0.05)) * _unit(rng.normal(size=3))),
                             rng.uniform(1.0, 3.0) * _unit(rng.normal(size=3)))
        T_marker = rigid(so3.exp(np.radians(rng.uniform(0.2, 0.8)) * _unit(rng.normal(size=3))),
                         rng.uniform(1.0, 4.0) * _unit(rng.normal(size=3)))
        out[name] = HiddenFrames(T_world_r1 @ T_cell_base @ T_survey, T_marker)
    return out


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def rehearsal_truths(cell: Any, seed: int, errors: PlantedErrors = PlantedErrors(compliance_mm=1.0)
                     ) -> dict[str, Any]:
    """Each arm's physics twin (a :class:`~drivers.sim.truth.TwinTruth`), seeded like the simulated cell."""
    from drivers.sim.truth import cell_truths

    return cell_truths(cell, seed, errors)


class StateReader:
    """Latest joint feedback per motion group, read from a MotoROS state port (50241) in a thread.

    A MotoROS controller serves several state connections, so this reader does not take the motion
    connection the collector needs. It reconnects, with a capped back-off, when the controller goes away.

    Args:
        host: controller address. state_port: its state port.
        retry_s: delay between connection attempts [s].
    """

    def __init__(self, host: str, state_port: int, retry_s: float = 0.2) -> None:
        self.host, self.state_port, self.retry_s = host, state_port, retry_s
        self.device = f"motoros-state@{host}:{state_port}"
        self._latest: dict[int, tuple[np.ndarray, float]] = {}
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="rehearsal-state", daemon=True)

    def start(self) -> "StateReader":
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)

    def joints(self, group: int, max_age_s: float = 0.5) -> np.ndarray | None:
        """Joint angles [rad] (6,) of ``group``, or None when none newer than ``max_age_s`` [s] arrived."""
        with self._lock:
            got = self._latest.get(group)
        if got is None or time.monotonic() - got[1] > max_age_s:
            return None
        return got[0]

    def _run(self) -> None:
        from drivers.motoros.codec import JointFeedback, JointFeedbackEx, decode
        from drivers.motoros.framing import Framer, recv_into_framer

        while not self._stop.is_set():
            try:
                sock = socket.create_connection((self.host, self.state_port), timeout=1.0)
            except OSError:
                self._stop.wait(self.retry_s)
                continue
            sock.settimeout(0.1)
            framer = Framer(self.device)
            try:
                while not self._stop.is_set():
                    try:
                        packets = recv_into_framer(sock, framer)
                    except TimeoutError:
                        continue
                    for packet in packets:
                        try:
                            msg = decode(packet)
                        except ProtocolError:
                            continue
                        groups = msg.groups if isinstance(msg, JointFeedbackEx) else (
                            (msg,) if isinstance(msg, JointFeedback) else ())
                        with self._lock:
                            for fb in groups:
                                self._latest[fb.group] = (np.asarray(fb.pos[:6], dtype=float).copy(),
                                                          time.monotonic())
            except (ProtocolError, OSError) as e:
                log.info("%s: %s; reconnecting", self.device, e)
            finally:
                sock.close()
            self._stop.wait(self.retry_s)


class RehearsalMocap:
    """Marker poses in the hidden mocap world for the arms' current joint angles.

    Args:
        cell: the cell (robots, ``controller.groups``, ``mocap.rigid_bodies``).
        reader: where the joint angles come from.
        seed: the rehearsal seed (hidden frames and twins).
        truths: the twins (default: :func:`rehearsal_truths` of ``seed``).
    """

    def __init__(self, cell: Any, reader: StateReader, seed: int,
                 truths: Mapping[str, Any] | None = None) -> None:
        self.cell, self.reader = cell, reader
        self.frames = hidden_frames(cell, seed)
        self.truths = dict(truths) if truths is not None else rehearsal_truths(cell, seed)
        self.groups = dict(cell.controller.groups)
        self.bodies = dict(cell.mocap.rigid_bodies)

    def poses(self, t_s: float) -> dict[str, tuple[np.ndarray, np.ndarray] | None]:
        """Rigid-body name -> (R_world_marker (3, 3), p_world_marker (3,) [mm]); None when not tracked."""
        out: dict[str, tuple[np.ndarray, np.ndarray] | None] = {}
        for robot, body in self.bodies.items():
            q = self.reader.joints(self.groups[robot]) if robot in self.groups else None
            if q is None or not np.all(np.isfinite(q)):
                out[body] = None
                continue
            out[body] = self.marker_pose(robot, q)
        return out

    def marker_pose(self, robot: str, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The true marker pose of ``robot`` at ``q`` [rad] (6,) in the mocap world."""
        R, p = self.truths[robot].pose(np.atleast_2d(q))
        hf = self.frames[robot]
        T = hf.T_world_base @ rigid(R[0], p[0]) @ hf.T_tool_marker
        return T[:3, :3], T[:3, 3]
