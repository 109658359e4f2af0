"""Identification: the one Levenberg-Marquardt solver and the geometric identification problem.

- :mod:`.lm`: the solver (damping, acceptance, stopping, an honest :class:`LMResult`) and the
  :class:`LeastSquaresProblem` protocol a problem implements (residuals, Jacobian, prior);
- :mod:`.geometric`: :class:`GeometricProblem` (minimal POE parameters from static poses, batched over
  clusters), the orientation weight and the weighted pose residuals shared by every problem;
- :mod:`.observability`: which parameter directions a data set sees, and the Tikhonov filter weights;
- :mod:`.cpa`: circular point analysis (joint axes from single-joint sweeps).

The joint geometry + physics refit of diagnosis (:class:`calibration.diagnosis.refit.JointProblem`) is another
problem of the same solver.
"""

from calibration.identification.geometric import (
                                                  DEFAULT_ORIENTATION_WEIGHT,
                                                  GeometricProblem,
                                                  Kinematics,
                                                  NlsResult,
                                                  rotation_residual_scale,
                                                  weighted_residuals,
)
from calibration.identification.lm import (
                                                  Groups,
                                                  LeastSquaresProblem,
                                                  Linearisation,
                                                  LMResult,
                                                  LMSettings,
                                                  Residuals,
                                                  StopReason,
                                                  solve,
)

__all__ = [
    "DEFAULT_ORIENTATION_WEIGHT", "GeometricProblem", "Groups", "Kinematics", "LMResult", "LMSettings",
    "LeastSquaresProblem", "Linearisation", "NlsResult", "Residuals", "StopReason", "rotation_residual_scale",
    "solve", "weighted_residuals",
]
