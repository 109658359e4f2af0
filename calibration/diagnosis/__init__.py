"""Diagnosis: find the physics a kinematic model left out, model it and show the fit improve.

- :mod:`.core`: :func:`diagnose` as named steps (split, model in use, residual drivers, candidate signatures,
  selection, held-out confirmation, refit, report);
- :mod:`.inuse`: the model in use, of any kind, as extended kinematics; :mod:`.extended`: candidates that are
  blocks of it;
- :mod:`.drivers`: what the residual follows; :mod:`.candidates`: the candidate library and signatures;
- :mod:`.selection`: the linearised selection and the one acceptance rule (:class:`Evidence`);
- :mod:`.refit`: the joint refit; :mod:`.model`: the refitted model file; :mod:`.noise`: the noise floor;
- :mod:`.report`: the result dataclasses and their JSON; :mod:`.explain`: their plain-language sentences;
- :mod:`.synthetic`: concealed synthetic cases for tests and proofs.

Math only: the workflow that reads files and writes reports is :mod:`app.workflows.diagnose`.
"""

from calibration.diagnosis.candidates import KINDS, Untested
from calibration.diagnosis.core import DiagnoseOptions, diagnose
from calibration.diagnosis.drivers import Driver, Mismatch, drivers, locate_mismatch
from calibration.diagnosis.extended import StructuralDeflection, ToolFrame
from calibration.diagnosis.inuse import InUse
from calibration.diagnosis.noise import NoiseFloor, noise_floor
from calibration.diagnosis.refit import JointFit, JointProblem
from calibration.diagnosis.refitted_model import result_model
from calibration.diagnosis.report import SCHEMA, Accuracy, Diagnosis, EffectEvidence, FoundEffect, PlotData
from calibration.diagnosis.selection import Evidence, SelectionOptions, blocked_folds

__all__ = [
    "Accuracy", "DiagnoseOptions", "Diagnosis", "Driver", "EffectEvidence", "Evidence",
    "FoundEffect", "InUse", "JointFit", "JointProblem", "KINDS", "Mismatch",
    "NoiseFloor", "PlotData", "SCHEMA", "SelectionOptions", "StructuralDeflection", "ToolFrame", "Untested",
    "blocked_folds", "diagnose", "drivers", "locate_mismatch", "noise_floor", "result_model",
]
