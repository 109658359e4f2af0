"""Several training recordings (days) in one fit: one arm model, one pair of frames per recording.

Each day's mocap-to-base registration and tool-marker registration differ a little (see
``../shared/data/welding_motoman``), so the recordings are not pooled as they are. Alternation:

1. the first recording fixes the gauge: its frames stay the identity (or the frames-first correction when its
   frame check found a problem), and the arm fitted on it alone (``reference``, the physics-informed ``pi``) gives
   every other recording's frames (both 6-DOF frames, :func:`calibration.frames.check.fit_frames`);
2. the arm is fitted on all recordings with their frames taken out (:func:`calibration.data.recording.take_out`), cluster
   ids kept apart, and the frames are refitted against it (``ROUNDS`` times).

Any method is then fitted on the pooled corrected recordings; the models are in the first recording's frames
(``rebase`` moves one to another day).

What differs between days: the frames (mm, deg), and per recording the joint model's training RMS against that
recording's own single-day fit. A ratio well above 1 (``KINEMATICS_RATIO_LIMIT``) means one arm cannot explain
every day: the arm's kinematics (not only the frames) changed between them. Which parameters differ, beyond the
noise and only along the directions each day identifies, comes from :func:`calibration.frames.daydiff.compare_days`
(``MultiDayFit.differences``) when the nominal arm is a constant POE model.

The two verdicts answer different questions and can both hold: the ratio is about accuracy (does one arm serve
every day?), the per-parameter tests about significance (did anything change beyond the measurement noise?). On
thousands of poses the tests see changes of a fraction of a millimetre that cost the joint fit a few per cent,
so "the frames explain the differences" (accuracy) and "the kinematics differ beyond the noise" (significance)
is a common pair; :meth:`MultiDayFit.summary` says so in a line of its own.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from calibration.arm import Arm
from calibration.data.recording import Recording, take_out
from calibration.errors import ModelError
from calibration.evaluation.metrics import errors
from calibration.frames.check import FramedFit, FrameFit, base_free, check_recording, fit_frames
from calibration.frames.daydiff import compare_days, day_names
from calibration.methods.fitter import Fitter
from calibration.methods.options import FitOptions
from calibration.models.base import KinematicModel
from calibration.models.rebased import RebasedModel

#: Rounds of frames and pooled arm after the start (frames against the first recording's own fit).
ROUNDS = 1
#: A day whose joint-fit training RMS exceeds its own single-day fit's by this factor is reported as a
#: kinematic change (not only frames).
KINEMATICS_RATIO_LIMIT = 1.25


@dataclass(frozen=True)
class Day:
    """One recording's part of a joint fit.

    Attributes:
        name: the recording (its file or folder name; its source when two share one).
        n_samples: its pose count.
        frames: its frames against the joint arm (``frames.result.T_base_correction`` etc.), None for the first.
        joint_rms_mm: position RMS of the joint model (with this recording's frames) on it [mm].
        own_rms_mm: position RMS of the reference method fitted on this recording alone [mm].
    """

    name: str
    n_samples: int
    frames: FrameFit | None
    joint_rms_mm: float
    own_rms_mm: float

    @property
    def ratio(self) -> float:
        return self.joint_rms_mm / max(self.own_rms_mm, 1e-12)

    def to_json(self) -> dict[str, Any]:
        return {"name": self.name, "samples": self.n_samples,
                "frames": None if self.frames is None else self.frames.to_json(),
                "joint_rms_mm": round(self.joint_rms_mm, 4), "own_rms_mm": round(self.own_rms_mm, 4),
                "ratio": round(self.ratio, 3)}


@dataclass(frozen=True)
class MultiDayFit:
    """Outcome of :func:`fit_days`.

    Attributes:
        fitter: fits any method on the pooled recordings with their frames taken out; its models are in the first
            recording's frames, and ``fitter.train`` is the pooled recordings in those frames.
        days: each recording's frames and figures.
        reference: the method the frames and the figures were fitted with.
        differences: what differs between the recordings per parameter (:class:`calibration.frames.daydiff.DaysResult`),
            None when not computed.
    """

    fitter: Fitter | FramedFit
    days: tuple[Day, ...]
    reference: str
    differences: Any = None

    @property
    def kinematics_changed(self) -> bool:
        """One arm does not explain every recording: some day's joint-fit RMS is ``KINEMATICS_RATIO_LIMIT`` times
        its own fit's or more (the arm is then a compromise, so every day's ratio grows; the largest is the odd
        one out)."""
        return any(d.ratio > KINEMATICS_RATIO_LIMIT for d in self.days)

    @property
    def worst(self) -> str:
        """The recording one arm explains least, relative to its own fit."""
        return max(self.days, key=lambda d: d.ratio).name

    def summary(self) -> str:
        lines = [f"{len(self.days)} recordings in one arm model, one pair of frames each (against the first "
                 f"recording's; {self.reference} fits):"]
        for d in self.days:
            frames = "the reference frames" if d.frames is None else f"frames off by {d.frames.size()}"
            lines.append(f"  {d.name}: {d.n_samples} poses, {frames}; training RMS {d.joint_rms_mm:.3f} mm in the "
                         f"joint fit against {d.own_rms_mm:.3f} mm fitted alone (x{d.ratio:.2f})")
        worst = max(d.ratio for d in self.days)
        if self.kinematics_changed:
            lines.append(f"Accuracy: one arm does not fit every recording nearly as well as its own fit does "
                         f"({self.worst} differs most: x{worst:.2f}, over x{KINEMATICS_RATIO_LIMIT}): the arm's "
                         "kinematics changed between the recordings beyond their frames; a joint model is a compromise.")
        else:
            lines.append(f"Accuracy: the frames explain the differences: one arm with each recording's frames fits "
                         f"every recording within x{KINEMATICS_RATIO_LIMIT} of that recording's own fit (at most "
                         f"x{worst:.2f}), so one model serves them all.")
        if self.differences is not None:
            lines.append(self.differences.summary())
            lines.append(self._relation(worst))
        return "\n".join(line for line in lines if line)

    def _relation(self, worst: float) -> str:
        """How the accuracy verdict (the ratios) and the significance verdict (``differences``) relate, when they
        seem to disagree."""
        significant = self.differences.kinematics_changed
        if significant and not self.kinematics_changed:
            return (f"Both hold: the kinematics did change beyond the measurement noise, but by too little to matter "
                    f"for accuracy: the joint fit costs at most x{worst:.2f} in training RMS against each recording's "
                    "own fit.")
        if self.kinematics_changed and not significant:
            return ("Both hold: no parameter differs beyond the noise along the directions both recordings identify, "
                    "yet one arm fits some recording worse than its own fit does: the difference lies in directions "
                    "only one recording identifies, or outside the arm's geometric parameters.")
        return ""

    def to_json(self) -> dict[str, Any]:
        return {"reference": self.reference, "days": [d.to_json() for d in self.days],
                "kinematics_ratio_limit": KINEMATICS_RATIO_LIMIT, "kinematics_changed": self.kinematics_changed,
                "differs_most": self.worst,
                "differences": None if self.differences is None else self.differences.to_json()}


def pool(recs: list[Recording], cluster_size: int = 7) -> Recording:
    """One recording of several: rows stacked, cluster ids offset so no two recordings share one; the extra
    columns all of them have."""
    keys = set.intersection(*(set(r.extra) for r in recs)) - {"cluster"}
    ids, offset = [], 0
    for r in recs:
        c = r.clusters(cluster_size)
        _, inverse = np.unique(c, return_inverse=True)
        ids.append(inverse + offset)
        offset += int(inverse.max()) + 1
    extra = {k: np.concatenate([r.extra[k] for r in recs]) for k in sorted(keys)}
    extra["cluster"] = np.concatenate(ids).astype(float)
    return Recording(np.concatenate([r.q for r in recs]), np.concatenate([r.p for r in recs]),
                     np.concatenate([r.quat for r in recs]), extra, " + ".join(r.source for r in recs))


def _rms(model: KinematicModel, rec: Recording) -> float:
    return float(np.sqrt(np.mean(errors(model, rec).position_mm ** 2)))


def fit_days(arm: Arm, recs: list[Recording], reference: str = "pi", cpa: Recording | None = None,
             options: FitOptions | None = None) -> MultiDayFit:
    """One arm over ``recs`` with per-recording frames (see the module docstring); every fit is
    ``Fitter.for_arm(arm, recording, cpa, options)``.

    Args:
        arm: the arm (its nominal model gives the first recording's frame check, the first frames, and the
            per-parameter comparison of the days).
        recs: two or more training recordings.
        reference: the method the frames are fitted against between rounds, and the days compared with.
        cpa: the CPA sweeps recording, or None.
        options: the fit options (default options when None).

    Raises:
        ModelError: fewer than two recordings.
    """
    if len(recs) < 2:
        raise ModelError(f"a joint fit needs at least two recordings, got {len(recs)}")
    nominal = arm.nominal_model()
    first = check_recording(nominal, recs[0])
    gauge = first.fits["base and tool"].result if first.found else None
    fixed = recs[0] if gauge is None else take_out(recs[0], gauge.T_base_correction, gauge.T_tool_correction)
    own = [Fitter.for_arm(arm, r, cpa, options).fit(reference)[0] for r in recs]
    joint = own[0] if gauge is None else RebasedModel(own[0].robot, own[0].method, own[0], gauge.T_base_correction,
                                                      gauge.T_tool_correction, 12)
    for _ in range(ROUNDS):
        frames = [FrameFit.of("base and tool", fit_frames(joint, r)) for r in recs[1:]]
        others = [take_out(r, f.result.T_base_correction, f.result.T_tool_correction)
                  for r, f in zip(recs[1:], frames)]
        pooled = Fitter.for_arm(arm, pool([fixed] + others), cpa, options)
        if gauge is not None:  # as the frames-first fit of one recording: the rigid part of its pi left free
            pooled = base_free(pooled)
        joint = pooled.fit(reference)[0]
    fitter: Fitter | FramedFit = pooled if gauge is None else \
        FramedFit(pooled, pool([recs[0]] + others), gauge, first)

    names = day_names([r.source for r in recs])
    days = []
    for i, r in enumerate(recs):
        f = None if i == 0 else frames[i - 1]
        if f is None:
            wrapped = fitter.fit(reference)[0]  # in the first recording's frames
        else:
            wrapped = RebasedModel(joint.robot, joint.method, joint, f.result.T_base_correction,
                                   f.result.T_tool_correction, 12)
        days.append(Day(names[i], len(r), f, _rms(wrapped, r), _rms(own[i], r)))
    differences = compare_days(arm.nominal, recs, names)
    return MultiDayFit(fitter, tuple(days), reference, differences)
