"""Simulated devices that ship in the package: an arm backed by a twin and a motion-capture system."""

from drivers.sim.clock import SimClock
from drivers.sim.mocap import SimMocapConfig, SimMocapSource
from drivers.sim.robot import SimFault, SimRobotConfig, SimRobotDriver
from drivers.sim.truth import PoeTruth, Truth, TwinTruth, physics_truth, planted_truth, sim_context_to_twin

__all__ = [
    "PoeTruth",
    "SimClock",
    "SimFault",
    "SimMocapConfig",
    "SimMocapSource",
    "SimRobotConfig",
    "SimRobotDriver",
    "Truth",
    "TwinTruth",
    "physics_truth",
    "planted_truth",
    "sim_context_to_twin",
]
