"""Moved to :mod:`calibration.identification.observability`; this re-export keeps the old import path working."""

from calibration.identification.observability import (
                                                      DEFAULT_REACH_MM,
                                                      DEFAULT_RELATIVE_TOLERANCE,
                                                      Observability,
                                                      analyse,
                                                      analyse_jacobian,
                                                      filter_weights,
)

__all__ = ["DEFAULT_REACH_MM", "DEFAULT_RELATIVE_TOLERANCE", "Observability", "analyse", "analyse_jacobian",
           "filter_weights"]
