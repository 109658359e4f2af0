"""Should the pi fit damp a rigid motion of the whole arm (a base-frame error) toward nominal? Both ways.

``FitOptions.pi_base_free``: pi's Tikhonov filter toward nominal either damps every geometric parameter as it is
(``damped``), or damps what is left of them after their best rigid motion of the arm (``base free``,
:func:`calibration.identification.observability.base_free_prior`; :meth:`ExtendedKinematics.base_motion` gives the 6 directions), so a
mocap-to-base registration error costs the fit nothing. Printed, for both:

- **twins** (unless ``--no-twins``): the synthetic arms of ``scripts/benchmarks/bench_frames.py`` (planted geometry and joint
  compliance; training on clusters with joints 1, 4, 5, 6 within 3 deg, held-out poses that move every joint
  widely), with the base frame off by each ``--errors`` size (mm/deg: within what the frame check lets through),
  fitted as is: nls1 and pi both ways, held-out position mean / max [mm], on both arms;
- **training days** (unless ``--no-days``; ``--days`` picks them): on every R1 training recording of ``../shared/data/welding_motoman/PH_grad_data``
  (no test recording is read), pi both ways scored on clusters held out from training (the 5 folds of the
  recommendation: RMS [mm], and the paired standard error of the difference over clusters), and on the three
  extrapolation folds of ``scripts/studies/extrapolation_folds.py`` (the q1/q4-q6 steps, the q2 edges, the q3 edges held
  out; mean / max [mm]).

    PYTHONPATH=. python scripts/studies/pi_base_frame.py [--json FILE] [--no-twins] [--no-days] [--days test0801_R1,...]
        [--seeds 0,1,2,3,4] [--errors 0/0,1.5/0.1,3/0.2]
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from calibration.data.recording import put_in  # noqa: E402
from calibration.kinematics import so3  # noqa: E402
from calibration.kinematics.so3 import make_T  # noqa: E402
from scripts.benchmarks.bench_frames import tool_error_case_of  # noqa: E402
from scripts.studies.pi_registration import run  # noqa: E402

#: The ways pi is fitted (the FitOptions fields that differ from the defaults).
WAYS: dict[str, dict[str, Any]] = {"damped": {"pi_base_free": False}, "base free": {"pi_base_free": True}}
#: The planted base error's rotation axis and shift direction (any direction not along a joint axis).
ERROR_AXIS = np.array([0.6, -0.8, 0.0])
ERROR_SHIFT = np.array([0.48, 0.36, -0.8])


def base_error_case(arm: str, seed: int, shift_mm: float, angle_deg: float) -> tuple[Any, Any, Any]:
    """(cell entry, training, held-out recording) of a twin of :func:`tool_error_case_of` (no marker error) whose
    base frame is off by ``shift_mm`` and ``angle_deg``."""
    robot, train, test = tool_error_case_of(0.0, 0.0, seed, 3.0, arm)
    T_base = make_T(so3.exp(np.radians(angle_deg) * ERROR_AXIS / np.linalg.norm(ERROR_AXIS)),
                    shift_mm * ERROR_SHIFT / np.linalg.norm(ERROR_SHIFT))
    return robot, put_in(train, T_base, np.eye(4)), put_in(test, T_base, np.eye(4))


def main(argv: list[str] | None = None) -> int:
    return run(argv, __doc__, WAYS, "0/0,1.5/0.1,3/0.2", "base frame", base_error_case, ("base_mm", "base_deg"))


if __name__ == "__main__":
    sys.exit(main())
