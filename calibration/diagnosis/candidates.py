"""The library of candidate effects and their signatures on the data.

A candidate is one effect kind acting on one joint (or one link), with zero parameters: its *signature*
is the first-order change of the weighted residual per parameter, ``S = d[p (mm); w * theta] / d values``,
stacked over samples to shape (6N, m) (rows ordered sample-major). What the geometric parameters can
already absorb is projected out: an effect whose signature, after that projection, is a small fraction of
what it would be over the reference workspace (the held-out poses, or the robot's joint range) cannot be
identified from the data, and is reported as such rather than searched for.

Once selected, the candidates of one kind are merged into one effect acting on all their joints or links
(:func:`merge`); warm-up thermal candidates have their time constant refined by the selection
(:func:`calibration.diagnosis.selection.tune_warmup`). :class:`Signatures` gives the signatures on the model in use.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, cast

import numpy as np
from scipy.linalg import block_diag

from calibration.diagnosis.extended import StructuralDeflection, ToolFrame
from calibration.diagnosis.inuse import InUse
from calibration.errors import ModelError
from calibration.kinematics.poe import PoeModel
from calibration.physics.base import Effect
from calibration.physics.compliance import JointCompliance, LumpedCompliance, PayloadCompliance
from calibration.physics.context import Context
from calibration.physics.extended import ExtendedEffect, MassFreeCompliance
from calibration.physics.gravity import GravityModel
from calibration.physics.joint_effects import Backlash, GearTransmission, JointOffset, MocapLatency
from calibration.physics.thermal import ThermalDrift, link_names

#: Warm-up time constants [s] scanned for thermal drift driven by ``t`` (refined afterwards).
TAU_GRID_S = (300.0, 900.0, 2700.0, 8100.0)
#: Links shorter than this [mm] are not thermal candidates: growth is proportional to length (10 mm of steel
#: grows 2.4 um over 20 K), and a link that is zero in the nominal model (a fitted one is a few mm at most) has
#: no direction to grow in.
MIN_LINK_MM = 10.0
#: Order in which kinds are listed (and tie-broken).
KINDS = ("joint_compliance", "payload_compliance", "gear_transmission", "backlash", "thermal_drift",
         "mocap_latency", "joint_offset", "tool_frame", "structural_deflection")
#: ``joint_compliance`` forms: per joint with the link masses, the 5-term mass-free form, the lumped form of joints
#: 2-3 (free link masses and centres of mass, :class:`~calibration.physics.compliance.LumpedCompliance`), or masses
#: when known.
COMPLIANCE_FORMS = ("auto", "masses", "mass_free", "lumped")

#: The identity of a candidate with its settings (:meth:`Candidate.key`): kind, label, thermal mode and time constant.
CandidateKey = tuple[str, str, Any, Any]


@dataclass(frozen=True)
class Candidate:
    """One effect kind on one joint or link, as a template with zero parameters.

    Attributes:
        kind: effect kind (``joint_compliance``, ...).
        label: what it acts on, in words (``joint 2``, ``link p23``).
        joints: 1-based joints it acts on (empty for links and latency).
        effect: the template effect (settings fixed, values zero).
        extra_dof: settings chosen from the data (a warm-up time constant), counted in the BIC.
    """

    kind: str
    label: str
    joints: tuple[int, ...]
    effect: Effect
    extra_dof: int = 0

    def key(self) -> CandidateKey:
        """Identity of the candidate including its settings (for de-duplication)."""
        return (self.kind, self.label, getattr(self.effect, "mode", ""), getattr(self.effect, "tau_s", 0.0))


@dataclass(frozen=True)
class Untested:
    """A candidate that could not be tested, and why.

    Attributes:
        kind: effect kind.
        label: what it would act on.
        joints: 1-based joints.
        reason: plain-language reason (missing context column, not identifiable from this data, ...).
    """

    kind: str
    label: str
    joints: tuple[int, ...]
    reason: str


@dataclass(frozen=True)
class Signatures:
    """Signatures of effects on the fitted model in use, by default on the fit data.

    Attributes:
        inuse: the model in use at its fitted parameters.
        q: joint angles of the fit data [rad], shape (N, 6).
        context: their context.
        w_rot: rotation residual scale (``sqrt(2a)``).
    """

    inuse: InUse
    q: np.ndarray
    context: Context
    w_rot: float

    def __call__(self, effect: Effect) -> np.ndarray:
        """The signature (6N, m) of ``effect`` on the fit data."""
        return self.on(effect, self.q, self.context)

    def on(self, effect: Effect, q: np.ndarray, context: Context) -> np.ndarray:
        """The signature (6M, m) of ``effect`` at joint angles q (M, 6) with their context."""
        return self.inuse.signature(effect, q, context, self.inuse.theta, self.w_rot)


def _varies(context: Context, key: str) -> bool:
    return key in context and np.ptp(np.asarray(context[key], dtype=float)) > 0


def library(model: PoeModel, q: np.ndarray, context: Context, gravity: GravityModel | None = None,
            kinds: tuple[str, ...] = KINDS, compliance_form: str = "auto") -> tuple[list[Candidate], list[Untested]]:
    """Every candidate the data can test, and the ones it cannot with the reason.

    Args:
        model: the geometry in use.
        q: joint angles of the fit data [rad], shape (N, 6).
        context: their context (columns ``t``, ``temp_c``, ``payload_kg``, ``dir1..6``, ``qd``).
        gravity: link masses (``joint_compliance`` per joint; without them the mass-free form is used).
        kinds: the kinds to consider.
        compliance_form: one of :data:`COMPLIANCE_FORMS`.

    Raises:
        ModelError: an unknown compliance form, or ``masses`` without link masses.
    """
    if compliance_form not in COMPLIANCE_FORMS:
        raise ModelError(f"unknown compliance form {compliance_form!r}; valid: {', '.join(COMPLIANCE_FORMS)}")
    if compliance_form == "masses" and gravity is None and "joint_compliance" in kinds:
        raise ModelError("compliance form 'masses' needs link masses; use 'mass_free' or 'auto'")
    n = model.n_joints
    cands: list[Candidate] = []
    skipped: list[Untested] = []
    if "joint_compliance" in kinds:
        cands += _joint_compliance(model, q, gravity, compliance_form)
    if "payload_compliance" in kinds:
        _payload_compliance(context, n, cands, skipped)
    if "gear_transmission" in kinds:
        cands += [Candidate("gear_transmission", f"joint {j}", (j,), GearTransmission(((j, (1, 2)),), np.zeros(4)))
                  for j in range(1, n + 1)]
    if "backlash" in kinds:
        _backlash(context, n, cands, skipped)
    if "thermal_drift" in kinds:
        _thermal_drift(model, context, cands, skipped)
    if "mocap_latency" in kinds:
        if "qd" in context and np.any(np.asarray(context["qd"]) != 0):
            cands.append(Candidate("mocap_latency", "all joints", (), MocapLatency(values=np.zeros(1))))
        else:
            skipped.append(Untested("mocap_latency", "all joints", (), "static samples: no joint speeds qd1..qd6"))
    if "joint_offset" in kinds:
        cands += [Candidate("joint_offset", f"joint {j}", (j,), JointOffset((j,), np.zeros(1))) for j in range(1, n + 1)]
    if "tool_frame" in kinds:
        cands.append(Candidate("tool_frame", "tool marker", (), ToolFrame()))
    if "structural_deflection" in kinds:
        cands.append(Candidate("structural_deflection", "links 2-3 (q2, q3; joint-1 frame)", (2, 3),
                               StructuralDeflection()))
    return cands, skipped


def _joint_compliance(model: PoeModel, q: np.ndarray, gravity: GravityModel | None,
                      compliance_form: str) -> list[Candidate]:
    """The joint-compliance candidates of :func:`library`: one mass-free or lumped pair, or per joint whose gravity
    torque varies over ``q`` and the shoulder-elbow pair."""
    if compliance_form == "mass_free" or (compliance_form == "auto" and gravity is None):
        return [Candidate("joint_compliance", "joints 2-3 (mass-free form)", (2, 3), MassFreeCompliance())]
    if compliance_form == "lumped":
        return [Candidate("joint_compliance", "joints 2-3 (lumped form)", (2, 3),
                          LumpedCompliance.for_arm(model, (2, 3)))]
    if gravity is None:  # library() asks for link masses before the form that needs them
        raise ModelError(f"compliance form {compliance_form!r} needs link masses; use 'mass_free' or 'auto'")
    cands = []
    tau = gravity.torque(model, q)
    for j in range(2, model.n_joints + 1):
        if np.ptp(tau[:, j - 1]) > 1e-6:
            cands.append(Candidate("joint_compliance", f"joint {j}", (j,), JointCompliance(gravity, (j,), np.zeros(1))))
    if np.ptp(tau[:, 1]) > 1e-6 and np.ptp(tau[:, 2]) > 1e-6:
        # The shoulder and the elbow in the YAML's shape as one step: the lumped form of joints 2-3 competes in
        # the forward pass (see core.candidate_signatures), and this pair is what it is weighed against.
        cands.append(Candidate("joint_compliance", "joints 2-3", (2, 3),
                               JointCompliance(gravity, (2, 3), np.zeros(2))))
    return cands


def _payload_compliance(context: Context, n: int, cands: list[Candidate], skipped: list[Untested]) -> None:
    """Append :func:`library`'s payload-compliance candidates, or why they cannot be tested."""
    if "payload_kg" not in context or not np.any(np.asarray(context["payload_kg"]) != 0):
        skipped.append(Untested("payload_compliance", "joints 2-6", (), "no payload_kg column (or no payload carried)"))
    elif not _varies(context, "payload_kg"):
        # A payload that never changes is a load on the last link like the tool's: its deflection is part of the
        # own-weight compliance, whose lumped form takes any such load. Only a payload that changes shows a
        # deflection of its own (the difference between payloads).
        skipped.append(Untested("payload_compliance", "joints 2-6", (),
                                "the payload_kg column does not change (a constant payload is part of the own "
                                "weight)"))
    else:
        cands += [Candidate("payload_compliance", f"joint {j}", (j,), PayloadCompliance((j,), np.zeros(1)))
                  for j in range(2, n + 1)]
        # The shoulder and the elbow carry the payload together: as a pair their deflections are tested at once
        # (the elbow's alone is often too weak beside the shoulder's to pass on its own).
        cands.append(Candidate("payload_compliance", "joints 2-3", (2, 3), PayloadCompliance((2, 3), np.zeros(2))))


