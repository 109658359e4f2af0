"""Errors of the MotoROS adapter; all are DriverError (hence CellCalError) and carry their data."""

from __future__ import annotations

import numpy as np

from drivers.errors import DriverError, InvalidArgument, RobotFault

__all__ = ["ControllerNotReady", "InvalidArgument", "NonFiniteFeedback"]  # InvalidArgument: shared, in drivers.errors
from drivers.motoros.codes import SUBCODE_NAMES


class NonFiniteFeedback(DriverError):
    """The controller reported joint angles that are NaN or infinite; no motion is derived from them.

    Args:
        device: the driver.
        group: motion group index.
        q: the reported joint angles [rad].
    """

    def __init__(self, device: str, group: int, q: np.ndarray) -> None:
        self.group = group
        self.q = np.array(q, dtype=float)
        bad = [int(i) + 1 for i in np.flatnonzero(~np.isfinite(self.q))]  # ints: np.int64(1) in the message
        super().__init__(device, f"joint feedback of group {group} is not finite (joints {bad}: "
                                 f"{self.q.tolist()}); refusing to move")


class ControllerNotReady(RobotFault):
    """The controller refused motion; ``subcode`` is the MotoROS NOT_READY / FALSE subcode (0 if none).

    Args:
        device: the driver.
        what: the request or check that failed (``START_TRAJ_MODE``, ``motion refused``).
        subcode: MotoROS subcode (``5005`` = not in remote mode), 0 when the cause came from RobotStatus.
        cause: words for the cause (defaults to the subcode's name, followed by the subcode).
    """

    def __init__(self, device: str, what: str, subcode: int = 0, cause: str | None = None) -> None:
        self.what = what
        self.subcode = subcode
        self.cause = cause or SUBCODE_NAMES.get(subcode, f"subcode {subcode}")
        suffix = f" (subcode {subcode})" if subcode and cause is None else ""
        super().__init__(device, f"{what}: {self.cause}{suffix}")
