"""Simulated devices that ship in the package: an arm backed by a twin and a motion-capture system."""

from drivers.sim.clock import SimClock
from drivers.sim.mocap import SimMocapConfig, SimMocapSource
from drivers.sim.robot import SimFault, SimRobotConfig, SimRobotDriver
from drivers.sim.truth import PoeTruth, Truth, planted_truth

__all__ = [
    "PoeTruth",
    "SimClock",
    "SimFault",
    "SimMocapConfig",
    "SimMocapSource",
    "SimRobotConfig",
    "SimRobotDriver",
    "Truth",
    "planted_truth",
]