def _backlash(context: Context, n: int, cands: list[Candidate], skipped: list[Untested]) -> None:
    """Append :func:`library`'s backlash candidate of each joint approached from both sides, the others untested."""
    for j in range(1, n + 1):
        d = np.asarray(context.get(f"dir{j}", np.zeros(1)), dtype=float)
        if np.any(d > 0) and np.any(d < 0):
            cands.append(Candidate("backlash", f"joint {j}", (j,), Backlash((j,), np.zeros(1))))
        else:
            skipped.append(Untested("backlash", f"joint {j}", (j,),
                                    f"no dir{j} column with both approach directions"))


def _thermal_drift(model: PoeModel, context: Context, cands: list[Candidate], skipped: list[Untested]) -> None:
    """Append :func:`library`'s thermal-drift candidates (warm-up over time, temperature) of each long link."""
    links = [l for c, l in enumerate(link_names(model.n_joints)) if np.linalg.norm(model.P[:, c]) > MIN_LINK_MM]
    if _varies(context, "t"):
        cands += [Candidate("thermal_drift", f"link {l}", (), ThermalDrift((l,), np.zeros(1), "warmup", tau), 1)
                  for l in links for tau in TAU_GRID_S]
    if _varies(context, "temp_c"):
        ref = float(np.min(context["temp_c"]))
        cands += [Candidate("thermal_drift", f"link {l}", (),
                            ThermalDrift((l,), np.zeros(1), "temperature", ref_temp_c=ref)) for l in links]
    if not (_varies(context, "t") or _varies(context, "temp_c")):
        skipped.append(Untested("thermal_drift", "links", (), "no t or temp_c column that varies"))


