"""Moved to :mod:`calibration.identification.cpa`; this re-export keeps the old import path working."""

from calibration.identification.cpa import (
                                            MIN_SWEEP_RAD,
                                            MIN_SWEEP_SAMPLES,
                                            Circle,
                                            fit_circle,
                                            identify_cpa,
                                            split_sweeps,
)

__all__ = ["MIN_SWEEP_RAD", "MIN_SWEEP_SAMPLES", "Circle", "fit_circle", "identify_cpa", "split_sweeps"]
