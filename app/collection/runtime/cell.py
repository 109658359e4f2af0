"""What a workflow asks of the cell at run time: the :class:`Cell` Protocol.

Two classes implement it: :class:`~app.collection.runtime.sim.SimCell` (both arms, the mocap and the Zenoh link
simulated on this machine) and :class:`~app.collection.runtime.real.RealCell` (the MotoROS controller and the mocap
bridge). The collection (:func:`~app.collection.collect.collect_arm`), the registration
(:func:`~app.collection.register.measure_registration`), the recalibration
(:func:`~app.workflows.recalibrate.recalibrate`) and the real contact validation
(:func:`~app.dual.validate_real.run_real_validation`) take a :class:`Cell` and call nothing else on it. The Protocol
is structural: neither class inherits it, mypy checks that each has every member (``tests/app/collection/test_cell_protocol.py``).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Protocol, Self

import numpy as np

from cell_config.loader import CellSpec
from drivers.base import MocapSource, RobotDriver

__all__ = ["Cell"]


class Cell(Protocol):
    """The cell a workflow moves and measures: every arm's driver, each arm's mocap, their parking poses.

    A context manager: entering opens (connects) everything, leaving closes it; a cell is used only while open.

    Attributes:
        cell: the cell description it was built from.
        drivers: robot name -> its connected driver (every arm of the cell: the other arms' live poses feed the
            safety checks).
        body_ids: robot name -> the rigid-body id its tool marker's frames carry in :meth:`mocap_for`.
        frames_received: mocap frames received so far (the demo's and ``collect``'s summary count).
    """

    @property
    def cell(self) -> CellSpec: ...

    @property
    def drivers(self) -> dict[str, RobotDriver]: ...

    @property
    def body_ids(self) -> Mapping[str, int]: ...

    @property
    def frames_received(self) -> int: ...

    def park_q(self, robot: str) -> np.ndarray:
        """Parking pose [rad] of ``robot``, shape (6,)."""
        ...

    def others(self, robot: str) -> dict[str, RobotDriver]:
        """Drivers of every arm but ``robot``."""
        ...

    def mocap_for(self, robot: str) -> MocapSource:
        """The mocap source of ``robot``'s tool marker (in its base frame when the cell is registered)."""
        ...

    def open(self) -> Self:
        """Connect everything; on failure whatever was opened is closed again."""
        ...

    def close(self) -> None:
        """Close everything; safe to call twice."""
        ...

    def __enter__(self) -> Self: ...

    def __exit__(self, *exc: object) -> None: ...