def visibility(S_fit: np.ndarray, Q_geo: np.ndarray, S_ref: np.ndarray, n_fit: int, n_ref: int, visible_min: float
               ) -> tuple[float, float, np.ndarray]:
    """How much of a candidate the fit data can see once the geometric fit has absorbed what it can.

    Args:
        S_fit: signature on the fit data (6N, m).
        Q_geo: orthonormal basis of the geometric columns on the fit data (6N, k).
        S_ref: signature on the reference workspace (6M, m).
        n_fit, n_ref: sample counts N and M.
        visible_min: parameter directions whose visible fraction is below this are absorbed.

    Returns:
        ``(visible, excited, basis)``: the largest visible fraction (singular value of the projected
        signature per fit sample, each column relative to its reference RMS); the fit/reference RMS ratio of
        the raw signature (small when the data barely move what drives the effect); and the (m, k)
        parameter directions that are visible (the others are left to the geometry and held at zero).
    """
    ref_rms = np.sqrt(np.sum(S_ref**2, axis=0) / n_ref)
    ref_rms = np.where(ref_rms > 0, ref_rms, 1.0)
    S = S_fit / ref_rms
    S_perp = S - Q_geo @ (Q_geo.T @ S)
    _, sv, Vt = np.linalg.svd(S_perp / np.sqrt(n_fit), full_matrices=False)
    excited = float(np.max(np.sqrt(np.sum(S**2, axis=0) / n_fit)))
    keep = sv >= visible_min
    basis = Vt[keep].T / ref_rms[:, None]
    if keep.all():
        basis = np.eye(S.shape[1])
    return float(sv[0]), excited, basis


