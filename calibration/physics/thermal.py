"""Thermal drift: links grow as the arm warms up. A geometry effect, not a joint-angle one.

Each listed link vector ``P[:, j]`` (named ``p01, p12, ..., p56, p6T``) grows along its own direction by

- ``mode="warmup"``: ``dL_j(t) = growth_{link}_mm * (1 - exp(-t / tau_s))`` (context ``t`` [s]), or
- ``mode="temperature"``: ``dL_j = growth_{link}_mm_per_K * (temp_c - ref_temp_c)`` (context ``temp_c``).

Both are linear in the growth parameters for a fixed ``tau_s``/``ref_temp_c`` (these are settings, not
fitted; a fitter may scan ``tau_s``). The pose is the POE model with per-sample link vectors, and the
first-order pose Jacobian is ``dp/d growth_j = R_base_link[j] @ u_j * drive`` (orientation unchanged).
Steel grows about 11.5e-6 per kelvin: a 1082 mm forearm warming by 10 K grows about 0.12 mm.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from calibration.errors import ModelError
from calibration.kinematics.arrays import FloatArray
from calibration.kinematics.poe import PoeModel
from calibration.physics.base import Effect
from calibration.physics.context import Context, FittedSpan, check_q, context_array


def link_names(n: int) -> list[str]:
    """Names of the POE link vectors: ``p01, p12, ..., p(n-1)n, pnT``."""
    return [f"p{i}{i + 1}" for i in range(n)] + [f"p{n}T"]


@dataclass(frozen=True, eq=False)
class ThermalDrift(Effect):
    """Link growth with a warm-up curve or with temperature.

    Attributes:
        links: link vector names that grow (``p23`` upper arm, ``p34`` forearm on the Motomans).
        values: growth per link, ``growth_{link}_mm`` (warmup) or ``growth_{link}_mm_per_K`` (temperature).
        mode: ``"warmup"`` (driven by ``t``) or ``"temperature"`` (driven by ``temp_c``).
        tau_s: warm-up time constant [s] (warmup mode).
        ref_temp_c: temperature with no growth [deg C] (temperature mode; also the default of ``temp_c``).
    """

    kind = "thermal_drift"
    context_keys = frozenset({"t", "temp_c"})
    target = "geometry"
    links: tuple[str, ...] = ("p23", "p34")
    values: np.ndarray = field(default_factory=lambda: np.zeros(2))
    mode: Literal["warmup", "temperature"] = "warmup"
    tau_s: float = 1800.0
    ref_temp_c: float = 20.0

    def __post_init__(self) -> None:
        links = tuple(str(l) for l in self.links)
        valid = link_names(6)
        if not links or len(set(links)) != len(links) or any(l not in valid for l in links):
            raise ModelError(f"links must be distinct names among {', '.join(valid)}, got {list(links)}")
        if self.mode not in ("warmup", "temperature"):
            raise ModelError(f"mode must be 'warmup' or 'temperature', got {self.mode!r}")
        if not self.tau_s > 0:
            raise ModelError(f"tau_s must be positive, got {self.tau_s}")
        object.__setattr__(self, "links", links)
        object.__setattr__(self, "tau_s", float(self.tau_s))
        object.__setattr__(self, "ref_temp_c", float(self.ref_temp_c))
        super().__post_init__()

    @property
    def names(self) -> tuple[str, ...]:
        unit = "mm" if self.mode == "warmup" else "mm_per_K"
        return tuple(f"growth_{l}_{unit}" for l in self.links)

    def fitted_joints(self, n: int) -> tuple[int, ...]:
        return ()  # its drive is the time or the temperature, not q

    def fitted_context(self) -> dict[str, FittedSpan]:
        """``t`` over the time constant for the warm-up curve, above the recorded times: a recording that saw too
        little of the rise (:data:`calibration.models.guard.HELD_BELOW_RISE`) has seen the curve's slope but not its
        bend, so the asymptote would be a guess (the fitted time constant and growth trade off along that slope);
        before the recording the formula pins the curve at zero at ``t = 0``. Nothing for the growth per kelvin, a
        formula."""
        return {"t": FittedSpan(self.tau_s, "above")} if self.mode == "warmup" else {}

    def drive(self, N: int, context: Context | None = None) -> np.ndarray:
        """The per-sample factor multiplying the growth parameters, shape (N,)."""
        if self.mode == "warmup":
            t = context_array(context, "t", N)
            factor: FloatArray = 1.0 - np.exp(-np.maximum(t, 0.0) / self.tau_s)
            return factor
        return context_array(context, "temp_c", N, self.ref_temp_c) - self.ref_temp_c

    def _directions(self, model: PoeModel) -> tuple[list[int], np.ndarray]:
        names = link_names(model.n_joints)
        cols = [names.index(l) for l in self.links]
        P = model.P[:, cols]
        norms = np.linalg.norm(P, axis=0)
        if np.any(norms < 1e-9):
            raise ModelError(f"links {[l for l, n in zip(self.links, norms) if n < 1e-9]} have zero length "
                             "and cannot grow")
        return cols, (P / norms).T  # (L, 3)

    def grow(self, P: list[Any], values: Any, N: int, context: Context | None, model: PoeModel) -> list[Any]:
        cols, u = self._directions(model)
        s = self.drive(N, context)
        P = list(P)
        for c, uj, v in zip(cols, u, [values[i] for i in range(len(cols))]):
            if isinstance(P[c], np.ndarray):
                P[c] = P[c] + (v * s)[:, None] * uj
            else:  # casadi, one configuration at the default context
                import casadi as ca

                P[c] = P[c] + v * float(s[0]) * ca.DM(uj)
        return P

    def geometry(self, model: PoeModel, N: int, context: Context | None = None,
                 P: np.ndarray | None = None) -> np.ndarray:
        P = np.array(np.broadcast_to(model.P if P is None else P, (N, 3, model.n_joints + 1)))
        grown = self.grow([P[:, :, c] for c in range(P.shape[2])], self.values, N, context, model)
        return np.stack(grown, axis=2)

    def pose_jacobian(self, model: PoeModel, q: np.ndarray, context: Context | None = None) -> np.ndarray:
        q = check_q(model, q)
        cols, u = self._directions(model)
        ch = model.chain(q)
        s = self.drive(q.shape[0], context)
        J = np.zeros((q.shape[0], 6, self.size))
        for col, (c, uj) in enumerate(zip(cols, u)):
            J[:, :3, col] = (ch.R_base_link[c] @ uj) * s[:, None]
        return J

    def _config(self) -> dict[str, Any]:
        return {"links": list(self.links), "mode": self.mode, "tau_s": self.tau_s, "ref_temp_c": self.ref_temp_c}
