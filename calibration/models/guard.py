"""The extrapolation guard: where a model's poses leave what its training data identified, and what it does there.

A :class:`Region` is the per-joint range of the training recording. Each physics effect of a ``physics`` or
``diagnosed`` model is evaluated at the joint angles :meth:`Region.hold` gives it: softly clamped into the range
(:meth:`Region.clamp`: inside, unchanged; outside, held near the value at the edge, saturating within
``margin_rad``, C1-continuous, so Jacobians and the casadi expression stay smooth) in the joints it is held in
(:meth:`Region.held_joints`), as read in every other joint. The rigid geometry moves with q everywhere.

Which joints (rule ``by_effect``, :data:`RULE_BY_EFFECT`): those whose angles the effect's fitted shape is a function
of (the effect's own declaration, :meth:`~calibration.physics.base.Effect.fitted_joints`) that the training data saw
over less than :data:`NARROW_SPAN_RAD`.
- A gear error's harmonics fitted inside a 2 deg band of q5 are held there, not swung through their period 40 deg
  away; fitted over 100 deg of q2, they go on as fitted.
- A compliance times a gravity torque (of the arm's masses, or of the mass-free gravity shape) has no fitted shape:
  it goes on as its formula says, in every joint.
A region saved before the rule (no ``rule`` key) holds every effect in every joint, as it did then
(:data:`RULE_EVERY_JOINT`), so an older model file predicts what it predicted.

The same in time and temperature: the region also records the range of each context entry of
:data:`GUARDED_CONTEXT` the training recording carried (:attr:`Region.context_range`), and an effect whose fitted
shape is a function of one, seen over too little of the span the shape shows itself over
(:meth:`~calibration.physics.base.Effect.fitted_context`: a warm-up curve recorded for less time than a cold start
takes to show a fifth of its fitted rise, :data:`HELD_BELOW_RISE`), is evaluated at that entry softly clamped into
the range (:meth:`Region.hold_context`, margin a share of the span). A warm-up fitted on ten minutes has then seen
its slope, not its bend, and its asymptote is a guess; held at the edge, it does not promise millimetres hours
later. ``scripts/benchmarks/bench_time_guard.py`` (synthetic twins, a 1800 s warm-up, 670 s recordings, poses 1-4 h on): a fit
whose time constant ran off (25 h) promised 4.5-5.0 / 8.9-10.4 mm without the hold and about 1.0 / 1.3 with it; a
fit that found its time constant (1.0-4.2 recording spans) is better free (0.05-0.77 mm mean) than held (about 1.0).
The first rule held any recording shorter than the fitted time constant, and so those too (a region saved with it
keeps it, :data:`CONTEXT_RULE_SPAN`; :data:`HELD_BELOW_RISE` says how the share was chosen). On seeds 30-39, which
no choice saw, no fit ran off and none is held: median of the later poses 0.292/0.451 mm, against 1.018/1.287 with
the first rule, which held 8 of the 10. On 67 min recordings (over two time constants) nothing is held. Before the
recording a warm-up is pinned at zero at ``t = 0`` by its formula and is not held. A growth per kelvin and a payload
compliance are formulas and go on as they say; a context entry the call does not carry (the default context, a
casadi expression) is not held.

A ``pi`` model has no guard. Its compliance is the mass-free gravity shape; its structural deflection's shape is
fitted, in q2 and q3 only, which every shared training day sees over 60 deg or more, so the rule would not hold it
there either (and holding it in q2, q3 was measured to cost the q2/q3 edge folds of
``scripts/studies/extrapolation_folds.py``). :func:`extrapolation` says how many poses lie outside the region and by how
much (``evaluate`` and ``predict`` report it).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Final, Literal

import numpy as np

from calibration.errors import ModelError
from calibration.kinematics.arrays import BoolArray, FloatArray

#: Width over which the clamp saturates outside the training range [rad], for a region saved without its own
#: (models fitted before the margins came from the data; see :func:`data_margin_rad`).
DEFAULT_MARGIN_RAD = math.radians(2.0)
#: A joint's clamp margin as a share of its training span, at most ``DEFAULT_MARGIN_RAD`` (:func:`data_margin_rad`).
MARGIN_SHARE = 0.1
#: The smallest clamp margin [rad]: a joint the training data never moved is held at the one angle it saw.
MIN_MARGIN_RAD = 1e-3
#: A joint the training data saw over less than this [rad] is seen narrowly: an effect whose fitted shape depends on
#: its angle is held at the edge there. Chosen on the training-only folds of ``scripts/studies/extrapolation_folds.py``
#: (see :data:`RULE_BY_EFFECT`); on the shared days the training spans are 12 deg or less (q1, q4-q6) or 60 deg or more
#: (q2, q3), so any value between gives the same figures.
NARROW_SPAN_RAD = math.radians(20.0)
#: Each effect held in the joints its fitted shape depends on that the data saw narrowly (regions fitted from now
#: on). Against every effect held in every joint, on the 24 extrapolation folds (training data only) the held-out
#: position error falls from 0.2094/0.6691 to 0.2065/0.6628 mm (mean over the folds of the mean/max, the same fits):
#: better on 8 folds, the same on 12, worse on 4 (0524 q3 edges +0.011, 0613 q2 edges +0.024, 0801 q2 edges
#: +0.027 mm mean; 0801 q3 edges +0.001 mean, -0.035 max). Letting the compliances extrapolate while holding every
#: harmonic in every joint, even one fitted over 100 deg of q2, is worse than either (0.2101/0.6712).
RULE_BY_EFFECT: Final = "by_effect"
#: Every effect held in every joint: a region saved before the effects declared their own (no ``rule`` key).
RULE_EVERY_JOINT: Final = "every_joint"
GuardRule = Literal["by_effect", "every_joint"]
RULES = (RULE_BY_EFFECT, RULE_EVERY_JOINT)
#: Share of an effect's exponential approach to its asymptote (a warm-up's rise from a cold start) the training
#: data must span, ``1 - exp(-seen / span)``, for the fitted curve to be trusted beyond it; less is held at the edge
#: (regions fitted from now on, :data:`CONTEXT_RULE_RISE`). Chosen with ``scripts/benchmarks/bench_time_guard.py`` (a
#: concealed 1800 s warm-up, 670 s recordings, poses 1-4 h later): over seeds 0-29, every fit whose time constant
#: came out at 5.47 spans or more (to 133) was better held (max 1.65-10.4 mm free, at most 1.37 held), and every
#: one between 1.01 and 4.17 spans better free (0.05-0.77 mm mean free against about 1 mm held); a fifth of the
#: rise is 4.48 spans. Judged on seeds 30-39, which no choice saw.
HELD_BELOW_RISE = 0.2
#: Context entries held by :data:`HELD_BELOW_RISE` (regions fitted from now on).
CONTEXT_RULE_RISE = "rise_share"
#: Context entries held when the data saw less than the effect's whole span (a warm-up recorded for less than its
#: time constant): the rule of a region saved before :data:`CONTEXT_RULE_RISE` (no ``context_rule`` key), which
#: also held the fits that had found their time constant, kept so an older model file predicts what it predicted.
CONTEXT_RULE_SPAN = "span"
CONTEXT_RULES = (CONTEXT_RULE_RISE, CONTEXT_RULE_SPAN)
#: The per-sample context entries whose training range a region records (a recording's columns of these names).
GUARDED_CONTEXT = ("t", "temp_c", "payload_kg")
#: Units of :data:`GUARDED_CONTEXT`, for the messages.
CONTEXT_UNITS = {"t": "s", "temp_c": "deg C", "payload_kg": "kg"}


def data_margin_rad(lower_rad: np.ndarray, upper_rad: np.ndarray) -> np.ndarray:
    """Per-joint clamp margin from the training data's own spread: ``MARGIN_SHARE`` of each joint's span, between
    ``MIN_MARGIN_RAD`` and ``DEFAULT_MARGIN_RAD``. An effect identified inside a narrow band is not carried further
    beyond it than a share of the band's own width; a wide band keeps the 2 deg margin.

    Chosen on the shared days' training recordings only (``scripts/studies/extrapolation_folds.py``: edge clusters of q2
    or q3, or the q1/q4-q6 steps, held out and extrapolated to; position mean/max [mm] on them). On 0620's steps
    (a gear error on a wrist joint seen within +-2 deg) the fixed 2 deg gives 0.185/0.666, 10 % of the span
    0.164/0.657, held hard at the edge 0.160/0.655. On the wide joints a share of the span cuts both ways: 10 % of
    the span (10-12 deg) helps 0524's q2 edges (0.197/0.841 -> 0.191/0.830) but costs 0524's q3 edges
    (0.179/0.451 -> 0.180/0.470), so the margin is capped at the old 2 deg. On every other fold evaluated the
    margin changes nothing beyond the third decimal.
    """
    span = np.asarray(upper_rad, dtype=float) - np.asarray(lower_rad, dtype=float)
    margin_rad: FloatArray = np.clip(MARGIN_SHARE * span, MIN_MARGIN_RAD, DEFAULT_MARGIN_RAD)
    return margin_rad


def excess_beyond(v: np.ndarray, lo: Any, hi: Any) -> np.ndarray:
    """How far v lies outside [lo, hi], zero inside (same shape as v)."""
    excess: FloatArray = np.maximum(lo - v, 0.0) + np.maximum(v - hi, 0.0)
    return excess


def soft_clamp(v: np.ndarray, lo: Any, hi: Any, m: Any, below: bool = True) -> np.ndarray:
    """v softly clamped into [lo, hi]: unchanged inside, ``hi + m tanh((v - hi) / m)`` above, and the mirror image
    below (only when ``below``): continuous with slope 1 at the edges, saturating within ``m`` outside."""
    above = hi + m * np.tanh(np.maximum(v - hi, 0.0) / m)
    under = lo - m * np.tanh(np.maximum(lo - v, 0.0) / m) if below else v
    return np.where(v > hi, above, np.where(v < lo, under, v))


@dataclass(frozen=True)
class Region:
    """Per-joint range of the training data.

    Attributes:
        lower_rad, upper_rad: smallest and largest training angle per joint [rad] (n,).
        margin_rad: the clamp's saturation width outside the range [rad], one for every joint or per joint (n,).
        rule: which joints an effect is held in (:meth:`held_joints`): ``by_effect`` (those its fitted shape depends
            on that the data saw narrowly) or ``every_joint`` (all, the guard of regions saved before the rule).
        context_range: smallest and largest value of each context entry of :data:`GUARDED_CONTEXT` the training
            data carried, ``{"t": (0.0, 600.0)}`` (empty for a recording with none, or a region saved before).
        context_rule: when an effect is held in a context entry (:meth:`held_context`): ``rise_share`` (the data saw
            less than :data:`HELD_BELOW_RISE` of its approach to the asymptote) or ``span`` (less than its whole
            span: regions saved before ``rise_share``).
    """

    lower_rad: np.ndarray
    upper_rad: np.ndarray
    margin_rad: float | np.ndarray = DEFAULT_MARGIN_RAD
    rule: GuardRule = RULE_BY_EFFECT
    context_range: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    context_rule: str = CONTEXT_RULE_RISE

    def __post_init__(self) -> None:
        lo, hi = np.asarray(self.lower_rad, dtype=float), np.asarray(self.upper_rad, dtype=float)
        if lo.shape != hi.shape or lo.ndim != 1 or np.any(hi < lo) or not np.all(np.isfinite(np.r_[lo, hi])):
            raise ModelError(f"a training region needs finite lower <= upper per joint, got {lo} and {hi}")
        m = np.asarray(self.margin_rad, dtype=float)
        if m.ndim > 1 or (m.ndim == 1 and m.shape != lo.shape) or not np.all(m > 0) or not np.all(np.isfinite(m)):
            raise ModelError(f"the clamp margin must be positive, one or one per joint, got {self.margin_rad}")
        if self.rule not in RULES:
            raise ModelError(f"unknown guard rule {self.rule!r}; valid: {', '.join(RULES)}")
        if self.context_rule not in CONTEXT_RULES:
            raise ModelError(f"unknown context rule {self.context_rule!r}; valid: {', '.join(CONTEXT_RULES)}")
        ranges = {}
        for key, bounds in dict(self.context_range).items():
            b = np.asarray(bounds, dtype=float)
            if key not in GUARDED_CONTEXT or b.shape != (2,) or not np.all(np.isfinite(b)) or b[1] < b[0]:
                raise ModelError(f"a training region's context range needs finite lower <= upper for entries among "
                                 f"{', '.join(GUARDED_CONTEXT)}, got {key!r}: {bounds!r}")
            ranges[key] = (float(b[0]), float(b[1]))
        object.__setattr__(self, "lower_rad", lo)
        object.__setattr__(self, "upper_rad", hi)
        object.__setattr__(self, "margin_rad", float(m) if m.ndim == 0 else m)
        object.__setattr__(self, "context_range", ranges)

    @classmethod
    def of(cls, q: np.ndarray, margin_rad: float | np.ndarray | None = None,
           context: Mapping[str, np.ndarray] | None = None) -> Region:
        """The range of joint angles q [rad] (N, n) and of the entries of :data:`GUARDED_CONTEXT` in the training
        ``context`` (a recording's :meth:`~calibration.data.recording.Recording.context`); by default each joint's
        margin from the data's own spread (:func:`data_margin_rad`)."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        lo, hi = q.min(axis=0), q.max(axis=0)
        seen = {k: np.asarray(v, dtype=float) for k, v in (context or {}).items()
                if k in GUARDED_CONTEXT and v is not None}
        seen = {k: v[np.isfinite(v)] for k, v in seen.items()}
        ranges = {k: (float(v.min()), float(v.max())) for k, v in seen.items() if v.size}
        return cls(lo, hi, data_margin_rad(lo, hi) if margin_rad is None else margin_rad, context_range=ranges)

    def excess(self, q: np.ndarray) -> np.ndarray:
        """How far each joint lies outside the range [rad] (N, n), zero inside."""
        return excess_beyond(np.atleast_2d(np.asarray(q, dtype=float)), self.lower_rad, self.upper_rad)

    def clamp(self, q: np.ndarray, joints: Sequence[int] | None = None) -> np.ndarray:
        """q (N, n) softly clamped into the range: ``edge + m tanh(excess / m)`` outside, unchanged inside; only the
        0-based ``joints`` listed (all when None), the others as given."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        held = soft_clamp(q, self.lower_rad, self.upper_rad, self.margin_rad)
        if joints is None:
            return held
        out = q.copy()
        out[:, list(joints)] = held[:, list(joints)]
        return out

    def clamp_casadi(self, q: Any, joints: Sequence[int] | None = None) -> Any:
        """:meth:`clamp` of casadi joint symbols (n,)."""
        import casadi as ca

        out = []
        margins = np.broadcast_to(self.margin_rad, self.lower_rad.shape)
        chosen = range(q.shape[0]) if joints is None else set(joints)
        for i in range(q.shape[0]):
            lo, hi, m = float(self.lower_rad[i]), float(self.upper_rad[i]), float(margins[i])
            out.append(ca.if_else(q[i] > hi, hi + m * ca.tanh((q[i] - hi) / m),
                                  ca.if_else(q[i] < lo, lo - m * ca.tanh((lo - q[i]) / m), q[i]))
                       if i in chosen else q[i])
        return ca.vertcat(*out)

    def narrow(self) -> np.ndarray:
        """Per joint (n,), whether the training data saw it over less than :data:`NARROW_SPAN_RAD`."""
        narrow: BoolArray = self.upper_rad - self.lower_rad < NARROW_SPAN_RAD
        return narrow

    def held_joints(self, effect: Any) -> tuple[int, ...]:
        """The 0-based joints ``effect`` (a :class:`~calibration.physics.base.Effect`) is held in under this
        region's rule: those its fitted shape depends on that the data saw narrowly, or every joint for a region
        saved before the rule."""
        n = self.lower_rad.size
        if self.rule == RULE_EVERY_JOINT:
            return tuple(range(n))
        narrow = self.narrow()
        return tuple(j for j in effect.fitted_joints(n) if narrow[j])

    def hold(self, effect: Any, q: np.ndarray) -> np.ndarray:
        """The joint angles (N, n) ``effect`` is evaluated at for the readings q (N, n): clamped in the joints it is
        held in (:meth:`held_joints`), as read in the others."""
        joints = self.held_joints(effect)
        return self.clamp(q, joints) if joints else np.atleast_2d(np.asarray(q, dtype=float))

    def hold_casadi(self, effect: Any, q: Any) -> Any:
        """:meth:`hold` of casadi joint symbols (n,)."""
        joints = self.held_joints(effect)
        return self.clamp_casadi(q, joints) if joints else q

    def held_context(self, effect: Any) -> dict[str, str]:
        """The context entries ``effect`` is held in, each with the sides it is held on (``both`` or ``above``): those
        its fitted shape depends on that the training data saw over too little of the span the shape shows itself
        over (:meth:`~calibration.physics.base.Effect.fitted_context`, a warm-up's time constant): less than
        :data:`HELD_BELOW_RISE` of its approach to the asymptote, or less than the whole span for a region saved
        before that rule (:attr:`context_rule`)."""
        seen = {k: hi - lo for k, (lo, hi) in self.context_range.items()}
        share = (lambda s, span: s < span) if self.context_rule == CONTEXT_RULE_SPAN else \
            (lambda s, span: -math.expm1(-s / span) < HELD_BELOW_RISE)
        return {k: fitted.sides for k, fitted in effect.fitted_context().items()
                if share(seen.get(k, math.inf), fitted.span)}

    def context_margin(self, key: str) -> float:
        """The clamp margin of context entry ``key``: :data:`MARGIN_SHARE` of its training span (a millionth of the
        edge's size, or of 1, for an entry the data saw at one value)."""
        lo, hi = self.context_range[key]
        return max(MARGIN_SHARE * (hi - lo), 1e-6 * max(abs(lo), abs(hi), 1.0))

    def hold_context(self, effect: Any, context: Mapping[str, Any] | None, N: int) -> Mapping[str, Any] | None:
        """The context ``effect`` is evaluated at for a recorded ``context`` of N samples: the entries it is held in
        (:meth:`held_context`) softly clamped into their training range on the sides it is held on, the others as
        given; an entry the context does not carry keeps the effect's default.

        Raises:
            ModelError: a held entry is neither a scalar nor of shape (N,).
        """
        from calibration.physics.context import (
            context_array,  # not at the top: a model need not load the physics package
        )

        held = {k: sides for k, sides in self.held_context(effect).items()
                if context is not None and context.get(k) is not None}
        if not held or context is None:  # held is empty when context is None
            return context
        return {**context, **{k: soft_clamp(context_array(context, k, N), *self.context_range[k],
                                            self.context_margin(k), below=sides == "both")
                              for k, sides in held.items()}}

    def context_excess(self, context: Mapping[str, Any] | None, N: int,
                       keys: Sequence[str] | None = None) -> dict[str, np.ndarray]:
        """How far each sample's recorded context entries lie outside their training range (N,), zero inside: per
        entry the region knows, the context carries and ``keys`` lists (all when None).

        Raises:
            ModelError: such an entry is neither a scalar nor of shape (N,).
        """
        from calibration.physics.context import context_array

        out = {}
        for k, (lo, hi) in self.context_range.items():
            if context is not None and context.get(k) is not None and (keys is None or k in keys):
                out[k] = excess_beyond(context_array(context, k, N), lo, hi)
        return out

    def without_context(self) -> Region:
        """The same region with no context range: its joint guard alone."""
        return replace(self, context_range={})

    def to_dict(self) -> dict[str, Any]:
        m = self.margin_rad
        d = {"lower_rad": self.lower_rad.tolist(), "upper_rad": self.upper_rad.tolist(),
             "margin_rad": m.tolist() if isinstance(m, np.ndarray) else float(m), "rule": self.rule}
        if self.context_range:
            d["context_range"] = {k: list(v) for k, v in self.context_range.items()}
            d["context_rule"] = self.context_rule
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Region:
        """Inverse of :meth:`to_dict`; a region saved before the rule existed (no ``rule``) keeps the guard it had
        then, every effect held in every joint, and one saved before the context rule (no ``context_rule``) keeps
        its hold in time (:data:`CONTEXT_RULE_SPAN`)."""
        try:
            m = d.get("margin_rad", DEFAULT_MARGIN_RAD)
            return cls(np.asarray(d["lower_rad"], dtype=float), np.asarray(d["upper_rad"], dtype=float),
                       np.asarray(m, dtype=float) if isinstance(m, list) else float(m),
                       d.get("rule", RULE_EVERY_JOINT), {k: tuple(v) for k, v in d.get("context_range", {}).items()},
                       d.get("context_rule", CONTEXT_RULE_SPAN))
        except (AttributeError, KeyError, TypeError, ValueError) as e:
            raise ModelError(f"bad training_region {d!r}: {e}") from e


#: Key of a model's ``info`` holding its training region.
REGION_KEY = "training_region"


def region_of(info: dict[str, Any]) -> Region | None:
    """The training region recorded in a model's ``info``, or None (a model fitted before the guard)."""
    d = info.get(REGION_KEY)
    return None if d is None else Region.from_dict(d)


#: A pose counts as outside the training range only when a joint lies more than this beyond it [deg]: half the 0.1 deg
#: the warnings print the excess in, so a count never comes with "by up to 0.0 deg" (poses a rounding's width past the
#: edge, such as a test pose on the training grid's own limit, were counted as extrapolated). Chosen by the printed
#: precision, not on any recording.
OUTSIDE_TOLERANCE_DEG = 0.05


def extrapolation(model: Any, q: np.ndarray, context: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """How many poses lie outside what the model's training data identified, by how much, and what the guard did.

    ``evaluate``, ``predict`` and ``diagnose`` all count with this one rule: a pose is outside the training range
    when one of its joints lies more than :data:`OUTSIDE_TOLERANCE_DEG` beyond that joint's training range (a pose
    only a rounding's width past the edge is not). In time, temperature and payload (the recorded ``context``) a pose
    is outside when its entry lies beyond the training range at all.

    Args:
        model: a :class:`~calibration.models.base.KinematicModel`.
        q: joint angles [rad] (N, n).
        context: the poses' recorded context (a recording's :meth:`~calibration.data.recording.Recording.context`), or
            None (the default context, which the guard never holds).

    Returns:
        ``poses``, ``outside_training_range`` (poses with a joint more than ``outside_tolerance_deg`` outside the
        training range), ``outside_tolerance_deg``, ``max_excess_deg`` (the largest joint excess of any pose, 0
        inside the range) and ``rms_excess_deg`` (over the poses counted outside, of each one's largest joint
        excess), ``max_excess_deg_per_joint`` (n,), ``outside_context_range`` (per context entry the model's effects
        read whose training range the model records and the poses carry: ``poses`` outside it, ``max_excess`` in
        ``unit``, ``range`` of the training data), ``outside_model_region`` (the model's own region test, e.g. a cdc
        interpolator's), ``region_known`` (False for a model saved without its training region), ``guard_acted`` /
        ``guard_shift_mm_max``: whether the guard changed the model's prediction on these poses (its terms held at
        the edge of the range, wherever a joint or a held context entry is past it at all) and the largest position
        change it made [mm] (0 and False for a model whose every term is rigid, or with every pose inside), and
        ``guard_shift_context_mm_max``: the part of it the hold in time, temperature and payload made, on the poses
        past their range (the joint guard left as it is).
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    region = model.region()
    own = int(np.count_nonzero(model.out_of_range(q)))
    out: dict[str, Any] = {"poses": int(q.shape[0]), "region_known": region is not None, "outside_model_region": own,
                           "outside_tolerance_deg": OUTSIDE_TOLERANCE_DEG}
    if region is None:
        return {**out, "outside_training_range": None, "max_excess_deg": None, "rms_excess_deg": None,
                "max_excess_deg_per_joint": None, "outside_context_range": {}, "guard_acted": False,
                "guard_shift_mm_max": None, "guard_shift_context_mm_max": None}
    ex = np.degrees(region.excess(q))
    worst = ex.max(axis=1)
    outside = worst > OUTSIDE_TOLERANCE_DEG
    context_ex = region.context_excess(context, q.shape[0], tuple(model.context_keys))
    late = np.zeros(q.shape[0], dtype=bool)  # poses past the range of a context entry
    for e in context_ex.values():
        late |= e > 0
    held = (worst > 0) | late  # where the guard's clamps act, however little
    shift = guard_shift_mm(model, q[held], _rows(context, held)) if held.any() else 0.0
    shift_context = (guard_shift_mm(model, q[late], _rows(context, late), region.without_context()) if late.any()
                     else 0.0)
    return {**out, "outside_training_range": int(np.count_nonzero(outside)),
            "max_excess_deg": float(worst.max(initial=0.0)),
            "rms_excess_deg": float(np.sqrt(np.mean(worst[outside] ** 2))) if outside.any() else 0.0,
            "max_excess_deg_per_joint": ex.max(axis=0).tolist(),
            "outside_context_range": {k: {"poses": int(np.count_nonzero(e > 0)), "max_excess": float(e.max(initial=0.0)),
                                          "unit": CONTEXT_UNITS[k], "range": list(region.context_range[k])}
                                      for k, e in context_ex.items()},
            "guard_acted": bool(shift > GUARD_ACTED_MM), "guard_shift_mm_max": shift,
            "guard_shift_context_mm_max": shift_context}


def _rows(context: Mapping[str, Any] | None, index: np.ndarray) -> dict[str, Any] | None:
    """The rows ``index`` (a mask over N samples) of a per-sample context: an entry of one row, or a scalar, stands
    for every row; ``qd`` (N, n) is taken by row."""
    if context is None:
        return None
    N = index.shape[0]
    return {k: v if v is None or np.ndim(v) == 0 else np.broadcast_to(v, (N,) + np.shape(v)[1:])[index]
            for k, v in context.items()}


#: What each count of :func:`extrapolation` counts, in words, for the JSON of the commands that report it: a user
#: read ``outside_fitted_region: 0`` beside ``outside_training_range: 50`` as a contradiction.
COUNTS_EXPLAINED = {
    "outside_training_range": f"poses with a joint more than {OUTSIDE_TOLERANCE_DEG:g} deg outside that joint's range "
                              "in the model's training data, for every model kind (null: the model file records no "
                              "training range)",
    "outside_context_range": "per recorded context entry (t, temp_c, payload_kg) whose training range the model "
                             "records: poses beyond that range, by how much, and the range",
    "outside_model_region": "poses outside the model's own interpolation region: the convex hull of the (q2, q3) "
                            "anchors a cdc model interpolates its parameters over; always 0 for a model of one "
                            "constant geometry (nominal, nls1, pi, ...), which has no such region",
}


#: The guard is said to have acted when it moves a predicted position by more than this [mm] (rounding level).
GUARD_ACTED_MM = 1e-9


def guard_shift_mm(model: Any, q: np.ndarray, context: Mapping[str, Any] | None = None,
                   against: Region | None = None) -> float:
    """The largest change [mm] the guard makes to the model's predicted position at joint angles q (N, n) and the
    poses' ``context``: the model against itself with its training region replaced by ``against`` (None: removed,
    which turns the guard off; the region without its context range: the guard in time and temperature alone)."""
    if q.shape[0] == 0:
        return 0.0
    other = model.with_region(against)
    return float(np.max(np.linalg.norm(model.fk_context(q, context)[1] - other.fk_context(q, context)[1], axis=1)))
