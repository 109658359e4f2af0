"""Array types for annotations: numpy arrays of a known element type, so mypy checks what flows between the
numpy functions (whose results are otherwise untyped) and the models.

Shapes are not part of these types; docstrings give them with units (``q: joint angles [rad], shape (N, 6)``).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

#: A float64 array (the default dtype of every length, angle, pose and parameter vector here).
FloatArray = NDArray[np.float64]

#: A boolean array (masks: free parameters, inliers, samples in a region).
BoolArray = NDArray[np.bool_]

#: An integer index array (sample or parameter indices).
IntArray = NDArray[np.intp]
