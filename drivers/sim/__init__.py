"""Simulated devices that ship in the package: an arm backed by a twin, a motion-capture system, a CAN probe
and the contact sensor behind it; the truths the arms are backed by (the one planter, :mod:`drivers.sim.truth`)."""

from drivers.sim.can_probe import SimulatedProbe
from drivers.sim.clock import SimClock
from drivers.sim.contact import SimContactSensor
from drivers.sim.mocap import SimMocapConfig, SimMocapSource
from drivers.sim.robot import SimFault, SimRobotConfig, SimRobotDriver
from drivers.sim.truth import Truth, TwinTruth, cell_truths, planted_truth, sim_context_to_twin

__all__ = [
    "SimClock",
    "SimContactSensor",
    "SimFault",
    "SimMocapConfig",
    "SimMocapSource",
    "SimRobotConfig",
    "SimRobotDriver",
    "SimulatedProbe",
    "Truth",
    "TwinTruth",
    "cell_truths",
    "planted_truth",
    "sim_context_to_twin",
]
