"""The statistics of a comparison of days: one test (:class:`Test`), one compared quantity (:class:`Quantity`), a
pair's difference (:class:`DayDiff`) and how far two days' poses overlap (:func:`pose_overlap`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, cast

import numpy as np
from scipy import special  # not scipy.stats: its import costs ~1 s per command (the same values, bit for bit)

#: Two poses are the same when every joint is within this [deg]; two recordings cover the same poses when at least
#: ``SAME_POSES`` of each's are in the other. Otherwise a kinematic difference between them may be a
#: configuration-dependent effect the geometric model leaves out: on the shared days, the lower and the upper
#: anchors of one training recording "differ" by up to 2 mm of link length, while its even and odd clusters agree.
POSE_MATCH_DEG = 1.0


SAME_POSES = 0.9


def pose_overlap(q_a: np.ndarray, q_b: np.ndarray) -> float:
    """Share of the poses of each recording within ``POSE_MATCH_DEG`` (every joint) of a pose of the other, the
    smaller of the two."""
    from scipy.spatial import cKDTree

    tol = np.radians(POSE_MATCH_DEG)
    a_in_b = np.mean(cKDTree(q_b).query(q_a, p=np.inf)[0] <= tol)
    b_in_a = np.mean(cKDTree(q_a).query(q_b, p=np.inf)[0] <= tol)
    return float(min(a_in_b, b_in_a))


@dataclass(frozen=True)
class Test:
    """A chi-square over ``dof`` directions: the statistic, its p-value and whether it is beyond the noise."""

    chi2: float
    dof: int
    p_value: float
    differs: bool

    @classmethod
    def of(cls, d: np.ndarray, V: np.ndarray, alpha: float) -> Test:
        if d.size == 0:
            return cls(0.0, 0, 1.0, False)
        chi2 = float(d @ np.linalg.solve(V, d))
        p = float(special.chdtrc(d.size, chi2))
        return cls(chi2, d.size, p, bool(p < alpha))

    def to_json(self) -> dict[str, Any]:
        return {"chi2": round(self.chi2, 2), "dof": self.dof, "p_value": float(f"{self.p_value:.3g}"),
                "differs": bool(self.differs)}


@dataclass(frozen=True)
class Quantity:
    """A difference with its standard error, or unidentified (``value`` None)."""

    name: str
    unit: str
    value: float | None
    se: float | None
    differs: bool
    identified_share: float

    def text(self) -> str:
        if self.value is None:
            return f"{self.name}: unidentified ({self.identified_share:.0%} of it seen)"
        return f"{self.name} {self.value:+.4g} ± {self.se:.2g} {self.unit}"

    def to_json(self) -> dict[str, Any]:
        return {"name": self.name, "unit": self.unit, "identified": self.value is not None,
                "difference": None if self.value is None else float(f"{self.value:.5g}"),
                "se": None if self.se is None else float(f"{self.se:.3g}"), "differs": bool(self.differs),
                "identified_share": round(self.identified_share, 3)}


@dataclass(frozen=True)
class DayDiff:
    """One recording against the reference: frames, kinematic parameters, named changes, the joint tests."""

    name: str
    n_samples: int
    noise_mm: float
    noise_deg: float
    frames: tuple[Quantity, ...]
    frames_test: Test
    parameters: tuple[Quantity, ...]
    kinematics_test: Test
    named: tuple[Quantity, ...]
    unexplained: Test
    alternatives: tuple[str, ...] = ()
    pose_overlap: float = 1.0

    @property
    def kinematics_differ(self) -> bool:
        return self.kinematics_test.differs or any(p.differs for p in self.parameters)

    @property
    def frames_differ(self) -> bool:
        return self.frames_test.differs or any(f.differs for f in self.frames)

    def summary(self, reference: str) -> str:
        frames = [f.text() for f in self.frames if f.differs]
        kin = [q.text() for q in self.named]
        if self.alternatives and self.named:
            kin.append("or as well: " + " / ".join(self.alternatives))
        if self.unexplained.differs:
            kin.append("further differences along " + ", ".join(p.name for p in self.parameters if p.differs)
                       if any(p.differs for p in self.parameters) else "further differences no named change explains")
        if self.frames_differ and not frames:  # no component alone: name the largest, correlated as they are
            # an identified quantity has both its value and its standard error
            shown = sorted((f for f in self.frames if f.value is not None),
                           key=lambda f: -abs(cast(float, f.value) / cast(float, f.se)))[:3]
            frames = [f"jointly (chi2 {self.frames_test.chi2:.0f} over {self.frames_test.dof}; largest: "
                      + "; ".join(f.text() for f in shown) + ")"]
        frames_text = ("frames differ: " + "; ".join(frames)) if self.frames_differ else \
            "frames the same within the noise"
        kin_text = ("kinematics differ: " + "; ".join(kin or ["jointly, along no single parameter"])
                    if self.kinematics_differ else
                    f"kinematics the same within the noise (chi2 {self.kinematics_test.chi2:.1f} over "
                    f"{self.kinematics_test.dof} identified directions)")
        caveat = ""
        if self.kinematics_differ and self.pose_overlap < SAME_POSES:
            caveat = (f" (caution: only {self.pose_overlap:.0%} of the poses are shared, so an effect the geometric "
                      f"model leaves out that depends on the pose would show the same way)")
        return f"  {self.name} against {reference}: {frames_text}; {kin_text}{caveat}"

    def to_json(self) -> dict[str, Any]:
        return {"name": self.name, "samples": self.n_samples, "pose_overlap": round(self.pose_overlap, 3),
                "same_poses": bool(self.pose_overlap >= SAME_POSES), "noise_mm": round(self.noise_mm, 4),
                "noise_deg": round(self.noise_deg, 5), "frames": [f.to_json() for f in self.frames],
                "frames_test": self.frames_test.to_json(), "frames_differ": bool(self.frames_differ),
                "parameters": [p.to_json() for p in self.parameters], "kinematics_test": self.kinematics_test.to_json(),
                "kinematics_differ": bool(self.kinematics_differ), "named_changes": [q.to_json() for q in self.named],
                "equally_good": list(self.alternatives),
                "unexplained": self.unexplained.to_json()}
