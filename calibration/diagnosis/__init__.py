"""Diagnosis: find the physics a kinematic model left out, model it and show the fit improve.

Math only: the workflow that reads files and writes reports is :mod:`app.diagnose`.
"""

from calibration.diagnosis.candidates import KINDS, Candidate, Untested, library, signature, visibility
from calibration.diagnosis.core import DiagnoseOptions, diagnose
from calibration.diagnosis.drivers import Driver, Mismatch, context_from_recording, drivers, locate_mismatch
from calibration.diagnosis.noise import NoiseFloor, noise_floor
from calibration.diagnosis.refit import JointFit, JointProblem
from calibration.diagnosis.report import SCHEMA, Accuracy, Diagnosis, Evidence, FoundEffect, PlotData
from calibration.diagnosis.selection import LinearSelection, SelectionOptions, Step, blocked_folds, forward_select

__all__ = [
    "Accuracy", "Candidate", "DiagnoseOptions", "Diagnosis", "Driver", "Evidence", "FoundEffect", "JointFit",
    "JointProblem", "KINDS", "LinearSelection", "Mismatch", "NoiseFloor", "PlotData", "SCHEMA", "SelectionOptions",
    "Step", "Untested", "blocked_folds", "context_from_recording", "diagnose", "drivers", "forward_select",
    "library", "locate_mismatch", "noise_floor", "signature", "visibility",
]
