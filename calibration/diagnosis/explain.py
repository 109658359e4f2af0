"""Plain-language sentences of a diagnosis: what each found effect means, why others are not identifiable,
and the verdict."""

from __future__ import annotations

from typing import cast

import numpy as np

from calibration.diagnosis.candidates import Candidate, Untested
from calibration.diagnosis.report import Accuracy, EffectEvidence, FoundEffect
from calibration.physics.base import Effect
from calibration.physics.joint_effects import GearTransmission
from calibration.physics.thermal import ThermalDrift

PHYSICS = {
    "joint_compliance": "joint compliance under gravity",
    "payload_compliance": "compliance under the payload",
    "gear_transmission": "gear transmission error",
    "backlash": "backlash",
    "thermal_drift": "thermal drift",
    "mocap_latency": "motion-capture latency",
    "joint_offset": "joint zero offset",
    "tool_frame": "tool-marker rotation",
    "structural_deflection": "structural deflection",
}


def _and(items: list[str]) -> str:
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " and " + items[-1]


def _pm(v: float, s: float | None, unit: str = "") -> str:
    return f"{v:.3g} ± {s:.2g}{unit}" if s is not None and np.isfinite(s) else f"{v:.3g}{unit}"


def not_identifiable(c: Candidate, visible: float, excited: float, q_fit: np.ndarray, q_ref: np.ndarray) -> Untested:
    """Why a candidate cannot be identified from the fit data."""
    why = "not identifiable from this data: "
    if c.joints:
        j = c.joints[0] - 1
        rng = f" (joint {j + 1} spans {np.degrees(np.ptp(q_fit[:, j])):.1f} deg in the fit data, " \
              f"{np.degrees(np.ptp(q_ref[:, j])):.1f} deg in the reference poses)"
    else:
        rng = ""
    if excited < 2 * visible or excited < 0.2:
        why += f"the fit data barely excite it{rng}"
    else:
        why += f"the geometric parameters absorb {100 * (1 - visible / max(excited, 1e-300)):.0f}% of its signature{rng}"
    return Untested(c.kind, c.label, c.joints, f"{why}; visible fraction {visible:.3f}")


def found(effect: Effect, std: np.ndarray, evidence: EffectEvidence) -> FoundEffect:
    """The report entry of a fitted effect."""
    params = effect.parameters()
    std_of: dict[str, float] = {k: float(s) for k, s in zip(effect.names, std)}
    unc: dict[str, float | None] = dict(std_of)  # plus None for a parameter that was not fitted
    joints: tuple[int, ...] = tuple(getattr(effect, "joints", ()))
    links: tuple[str, ...] = ()
    kind = effect.kind
    if kind == "gear_transmission":
        joints = tuple(j for j, _ in cast(GearTransmission, effect).harmonics)
        amps = []
        for j in joints:
            for k in (1, 2):
                a, b = params.get(f"j{j}_sin{k}_rad", 0.0), params.get(f"j{j}_cos{k}_rad", 0.0)
                amps.append(f"joint {j} order {k}: {1e3 * np.hypot(a, b):.3f} mrad")
        text = f"The reducer of joint{'s' if len(joints) > 1 else ''} {_and([str(j) for j in joints])} has a periodic " \
               f"transmission error in harmonics of its own angle ({'; '.join(amps)})."
    elif kind == "thermal_drift":
        thermal = cast(ThermalDrift, effect)
        links = tuple(thermal.links)
        unit = " mm" if thermal.mode == "warmup" else " mm/K"
        grow = [f"{l} {_pm(params[n], unc[n], unit)}" for l, n in zip(links, effect.names)]
        if thermal.mode == "warmup":
            params["tau_s"] = float(thermal.tau_s)
            unc["tau_s"] = None
            text = f"The arm grows as it warms up: link{'s' if len(links) > 1 else ''} {_and(grow)} with a warm-up " \
                   f"time constant of {thermal.tau_s:.0f} s."
        else:
            text = f"The arm grows with temperature: link{'s' if len(links) > 1 else ''} {_and(grow)}."
    elif kind == "tool_frame":
        ang = 1e3 * np.linalg.norm(effect.values)
        text = f"The tool marker is rotated in the flange frame by {ang:.3f} mrad " \
               f"(rx, ry, rz = {', '.join(_pm(1e3 * params[n], 1e3 * std_of[n]) for n in effect.names)} mrad)."
    elif kind == "structural_deflection":
        C = effect.values.reshape(-1, 6)
        text = f"The structure bends with the shoulder and elbow angles beyond what joint compliance explains: a " \
               f"smooth pose correction in the joint-1 frame of up to {np.abs(C[1:, :3]).sum(axis=0).max():.3f} mm " \
               f"and {1e3 * np.abs(C[1:, 3:]).sum(axis=0).max():.3f} mrad over (q2, q3) (7 Fourier terms per axis)."
    elif kind == "joint_compliance" and "c2_sin_q2_rad" in effect.names:
        v = 1e3 * effect.values
        text = f"The arm sags under its own weight (mass-free form, link masses unknown): joint 2 deflects by " \
               f"{v[0]:.3f} sin q2 + {v[1]:.3f} cos u + {v[2]:.3f} sin u mrad and joint 3 by {v[3]:.3f} cos u + " \
               f"{v[4]:.3f} sin u mrad (u = q2 - q3, the shape of the shoulder and elbow gravity torques)."
    elif kind == "mocap_latency":
        text = f"The pose is measured late while the arm moves: latency " \
               f"{_pm(1e3 * params['latency_s'], 1e3 * std_of['latency_s'], ' ms')}."
    else:
        vals = [f"{n.split('_')[0]} = {_pm(params[n], unc[n])} {n.split('_', 1)[1].replace('_per_', '/').replace('_', ' ')}"
                for n in effect.names]
        js = _and([str(j) for j in joints])
        lead = {
            "joint_compliance": f"The arm sags under its own weight: joint{'s' if len(joints) > 1 else ''} {js} "
                                "deflect in proportion to the gravity torque",
            "payload_compliance": f"The payload bends the arm: joint{'s' if len(joints) > 1 else ''} {js} deflect "
                                  "in proportion to the payload's gravity torque",
            "backlash": f"Joint{'s' if len(joints) > 1 else ''} {js} show{'' if len(joints) > 1 else 's'} lost motion "
                        "that depends on the approach direction (full width)",
            "joint_offset": f"The zero of joint{'s' if len(joints) > 1 else ''} {js} is off in a way the fitted "
                            "geometry cannot express",
        }[kind]
        text = f"{lead}: {'; '.join(vals)}."
    return FoundEffect(kind, joints, links, params, unc, evidence, text)


