"""The fake MotoROS controller of a whole cell: every motion group of ``cell.controller``, arms from the YAMLs.

``build_fake_controller`` makes the in-process fake (tests, rehearsals); ``run_fake_controller`` serves it
until told to stop, as the ``cellcal fake-controller`` process does, with fault injection from outside the
process: SIGUSR1 raises alarm 4107, SIGUSR2 toggles non-finite (NaN) joint feedback. A lost connection is
simulated by killing the process; a restarted one binds the same ports (SO_REUSEADDR) and MotorosLink
reconnects to it.

The cell object only needs ``cell.path``, ``cell.robots[name].robot`` (``max_speed_rad_s``,
``pulses_per_rad``) and ``cell.controller`` (``host``, ``motion_port``, ``state_port``, ``groups``: robot name
-> MotoROS group index, which MotoROS numbers 0..n-1).
"""

from __future__ import annotations

import logging
import signal
import threading
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from calibration.errors import ConfigError
from drivers.motoros.fake import FakeMotorosController

log = logging.getLogger("cellcal.drivers")

ALARM_ON_SIGUSR1 = 4107
N_JOINTS = 6


def _groups(cell: Any) -> list[str]:
    """Robot names ordered by MotoROS group index; ConfigError unless the indices are 0..n-1."""
    controller = getattr(cell, "controller", None)
    if controller is None:
        raise ConfigError(cell.path, "controller", "the cell has no controller block; a fake controller needs one")
    groups: Mapping[str, int] = controller.groups
    unknown = [name for name in groups if name not in cell.robots]
    if unknown:
        raise ConfigError(cell.path, "controller.groups", f"unknown robots {unknown}; valid: {', '.join(cell.robots)}")
    order = sorted(groups, key=lambda name: groups[name])
    if [groups[name] for name in order] != list(range(len(order))) or not 1 <= len(order) <= 4:
        raise ConfigError(cell.path, "controller.groups",
                          f"expected 1..4 robots on group indices 0..n-1 (MotoROS numbering), got {dict(groups)}")
    return order


def build_fake_controller(cell: Any, *, initial_q: dict[str, np.ndarray] | None = None, host: str | None = None,
                          motion_port: int | None = None, state_port: int | None = None,
                          servo_on_delay_s: float = 0.1, publish_hz: float = 100.0) -> FakeMotorosController:
    """A (not yet started) fake controller serving every group of ``cell.controller.groups``.

    Args:
        cell: a ``CellSpec`` with a ``controller`` block.
        initial_q: starting joint angles [rad] per robot name, shape (6,); missing robots start at zeros.
        host, motion_port, state_port: override ``cell.controller``'s (0 = a free port).
        servo_on_delay_s: time START_TRAJ_MODE takes to turn the servos on [s].
        publish_hz: state publication rate [Hz].

    Raises:
        ConfigError: no controller block, an unknown robot, or group indices other than 0..n-1.
    """
    names = _groups(cell)
    specs = [cell.robots[name].robot for name in names]
    q0 = np.zeros((len(names), N_JOINTS))
    for i, name in enumerate(names):
        if initial_q is not None and name in initial_q:
            q = np.asarray(initial_q[name], dtype=float)
            if q.shape != (N_JOINTS,) or not np.all(np.isfinite(q)):
                raise ConfigError(cell.path, f"initial_q.{name}", f"expected {N_JOINTS} finite angles [rad], got {q}")
            q0[i] = q
    ctrl = cell.controller
    return FakeMotorosController(
        n_groups=len(names), n_joints=N_JOINTS,
        max_speed_rad_s=np.stack([np.asarray(s.max_speed_rad_s, dtype=float) for s in specs]),
        pulses_per_rad=np.stack([np.asarray(s.pulses_per_rad, dtype=float) for s in specs]),
        publish_hz=publish_hz, host=ctrl.host if host is None else host,
        motion_port=ctrl.motion_port if motion_port is None else motion_port,
        state_port=ctrl.state_port if state_port is None else state_port, initial_q=q0,
        servo_on_delay_s=servo_on_delay_s)


def run_fake_controller(cell: Any, stop: threading.Event, *, initial_q: dict[str, np.ndarray] | None = None,
                        host: str | None = None, motion_port: int | None = None, state_port: int | None = None,
                        servo_on_delay_s: float = 1.0,
                        on_ready: Callable[[FakeMotorosController], None] | None = None) -> None:
    """Serve the cell's fake controller until ``stop`` is set; call from the main thread.

    SIGUSR1 raises alarm 4107 (START_TRAJ_MODE resets it, as on a real controller), SIGUSR2 toggles NaN joint
    feedback. The previous handlers are restored on return. ``on_ready`` is called with the started fake
    (its ports are bound).

    Raises:
        ConfigError: see ``build_fake_controller``.
        OSError: a port is taken.
    """
    fake = build_fake_controller(cell, initial_q=initial_q, host=host, motion_port=motion_port,
                                 state_port=state_port, servo_on_delay_s=servo_on_delay_s)

    def alarm(signum: int, frame: object) -> None:
        log.warning("fake controller: SIGUSR1, raising alarm %d", ALARM_ON_SIGUSR1)
        fake.set_alarm(ALARM_ON_SIGUSR1)

    def toggle_feedback(signum: int, frame: object) -> None:
        fake.set_nonfinite_feedback(not fake.nonfinite_feedback)
        log.warning("fake controller: SIGUSR2, non-finite joint feedback %s",
                    "on" if fake.nonfinite_feedback else "off")

    previous = {signal.SIGUSR1: signal.signal(signal.SIGUSR1, alarm),
                signal.SIGUSR2: signal.signal(signal.SIGUSR2, toggle_feedback)}
    try:
        with fake:
            log.info("fake controller on %s: motion %d, state %d, groups %s", fake.host, fake.motion_port,
                     fake.state_port, _groups(cell))
            if on_ready is not None:
                on_ready(fake)
            while not stop.wait(0.05):
                pass
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


def serve_fake_controller(cell: Any, seed: int = 0, stop: threading.Event | None = None, **kwargs: Any) -> None:
    """The notes' name for ``run_fake_controller``; ``seed`` is accepted for that contract and unused (the fake
    is deterministic). Without ``stop`` it serves until the process ends."""
    run_fake_controller(cell, stop if stop is not None else threading.Event(), **kwargs)
