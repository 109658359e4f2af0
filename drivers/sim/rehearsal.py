"""The physics behind the one-machine rehearsal of the real cell: what only the fake peers know.

``cellcal fake-controller`` and ``cellcal fake-motive`` run as separate processes. The fake controller moves
simulated arms; the fake Motive watches them the way a real motion-capture system watches real arms: it reads
their joint angles from the controller's state port (as any MotoROS state client may), puts each arm's
physics twin at those angles, and reports the tool markers **in a mocap world frame that is neither robot's
base frame**. Everything here is derived from one seed, so both processes and a test that knows the seed
agree on it; no workflow of cellcal reads it (they must find the frames by ``cellcal register``).

* :func:`hidden_frames`: per robot the mocap-world -> base transform and a small marker offset on the tool.
* :func:`rehearsal_truths`: per robot the physics twin (planted geometry and gravity compliance).
* :class:`StateReader`: the latest joint angles per group from the controller's state port (the driver's reader).
* :class:`RehearsalMocap`: marker poses in the mocap world for the current joint angles.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from calibration.kinematics import so3
from calibration.physics import PlantedErrors
from drivers.errors import DriverError
from drivers.motoros.state import StateStream
from drivers.sim.truth import cell_truths


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
    u: np.ndarray = v / np.linalg.norm(v)
    return u


def rehearsal_truths(cell: Any, seed: int, errors: PlantedErrors = PlantedErrors(compliance_mm=1.0)
                     ) -> dict[str, Any]:
    """Each arm's physics twin (a :class:`~drivers.sim.truth.TwinTruth`), seeded like the simulated cell."""

    return cell_truths(cell, seed, errors)


class StateReader:
    """Latest joint angles per motion group, read from the controller's MotoROS state port (50241).

    A thin view of the driver's own :class:`~drivers.motoros.state.StateStream` (the same reader, reconnection and
    back-off), which does not take the motion connection the collector needs: MotoROS serves several state
    connections.

    Args:
        host: controller address. state_port: its state port.
    """

    def __init__(self, host: str, state_port: int) -> None:

        self._stop = threading.Event()
        self._stream = StateStream(host, state_port, f"motoros-state@{host}:{state_port}", self._stop,
                                   connect_timeout_s=1.0, backoff_s=0.05, max_backoff_s=0.5, stale_after_s=0.5)

    def start(self) -> StateReader:
        self._stream.start()
        return self

    def close(self) -> None:
        self._stop.set()
        self._stream.join()

    def joints(self, group: int) -> np.ndarray | None:
        """Joint angles [rad] (6,) of ``group``, or None while none fresh arrived (controller away or restarting)."""
        try:
            feedback, _ = self._stream.feedback(group)
        except DriverError:
            return None
        return np.asarray(feedback.pos[:6], dtype=float).copy()


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
        self._last: dict[str, tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]] = {}  # robot -> (q, its pose)

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
        """The true marker pose of ``robot`` at ``q`` [rad] (6,) in the mocap world.

        A function of ``q`` only: the last one per robot is kept, so a still arm (most frames: the stream runs at
        240 Hz, the controller's feedback far slower) costs no twin evaluation.
        """
        last = self._last.get(robot)
        if last is not None and np.array_equal(last[0], q):
            return last[1][0].copy(), last[1][1].copy()
        R, p = self.truths[robot].pose(np.atleast_2d(q))
        hf = self.frames[robot]
        T = hf.T_world_base @ rigid(R[0], p[0]) @ hf.T_tool_marker
        self._last[robot] = (np.array(q, dtype=float), (T[:3, :3].copy(), T[:3, 3].copy()))
        return T[:3, :3], T[:3, 3]