def _on(e: FoundEffect) -> str:
    if e.kind == "tool_frame":
        return "the tool marker"
    if e.links:
        return f"links {_and(list(e.links))}"
    if e.joints:
        return f"joint{'s' if len(e.joints) > 1 else ''} {_and([str(j) for j in e.joints])}"
    return "the measurement"


def verdict(effects: list[FoundEffect], baseline: Accuracy, final: Accuracy, floor_mm: float,
            hidden: list[Untested], untested: list[Untested], rejected: list[FoundEffect] | None = None) -> str:
    """One paragraph: what was left out, the gain, and what the data could not show."""
    if effects:
        names = _and([f"{PHYSICS[e.kind]} on {_on(e)}" for e in effects])
        text = (f"Left out: {names}. Modelling {'them' if len(effects) > 1 else 'it'} cuts held-out RMS from "
                f"{baseline.rms_mm:.3f} to {final.rms_mm:.3f} mm (max {baseline.max_mm:.3f} to {final.max_mm:.3f} mm); "
                f"the noise floor is {floor_mm:.3f} mm.")
    else:
        text = (f"Nothing left out that this data can show: no candidate effect passes both the information criterion "
                f"and the held-out test. Held-out RMS {baseline.rms_mm:.3f} mm (max {baseline.max_mm:.3f} mm); "
                f"noise floor {floor_mm:.3f} mm.")
    if final.rms_mm > 1.5 * floor_mm:
        text += (f" The held-out error stays {final.rms_mm / floor_mm:.1f}x the noise floor: something the candidate "
                 "library does not describe, or that this data cannot identify, remains.")
    if rejected:
        names = _and([f"{PHYSICS[e.kind]} on {_on(e)}" for e in rejected])
        text += (f" Rejected: {names} fitted the fit data but did not improve the held-out data beyond noise "
                 "(not confirmed: it does not extrapolate beyond the poses it was fitted on, or is too weak).")
    by_kind: dict[str, tuple[list[str], list[str]]] = {}  # kind -> (its joints, what it acts on without joints)
    for u in hidden:
        if u.kind != "joint_offset":  # an absorbed offset is simply part of the fitted geometry
            joints, others = by_kind.setdefault(u.kind, ([], []))
            joints.extend(str(j) for j in u.joints)
            if not u.joints:  # thermal drift of a link, a frame, latency: named by its label
                others.append(u.label)
    if by_kind:
        parts = [f"{PHYSICS[k]} on " + _and(([f"joint{'s' if len(js) > 1 else ''} {_and(js)}"] if js else []) + other)
                 for k, (js, other) in by_kind.items()]
        text += (f" Not identifiable from this data (the fit data barely move those joints, or the geometric fit "
                 f"absorbs the effect): {_and(parts)}.")
    kinds = sorted({u.kind for u in untested})
    if kinds:
        text += f" Untested for lack of data columns: {', '.join(kinds)}."
    return text
