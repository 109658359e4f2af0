"""Diagnosis: find the physics a kinematic model left out, model it and show the fit improve.

Math only: the workflow that reads files and writes reports is :mod:`app.diagnose`.
"""

from calibration.diagnosis.candidates import KINDS, Candidate, Untested, library, signature, visibility
from calibration.diagnosis.core import DiagnoseOptions, diagnose
from calibration.diagnosis.extended import ExtendedEffect, MassFreeCompliance, StructuralDeflection, ToolFrame
from calibration.diagnosis.inuse import InUse
from calibration.diagnosis.model import DiagnosedModel, result_model
from calibration.diagnosis.drivers import Driver, Mismatch, drivers, locate_mismatch
from calibration.diagnosis.noise import NoiseFloor, noise_floor
from calibration.diagnosis.refit import JointFit, JointProblem
from calibration.diagnosis.report import SCHEMA, Accuracy, Diagnosis, Evidence, FoundEffect, PlotData
from calibration.diagnosis.selection import LinearSelection, SelectionOptions, Step, blocked_folds, forward_select

__all__ = [
    "Accuracy", "Candidate", "DiagnoseOptions", "DiagnosedModel", "Diagnosis", "Driver", "Evidence",
    "ExtendedEffect", "FoundEffect", "InUse", "JointFit", "JointProblem", "MassFreeCompliance",
    "StructuralDeflection", "ToolFrame", "result_model", "KINDS", "LinearSelection", "Mismatch", "NoiseFloor", "PlotData", "SCHEMA", "SelectionOptions",
    "Step", "Untested", "blocked_folds", "diagnose", "drivers", "forward_select",
    "library", "locate_mismatch", "noise_floor", "signature", "visibility",
]
