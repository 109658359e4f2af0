"""The base of the non-geometric effect models: parameters, context, registry and the combined pose.

An effect is a small frozen dataclass with named parameters (units in the names, e.g. ``c2_rad_per_Nm``)
held in ``values`` (m,). Most effects perturb the joint angles, ``q_true = q + delta_q(model, q, context)``,
before POE forward kinematics; their first-order pose signature is ``jacobian_q(q) @ delta_q``. Effects with
``target == "geometry"`` (thermal drift) instead change the link vectors per sample.

The context is a mapping of per-sample arrays, each shape (N,) unless noted; missing keys take defaults
that switch the effect off for static, cold, unloaded data:

==============  =========================================  =======
key             meaning                                    default
==============  =========================================  =======
``t``           time since the arm started working [s]     0
``temp_c``      arm temperature [deg C]                    the effect's reference
``dir1..dir6``  approach direction of joint i, in {-1,0,1} 0
``payload_kg``  mass carried at the tool point [kg]        0
``qd``          joint velocities [rad/s], shape (N, n)     0
==============  =========================================  =======

Effects that are linear in their parameters give a regressor ``Y (N, n, m)`` with
``delta_q == Y @ values``, and every effect gives the first-order pose Jacobian ``(N, 6, m)`` (rows
``[p (mm); rotation (rad)]`` in the base frame) so a fitter gets Jacobians cheaply.

One definition, two backends: a joint effect writes its regressor once, as :meth:`Effect.joint_terms` against
:class:`calibration.kinematics.casadi_expr.Ops`; :meth:`Effect.regressor` evaluates it on numpy arrays and
:meth:`Effect.casadi_dq` on casadi symbols (the default context), so a planner differentiates through the
deflection exactly. A geometry effect does the same with :meth:`Effect.grow`.

The registry :data:`EFFECT_KINDS` maps ``kind`` (or ``kind:form`` for a second form of a kind, such as the
mass-free joint compliance) to its class; effects that are blocks of the ``pi`` layout and act on the pose
(:class:`ExtendedEffect` with ``target == "pose"``) are declared with ``register=False``: they are saved in a
``pi`` model's parameters, never as effects of a physics model.
"""

from __future__ import annotations

import abc
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, fields, replace
from typing import TYPE_CHECKING, Any, ClassVar, Literal, Protocol

import numpy as np

from calibration.errors import ModelError
from calibration.kinematics.arrays import FloatArray
from calibration.kinematics.casadi_expr import NUMPY, Ops
from calibration.kinematics.poe import PoeModel
from calibration.physics.context import Context, FittedSpan, check_q

#: ``(joint index 0-based, value column, d delta_q[joint] / d values[column])``: one regressor entry.
Term = tuple[int, int, Any]


EFFECT_KINDS: dict[str, type[Effect]] = {}