def merge(kind: str, cands: list[Candidate], bases: dict[CandidateKey, np.ndarray]) -> tuple[Effect, np.ndarray]:
    """One effect of ``kind`` acting on every joint/link of the chosen candidates, and its parameter basis."""
    cands = sorted(cands, key=lambda c: (c.joints, c.label))
    B = block_diag(*[bases.get(c.key(), np.eye(c.effect.size)) for c in cands])
    return merged_effect(kind, cands), B


def merged_effect(kind: str, cands: list[Candidate]) -> Effect:
    first = cands[0].effect
    if kind == "thermal_drift":
        thermal = [cast(ThermalDrift, c.effect) for c in cands]  # the candidates of one kind
        links = tuple(t.links[0] for t in thermal)
        return ThermalDrift(links, np.zeros(len(links)), thermal[0].mode, thermal[0].tau_s, thermal[0].ref_temp_c)
    if kind in ("mocap_latency", "tool_frame", "structural_deflection") or isinstance(first, (ExtendedEffect,
                                                                                               LumpedCompliance)):
        return first
    joints = tuple(sorted(j for c in cands for j in c.joints))
    if kind == "gear_transmission":
        return type(first)(tuple((j, (1, 2)) for j in joints), np.zeros(4 * len(joints)))
    if kind == "joint_compliance":
        return type(first)(cast(JointCompliance, first).gravity, joints, np.zeros(len(joints)))  # the per-joint form
    return type(first)(joints=joints, values=np.zeros(len(joints)))


def dedupe(items: list[Untested], testable: set[str]) -> list[Untested]:
    """One entry per (kind, label), none for labels testable at other settings (thermal time constants)."""
    seen, out = set(), []
    for u in items:
        if (u.kind, u.label) not in seen and not (u.kind == "thermal_drift" and u.label in testable):
            seen.add((u.kind, u.label))
            out.append(u)
    return out
