"""Driver-side exceptions; every third-party or socket error is wrapped into one of these."""

from __future__ import annotations

from calibration.errors import CellCalError


class DriverError(CellCalError):
    """A device or network peer failed; ``device`` names it (``motoros@127.0.0.1:50240``)."""

    def __init__(self, device: str, reason: str) -> None:
        self.device = device
        self.reason = reason
        super().__init__(f"{device}: {reason}")


class InvalidArgument(DriverError):
    """A caller passed a driver, link or simulated device a value it cannot use; raised before anything is sent.

    Args:
        device: the driver, link or simulated device (``motoros@10.0.0.2:50240/R1``, ``sim:R1``, ``sim:clock``).
        argument: the parameter name (``speed_fraction``).
        value: what was passed.
        expected: what would have been accepted (``"in (0, 1]"``).
    """

    def __init__(self, device: str, argument: str, value: object, expected: str) -> None:
        self.argument = argument
        self.value = value
        self.expected = expected
        super().__init__(device, f"{argument} must be {expected}, got {value!r}")


class DriverTimeout(DriverError, TimeoutError):
    """A device did not answer or settle in time."""

    def __init__(self, device: str, what: str, seconds: float) -> None:
        self.seconds = seconds
        super().__init__(device, f"timed out after {seconds:.3g} s waiting for {what}")


class DriverDisconnected(DriverError, ConnectionError):
    """The connection to a device was lost (and reconnection, if tried, failed)."""


class RobotFault(DriverError):
    """The controller reports an alarm, an e-stop or servo off; motion is refused until it is cleared."""


class ProtocolError(DriverError):
    """A peer sent bytes that do not follow the protocol (bad length, unknown message, truncated packet)."""