@dataclass(frozen=True, eq=False)
class Effect(abc.ABC):
    """One physical effect with named parameters ``values`` (m,).

    Subclasses define ``kind`` (the spec's effect name), a ``values`` field, ``names`` and either
    :meth:`regressor` (joint effects, linear) or :meth:`geometry` (geometry effects).
    """

    kind: ClassVar[str]
    form: ClassVar[str] = ""  # a second form of a kind (``mass_free``), saved as ``form`` in the file
    #: The context entries the effect reads (``dir`` for ``dir1..dirn``; ``qd``, ``t``, ``temp_c``,
    #: ``payload_kg``), or None when a subclass does not say (then it may read anything). A simulated arm
    #: memoises its true pose per (q, directions) only when its twin reads nothing else
    #: (:meth:`drivers.sim.SimRobotDriver.true_pose`); tests check that an undeclared entry never changes a pose.
    context_keys: ClassVar[frozenset[str] | None] = None
    target: ClassVar[Literal["joints", "geometry", "pose"]] = "joints"
    if TYPE_CHECKING:
        # For the type checker only: every subclass declares ``values`` as its own dataclass field, after its
        # settings, so its constructor reads ``Kind(settings..., values)``. A field here would come first in every
        # subclass's constructor; the comment form keeps this declaration out of the dataclass fields.
        values = np.zeros(0)  # type: np.ndarray

        def __init__(self, *args: Any, **kwargs: Any) -> None:
            """The constructor of a subclass: its settings, then ``values``."""

    def __init_subclass__(cls, register: bool = True, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if register and "kind" in cls.__dict__:
            EFFECT_KINDS[registry_key(cls.kind, cls.form)] = cls

    def __post_init__(self) -> None:
        values = np.array(getattr(self, "values"), dtype=float).reshape(-1)
        if values.shape != (len(self.names),):
            raise ModelError(f"{self.kind}: expected {len(self.names)} values for {list(self.names)}, "
                             f"got shape {values.shape}")
        if not np.all(np.isfinite(values)):
            raise ModelError(f"{self.kind}: parameter values must be finite")
        object.__setattr__(self, "values", values)

    @property
    @abc.abstractmethod
    def names(self) -> tuple[str, ...]:
        """Parameter names with units, in the order of ``values``."""

    @property
    def size(self) -> int:
        return len(self.names)

    def parameters(self) -> dict[str, float]:
        """Parameters as ``{name: value}`` (the report's ``parameters`` entry)."""
        return {k: float(v) for k, v in zip(self.names, self.values)}

    def with_values(self, values: np.ndarray) -> Effect:
        """The same effect with other parameter values (m,)."""
        # mypy checks replace() against the base's dataclass fields, and ``values`` is each subclass's field
        return replace(self, values=np.asarray(values, dtype=float))  # type: ignore[call-arg]

    def fitted_joints(self, n: int) -> tuple[int, ...]:
        """The 0-based joints, of an arm of n, whose angles the effect's fitted shape is a function of: where the
        training data saw such a joint only narrowly, the extrapolation guard holds the effect at the edge of what
        it saw (:meth:`calibration.models.guard.Region.held_joints`).

        ``()`` for an effect whose shape in q comes from physics, its size alone fitted (a compliance times a gravity
        torque: its formula says how it goes on), or that does not depend on q. By default every joint (a fitted
        shape of unknown variables).
        """
        return tuple(range(n))

    def fitted_context(self) -> dict[str, FittedSpan]:
        """The context entries (``t``, ``temp_c``, ``payload_kg``) the effect's fitted shape is a function of, each
        with the span over which that shape shows itself (a warm-up's time constant) and the sides of the training
        range past which the shape is a guess: where the training data saw too little of that span (less than a
        fifth of the approach to the asymptote, :data:`calibration.models.guard.HELD_BELOW_RISE`), the extrapolation
        guard holds the effect at those edges of what it saw (:meth:`calibration.models.guard.Region.held_context`).

        Empty by default: a context entry that enters by a formula, its size alone fitted (a payload times a
        compliance, a temperature times a growth per kelvin), goes on as the formula says.
        """
        return {}

    def joint_terms(self, ops: Ops, q: list[Any], chain: Callable[[], Any], context: Context | None,
                    N: int) -> list[Term]:
        """The non-zero regressor entries, written once for numpy and casadi. Joint effects only.

        Args:
            ops: the backend (:data:`calibration.kinematics.casadi_expr.NUMPY` or ``casadi_ops()``).
            q: per-joint angles [rad]: numpy columns (N,) or casadi scalars.
            chain: returns the frames of the effect's geometry at ``q`` (a :class:`~calibration.kinematics.poe.Chain` or
                :class:`~calibration.kinematics.casadi_expr.SxChain`); called only by effects that need it.
            context: per-sample context (numpy) or None (casadi: the default context).
            N: number of samples (1 for casadi).
        """
        raise ModelError(f"{self.kind} does not act on the joint angles; use pose_jacobian")

    def regressor(self, model: PoeModel, q: np.ndarray, context: Context | None = None) -> np.ndarray:
        """Linear form ``delta_q = Y @ values``; Y has shape (N, n, m). Joint effects only."""
        q = check_q(model, q)
        Y = np.zeros(q.shape + (self.size,))
        for j, col, v in self.joint_terms(NUMPY, list(q.T), lambda: model.chain(q), context, q.shape[0]):
            Y[:, j, col] = v
        return Y

    def casadi_dq(self, ops: Ops, q: Any, chain: Callable[[], Any], values: Any = None) -> list[Any]:
        """``delta_q`` at the default context on casadi symbols q (n,), as n expressions; ``values`` (m,)
        may be symbols (default: this effect's values). Zero for geometry effects."""
        n = q.shape[0]
        dq: list[Any] = [0.0] * n
        if self.target != "joints":
            return dq
        values = self.values if values is None else values
        for j, col, v in self.joint_terms(ops, [q[i] for i in range(n)], chain, None, 1):
            dq[j] = dq[j] + values[col] * v
        return dq

    def grow(self, P: list[Any], values: Any, N: int, context: Context | None, model: PoeModel) -> list[Any]:
        """Link vectors ``P`` (one entry per column: (N, 3) numpy or (3, 1) casadi) changed by a geometry
        effect with ``values``; written once for both backends. Geometry effects only."""
        raise ModelError(f"{self.kind} does not change the link geometry")

    def delta_q(self, model: PoeModel, q: np.ndarray, context: Context | None = None) -> np.ndarray:
        """Joint-angle perturbation [rad], shape (N, n); zero for geometry effects."""
        q = check_q(model, q)
        if self.target != "joints":
            return np.zeros_like(q)
        dq: FloatArray = self.regressor(model, q, context) @ self.values
        return dq

    def geometry(self, model: PoeModel, N: int, context: Context | None = None,
                 P: np.ndarray | None = None) -> np.ndarray:
        """Per-sample link vectors [mm] (N, 3, n+1) starting from ``P`` (model's when None). Geometry effects."""
        raise ModelError(f"{self.kind} does not change the link geometry")

    def pose_jacobian(self, model: PoeModel, q: np.ndarray, context: Context | None = None) -> np.ndarray:
        """First-order pose change per parameter, ``d[p (mm); theta (rad)] / d values``, shape (N, 6, m)."""
        q = check_q(model, q)
        J: FloatArray = model.jacobian_q(q) @ self.regressor(model, q, context)
        return J

    def _config(self) -> dict[str, Any]:
        """Settings other than ``values`` as plain Python (override when not plain fields)."""
        out = {}
        for f in fields(self):
            if f.name != "values":
                v = getattr(self, f.name)
                out[f.name] = list(v) if isinstance(v, tuple) else v
        return out

    @classmethod
    def _from_config(cls, config: dict[str, Any], values: np.ndarray) -> Effect:
        kw = {k: tuple(v) if isinstance(v, list) else v for k, v in config.items()}
        return cls(values=values, **kw)

    def to_dict(self) -> dict[str, Any]:
        """Plain mapping ``{kind, [form,] parameters: {name: value}, **config}`` that :func:`effect_from_dict`
        reads."""
        form = {"form": self.form} if self.form else {}
        return {"kind": self.kind, **form, **self._config(), "parameters": self.parameters()}


def registry_key(kind: str, form: str = "") -> str:
    """Key of an effect class in :data:`EFFECT_KINDS`: ``kind``, or ``kind:form`` for a second form."""
    return f"{kind}:{form}" if form else kind


def effect_from_dict(d: Mapping[str, Any]) -> Effect:
    """Inverse of :meth:`Effect.to_dict`."""
    kind = d.get("kind")
    key = registry_key(kind, str(d.get("form") or "")) if isinstance(kind, str) else kind
    if key not in EFFECT_KINDS:
        raise ModelError(f"unknown effect kind {key!r}; valid: {', '.join(sorted(EFFECT_KINDS))}")
    cls = EFFECT_KINDS[key]
    config = {k: v for k, v in d.items() if k not in ("kind", "form", "parameters")}
    params = dict(d["parameters"])
    probe = cls._from_config(config, np.zeros(len(params)))
    if list(probe.names) != list(params):
        raise ModelError(f"{kind}: parameter names {list(params)} do not match {list(probe.names)}")
    return probe.with_values(np.array([params[k] for k in probe.names], dtype=float))


#: Every context entry an effect can read, as :attr:`Effect.context_keys` names them (``dir`` for ``dir1..dirn``).
CONTEXT_KEYS = frozenset({"t", "temp_c", "payload_kg", "qd", "dir"})


def context_keys_of(effects: Sequence[Effect]) -> frozenset[str] | None:
    """The context entries a set of effects reads: the union of their :attr:`Effect.context_keys`, or None when one
    does not say."""
    keys: set[str] = set()
    for e in effects:
        if e.context_keys is None:
            return None
        keys |= e.context_keys
    return frozenset(keys)


def effects_read(effects: Sequence[Effect]) -> frozenset[str]:
    """The context entries a set of effects may read: :func:`context_keys_of`, every entry when one does not say."""
    keys = context_keys_of(effects)
    return CONTEXT_KEYS if keys is None else keys


class Guard(Protocol):
    """A model's extrapolation guard (:class:`calibration.models.guard.Region`): what each effect is evaluated at."""

    def hold(self, effect: Effect, q: np.ndarray) -> np.ndarray:
        """The joint angles (N, n) ``effect`` is evaluated at for the readings q (N, n)."""

    def hold_context(self, effect: Effect, context: Context | None, N: int) -> Context | None:
        """The context ``effect`` is evaluated at for the recorded ``context`` of N samples."""


class NoGuard:
    """The guard of a model without a training region: every effect at the readings and the context as given."""

    def hold(self, effect: Effect, q: np.ndarray) -> np.ndarray:
        return q

    def hold_context(self, effect: Effect, context: Context | None, N: int) -> Context | None:
        return context


NO_GUARD = NoGuard()


def apply_effects(model: PoeModel, effects: tuple[Effect, ...] | list[Effect], q: np.ndarray,
                  context: Context | None = None, guard: Guard | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Tool pose of a POE model with effects: geometry effects change P, joint effects add to q.

    Args:
        model: geometric model the effects act on.
        effects: the effects, applied together (joint perturbations summed, geometry effects chained).
        q: commanded/measured joint angles [rad], shape (N, n).
        context: per-sample context, see the module docstring.
        guard: a model's extrapolation guard, which says the joint angles and the context each effect is evaluated
            at (default: ``q`` and ``context`` as given).

    Returns:
        ``(R_base_tool (N, 3, 3), p_base_tool (N, 3) [mm])``.
    """
    q = check_q(model, q)
    N, guard = q.shape[0], guard or NO_GUARD
    dq = np.zeros_like(q)
    P = None
    for e in effects:
        if e.target == "pose":
            raise ModelError(f"{e.kind} acts on the pose of a pi model, not on a POE model; fit a pi model")
        if e.target == "geometry":
            P = e.geometry(model, N, guard.hold_context(e, context, N), P)
        else:
            dq = dq + e.delta_q(model, guard.hold(e, q), guard.hold_context(e, context, N))
    return model.fk(q + dq, P=P)


def geometry_on_top(model: PoeModel, effects: Sequence[Effect], q: np.ndarray, context: Context | None,
                    R: np.ndarray, p: np.ndarray, guard: Guard | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(R, p)`` (a pose at ``q`` from any kinematics) with the geometry effects among ``effects`` applied on top:
    each moves the tool by the change it makes to ``model``'s forward kinematics at ``q`` (joint effects' deflections
    already added to ``q``), at the context the ``guard`` holds it at."""
    geometric = [e for e in effects if e.target == "geometry"]
    if not geometric:
        return R, p
    P, guard = None, guard or NO_GUARD
    for e in geometric:
        P = e.geometry(model, q.shape[0], guard.hold_context(e, context, q.shape[0]), P)
    R0, p0 = model.fk(q)
    R1, p1 = model.fk(q, P=P)
    return R1 @ np.swapaxes(R0, 1, 2) @ R, p + p1 - p0


