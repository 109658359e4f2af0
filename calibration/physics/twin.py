"""The digital twin: the simulated truth a diagnosis is proved against.

A :class:`Twin` is a POE geometry (the nominal arm with planted geometric errors) plus effects with their
true parameters. :meth:`Twin.random` plants effects at given magnitudes with a seed, and
:meth:`Twin.to_dict` writes a truth file for a proof script. Diagnosing code must never read that file.

:class:`PlantedErrors` and :func:`planted_twin` are the one error planter of the simulated cell: the demo,
``collect --sim``, ``validate-dual --sim``, the rehearsal and the tests all build their true arms with it
(geometric errors plus, optionally, a gravity-driven joint compliance).

Planting magnitudes are stated as what a person can check: the RMS tool-position perturbation [mm] each
effect causes on its own over a reference set of poses, under a context that excites it (see
:func:`reference_context`). Geometric errors are planted as parameters of
:class:`~calibration.kinematics.parameterisation.MinimalParameterisation` (offsets [mm], tilts [rad]).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from calibration.errors import ModelError
from calibration.kinematics.parameterisation import MinimalParameterisation
from calibration.kinematics.poe import PoeModel, poe_from_dict, poe_to_dict
from calibration.physics.base import Effect, apply_effects, context_keys_of, effect_from_dict
from calibration.physics.compliance import JointCompliance, PayloadCompliance
from calibration.physics.context import Context
from calibration.physics.gravity import GravityModel
from calibration.physics.joint_effects import Backlash, GearTransmission, JointOffset, MocapLatency
from calibration.physics.thermal import ThermalDrift

TWIN_SCHEMA = "cellcal.twin/1"
log = logging.getLogger("cellcal.calibration")

#: Kinds whose parameters are physically one-signed (compliance sags, backlash and growth are widths).
_POSITIVE = {"joint_compliance", "payload_compliance", "backlash", "thermal_drift", "mocap_latency"}


def default_effect(kind: str, gravity: GravityModel | None = None) -> Effect:
    """The effect of ``kind`` with the joints/links it usually acts on and zero parameters."""
    if kind == "joint_compliance":
        if gravity is None:
            raise ModelError("joint_compliance needs a GravityModel (link masses), e.g. GravityModel.from_spec")
        return JointCompliance(gravity)
    makers: dict[str, type[Effect]] = {
        "payload_compliance": PayloadCompliance, "gear_transmission": GearTransmission, "backlash": Backlash,
        "thermal_drift": ThermalDrift, "mocap_latency": MocapLatency, "joint_offset": JointOffset}
    if kind not in makers:
        raise ModelError(f"unknown effect kind {kind!r}; valid: joint_compliance, {', '.join(makers)}")
    return makers[kind]()


def reference_context(N: int, rng: np.random.Generator, payload_kg: float = 6.0, t_s: float = 7200.0,
                      temp_rise_c: float = 10.0, ref_temp_c: float = 20.0, qd_rad_s: float = 0.3
                      ) -> dict[str, np.ndarray]:
    """A context that excites every effect: random approach directions and velocities, a load, a warm arm.

    Args:
        N: number of samples.
        rng: random generator.
        payload_kg: carried mass [kg].
        t_s: time since start [s] (several warm-up time constants).
        temp_rise_c: temperature above ``ref_temp_c`` [K].
        qd_rad_s: joint speeds drawn uniformly in +-qd_rad_s [rad/s].
    """
    ctx: dict[str, np.ndarray] = {f"dir{i + 1}": rng.choice([-1.0, 1.0], N) for i in range(6)}
    ctx.update(t=np.full(N, t_s), temp_c=np.full(N, ref_temp_c + temp_rise_c), payload_kg=np.full(N, payload_kg),
               qd=rng.uniform(-qd_rad_s, qd_rad_s, (N, 6)))
    return ctx


def plant(effect: Effect, model: PoeModel, magnitude_mm: float, rng: np.random.Generator, q_ref: np.ndarray,
          context: Context) -> Effect:
    """The effect with random parameters scaled so its RMS tool-position change over ``q_ref`` is ``magnitude_mm``."""
    x = rng.normal(size=effect.size)
    if effect.kind in _POSITIVE:
        x = np.abs(x) + 0.2  # one-signed and not vanishing
    dp = np.einsum("nij,j->ni", effect.pose_jacobian(model, q_ref, context)[:, :3], x)
    rms = float(np.sqrt(np.mean(np.sum(dp**2, axis=1))))
    if rms <= 0:
        raise ModelError(f"{effect.kind} does not move the tool over the reference poses and context")
    x = x * magnitude_mm / rms  # first order; the passes below correct the small nonlinearity
    _, p0 = model.fk(q_ref)
    for _ in range(2):
        _, p = apply_effects(model, [effect.with_values(x)], q_ref, context)
        rms = float(np.sqrt(np.mean(np.sum((p - p0) ** 2, axis=1))))
        if rms <= 0:
            raise ModelError(f"{effect.kind} does not move the tool over the reference poses and context")
        x = x * magnitude_mm / rms
    return effect.with_values(x)


@dataclass(frozen=True)
class PlantedErrors:
    """How wrong a simulated arm is.

    Attributes:
        offset_std_mm: standard deviation of the planted joint-origin offsets [mm].
        tilt_std_rad: standard deviation of the planted joint-axis tilts [rad].
        compliance_mm: RMS tool displacement of the planted gravity-driven joint compliance [mm] (0: none).
    """

    offset_std_mm: float = 0.5
    tilt_std_rad: float = math.radians(0.05)
    compliance_mm: float = 0.0


def planted_twin(nominal: PoeModel, errors: PlantedErrors = PlantedErrors(), seed: int = 0,
                 gravity: GravityModel | None = None) -> Twin:
    """The true arm: ``nominal`` with seeded geometric errors and, if asked, a joint compliance under gravity.

    Args:
        nominal: the nominal arm with its tool.
        errors: the planted magnitudes.
        seed: random seed; the same seed plants the same errors.
        gravity: link masses, needed when ``errors.compliance_mm > 0``.

    Raises:
        ModelError: a compliance is asked for without a gravity model.
    """
    effects = {"joint_compliance": errors.compliance_mm} if errors.compliance_mm > 0 else {}
    return Twin.random(nominal, effects, seed, gravity=gravity, offset_std_mm=errors.offset_std_mm,
                       tilt_std_rad=errors.tilt_std_rad)


@dataclass(frozen=True, eq=False)
class Twin:
    """Simulated truth: geometry with planted errors and effects with true parameters.

    Attributes:
        geometry: the true POE geometry (with tool).
        effects: effects with their true parameters.
        info: free metadata (seed, magnitudes, planted geometric parameters by name).
    """

    geometry: PoeModel
    effects: tuple[Effect, ...] = ()
    info: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        effects = tuple(self.effects)
        kinds = [e.kind for e in effects]
        if len(set(kinds)) != len(kinds):
            raise ModelError(f"each effect kind may appear once, got {kinds}")
        object.__setattr__(self, "effects", effects)

    @classmethod
    def from_parameters(cls, parameterisation: MinimalParameterisation, x: np.ndarray,
                        effects: tuple[Effect, ...] = (), info: dict[str, Any] | None = None) -> Twin:
        """Twin whose geometry is the minimal parameter vector ``x`` (m,) around the nominal arm."""
        info = dict(info or {})
        info["geometric"] = dict(zip(parameterisation.names(), np.asarray(x, dtype=float).tolist()))
        return cls(parameterisation.model(x), tuple(effects), info)

    def pose(self, q: np.ndarray, context: Context | None = None) -> tuple[np.ndarray, np.ndarray]:
        """True tool pose ``(R (N, 3, 3), p (N, 3) [mm])`` for joint readings q [rad] (N, 6) and a context."""
        return apply_effects(self.geometry, self.effects, q, context)

    @property
    def context_keys(self) -> frozenset[str] | None:
        """The context entries :meth:`pose` reads (the union of its effects' :attr:`Effect.context_keys`), or None
        when an effect does not say."""
        return context_keys_of(self.effects)

    def effect(self, kind: str) -> Effect:
        for e in self.effects:
            if e.kind == kind:
                return e
        raise ModelError(f"the twin has no {kind!r} effect; it has {[e.kind for e in self.effects]}")

    @classmethod
    def random(cls, nominal: PoeModel, magnitudes_mm: Mapping[str, float], seed: int,
               gravity: GravityModel | None = None, offset_std_mm: float = 0.0, tilt_std_rad: float = 0.0,
               templates: Mapping[str, Effect] | None = None, q_ref: np.ndarray | None = None,
               context: Context | None = None) -> Twin:
        """Plant geometric errors and effects at given magnitudes.

        Args:
            nominal: the nominal arm with tool.
            magnitudes_mm: effect kind -> RMS tool-position change [mm] over ``q_ref`` under ``context``.
            seed: seed of every random draw.
            gravity: link masses, needed for ``joint_compliance``.
            offset_std_mm, tilt_std_rad: standard deviations of the planted minimal geometric parameters.
            templates: kind -> effect whose joints/links/settings to use (default :func:`default_effect`).
            q_ref: reference poses [rad] (N, 6); default 200 poses uniform in +-1 rad.
            context: reference context; default :func:`reference_context`.
        """
        rng = np.random.default_rng(seed)
        par = MinimalParameterisation(nominal)
        x = np.concatenate([rng.normal(0, offset_std_mm, 2 * par.n_joints),
                            rng.normal(0, tilt_std_rad, 2 * par.n_joints)])
        geometry = par.model(x)
        q_ref = rng.uniform(-1.0, 1.0, (200, nominal.n_joints)) if q_ref is None else np.asarray(q_ref, float)
        context = reference_context(q_ref.shape[0], rng) if context is None else context
        effects = []
        for kind, mag in magnitudes_mm.items():
            template = (templates or {}).get(kind) or default_effect(kind, gravity)
            effects.append(plant(template, geometry, float(mag), rng, q_ref, context))
            log.debug("planted %s at %.3f mm: %s", kind, mag, effects[-1].parameters())
        info = {"seed": int(seed), "magnitudes_mm": {k: float(v) for k, v in magnitudes_mm.items()},
                "offset_std_mm": float(offset_std_mm), "tilt_std_rad": float(tilt_std_rad)}
        return cls.from_parameters(par, x, tuple(effects), info)

    def to_dict(self) -> dict[str, Any]:
        """Truth file content (plain Python)."""

        return {"schema": TWIN_SCHEMA, "geometry": poe_to_dict(self.geometry),
                "effects": [e.to_dict() for e in self.effects], "info": self.info}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Twin:

        if d.get("schema") != TWIN_SCHEMA:
            raise ModelError(f"unsupported twin schema {d.get('schema')!r}; expected {TWIN_SCHEMA!r}")
        return cls(poe_from_dict(d["geometry"]), tuple(effect_from_dict(e) for e in d["effects"]),
                   dict(d.get("info", {})))
