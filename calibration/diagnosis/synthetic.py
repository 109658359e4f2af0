"""Synthetic recordings for proving a diagnosis: a cluster design with the context effects need.

Like the paper's design (anchors on a (q2, q3) grid, each followed by +1 deg on every joint in turn) but
with the wrist and base joints spread, the anchors visited in random order, and the context columns the
effects are driven by: ``t`` increasing, ``temp_c`` following a warm-up curve, ``payload_kg`` varied per
cluster, random approach directions ``dir1..6`` and joint speeds ``qd1..qd6`` (poses taken on the fly).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from calibration.data.recording import Recording, put_in
from calibration.kinematics import so3
from calibration.kinematics.so3 import make_T
from calibration.physics import (
    Backlash,
    GearTransmission,
    JointCompliance,
    PayloadCompliance,
    ThermalDrift,
    apply_effects,
)
from calibration.physics.gravity import GravityModel, joint_origins
from calibration.physics.twin import Twin

if TYPE_CHECKING:
    from calibration.kinematics.poe import PoeModel
    from calibration.physics.base import Effect
    from calibration.physics.gravity import GravityModel


@dataclass(frozen=True)
class Design:
    """Settings of a synthetic design.

    Attributes:
        n_q2, n_q3: anchor grid size over q2 in [-50, 50] deg and q3 in [-50, 30] deg.
        spread_deg: half-range of joints 1, 4, 5 [deg] (joint 6 gets 1.5x), drawn per anchor.
        period_s: time between samples [s].
        payloads_kg: payload values drawn per cluster [kg].
        speed_rad_s: joint speeds drawn uniformly in +-speed_rad_s [rad/s].
        noise_mm: position noise per axis [mm]; noise_deg: orientation noise per axis [deg].
    """

    n_q2: int = 8
    n_q3: int = 6
    spread_deg: float = 60.0
    period_s: float = 12.0
    payloads_kg: tuple[float, ...] = (0.0, 2.0, 4.0, 6.0)
    speed_rad_s: float = 0.3
    noise_mm: float = 0.03
    noise_deg: float = 0.01


def temperature_c(t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The arm's temperature [deg C] at times t [s]: 20 deg C warming by 10 K with a 1500 s time constant, read with
    0.1 K of noise."""
    return 20.0 + 10.0 * (1 - np.exp(-t / 1500.0)) + rng.normal(0, 0.1, np.shape(t))


def context_columns(N: int, groups: np.ndarray, design: Design, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Context columns for N samples in time order, one payload per cluster."""
    t = np.arange(N) * design.period_s + rng.uniform(0, 0.5 * design.period_s, N)
    payload = np.asarray(design.payloads_kg)[rng.integers(0, len(design.payloads_kg), groups.max() + 1)][groups]
    cols = {"t": t, "temp_c": temperature_c(t, rng), "payload_kg": payload}
    cols.update({f"dir{i}": rng.choice([-1.0, 1.0], N) for i in range(1, 7)})
    cols.update({f"qd{i}": rng.uniform(-design.speed_rad_s, design.speed_rad_s, N) for i in range(1, 7)})
    return cols


def cluster_poses(design: Design, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Joint angles [rad] (N, 6) and cluster ids (N,) of the cluster design, anchors in random order."""
    s = design.spread_deg
    rows = [[rng.uniform(-s, s), q2, q3, rng.uniform(-s, s), rng.uniform(-s, min(s, 85.0)), rng.uniform(-1.5 * s, 1.5 * s)]
               for q2 in np.linspace(-50, 50, design.n_q2) for q3 in np.linspace(-50, 30, design.n_q3)]
    anchors = np.radians(np.array(rows))[rng.permutation(len(rows))]
    q = np.repeat(anchors, 7, axis=0)
    for j in range(6):
        q[j + 1::7, j] += np.radians(1.0)
    return q, np.repeat(np.arange(len(anchors)), 7)


def random_poses(n: int, design: Design, rng: np.random.Generator) -> np.ndarray:
    """Held-out poses [rad] (n, 6) spread over the same ranges as the cluster design."""
    s = design.spread_deg
    lo = np.radians([-s, -50, -50, -s, -s, -1.5 * s])
    hi = np.radians([s, 50, 30, s, min(s, 85.0), 1.5 * s])
    return rng.uniform(lo, hi, (n, 6))


def context_of(cols: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The effect context of generated columns (``qd`` stacked)."""
    ctx = {k: v for k, v in cols.items() if not k.startswith("qd")}
    ctx["qd"] = np.stack([cols[f"qd{i}"] for i in range(1, 7)], axis=1)
    return ctx


def measure(twin: Twin, q: np.ndarray, cols: dict[str, np.ndarray], design: Design, rng: np.random.Generator,
            source: str = "synthetic") -> Recording:
    """A recording of the twin at q with the given context columns and Gaussian measurement noise."""
    R, p = twin.pose(q, context_of(cols))
    p = p + rng.normal(0, design.noise_mm, p.shape)
    R = so3.exp(rng.normal(0, np.radians(design.noise_deg), p.shape)) @ R
    return Recording(q, p, so3.R_to_quat(R), {k: np.asarray(v, dtype=float) for k, v in cols.items()}, source)


def design_and_context(design: Design, seed: int) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """Cluster poses, cluster ids (also as the ``cluster`` column) and context columns for a seed."""
    rng = np.random.default_rng(seed)
    q, groups = cluster_poses(design, rng)
    cols = context_columns(len(q), groups, design, rng)
    cols["cluster"] = groups.astype(float)
    return q, groups, cols


def heldout_design(design: Design, n: int, seed: int) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Random held-out poses over the same time span and context distribution."""
    rng = np.random.default_rng(seed)
    q = random_poses(n, design, rng)
    groups = np.arange(n) // 7
    cols = context_columns(n, groups, design, rng)
    span = design.n_q2 * design.n_q3 * 7 * design.period_s
    cols["t"] = np.sort(rng.uniform(0, span, n))
    cols["temp_c"] = temperature_c(cols["t"], rng)
    return q, cols


def proof_templates(gravity: GravityModel, seed: int) -> dict[str, Effect]:
    """Where the proof plants each kind: compliances on joints 2 and 3, the gear error on a joint that
    changes with the seed, backlash on joints 1-3, growth of links p23 and p34 (warm-up, 1800 s)."""

    j = (1, 2, 3, 4, 5, 6)[seed % 6]
    return {"joint_compliance": JointCompliance(gravity, (2, 3), np.zeros(2)),
            "payload_compliance": PayloadCompliance((2, 3), np.zeros(2)),
            "gear_transmission": GearTransmission(((j, (1, 2)),), np.zeros(4)),
            "backlash": Backlash((1, 2, 3), np.zeros(3)),
            "thermal_drift": ThermalDrift(("p23", "p34"), np.zeros(2), "warmup", 1800.0)}


def make_case(nominal: PoeModel, gravity: GravityModel, magnitudes_mm: dict[str, float], seed: int,
              design: Design = Design(), n_heldout: int = 300) -> tuple[Twin, Recording, Recording]:
    """A twin with the given effects concealed (magnitudes = RMS tool displacement on the design), planted
    geometric errors (0.5 mm, 0.5 mrad), and its fit and held-out recordings."""
    q, _, cols = design_and_context(design, seed)
    twin = Twin.random(nominal, magnitudes_mm, seed, gravity=gravity, offset_std_mm=0.5, tilt_std_rad=5e-4,
                       templates=proof_templates(gravity, seed), q_ref=q, context=context_of(cols))
    rng = np.random.default_rng(seed + 100_000)
    fit = measure(twin, q, cols, design, rng, "synthetic fit")
    qh, colsh = heldout_design(design, n_heldout, seed + 1)
    return twin, fit, measure(twin, qh, colsh, design, rng, "synthetic held-out")


#: A tool-marker registration error's direction: a shift along (1, -2, 2)/3 and a rotation about (2, 1, -2)/3.
TOOL_ERROR_SHIFT = np.array([1.0, -2.0, 2.0]) / 3.0
TOOL_ERROR_AXIS = np.array([2.0, 1.0, -2.0]) / 3.0
#: Like the shared days' training recordings: joints 1, 4, 5, 6 within a few degrees of zero...
NARROW_DESIGN = Design(spread_deg=3.0)
#: ...and held-out poses that move every joint widely, like their test recordings.
WIDE_DESIGN = Design(spread_deg=60.0)


def tool_error_case(nominal: PoeModel, gravity: GravityModel, shift_mm: float = 18.0, angle_deg: float = 0.5,
                    seed: int = 0, train_design: Design = NARROW_DESIGN, test_design: Design = WIDE_DESIGN,
                    n_heldout: int = 300) -> tuple[Recording, Recording, np.ndarray]:
    """Training and held-out recordings whose tool-marker registration is off by ``shift_mm`` and ``angle_deg``.

    The arm: planted geometry (0.5 mm, 0.5 mrad) and 0.3 mm of joint compliance (:func:`make_case`); training on
    ``train_design``'s clusters, held-out on random poses of ``test_design``; both measured through the same wrong
    marker frame ``T_tool`` (marker in flange, returned (4, 4) [mm]): ``T_meas = T_true @ T_tool``.
    """

    twin, train, _ = make_case(nominal, gravity, {"joint_compliance": 0.3}, seed, train_design, 1)
    q, cols = heldout_design(test_design, n_heldout, seed + 1)
    test = measure(twin, q, cols, test_design, np.random.default_rng(seed + 200_000), "synthetic held-out")
    T_tool = make_T(so3.exp(np.radians(angle_deg) * TOOL_ERROR_AXIS), shift_mm * TOOL_ERROR_SHIFT)
    return put_in(train, np.eye(4), T_tool), put_in(test, np.eye(4), T_tool), T_tool


def orientation_rms_deg(model: PoeModel, effect: Effect, q: np.ndarray, context: dict[str, np.ndarray]) -> float:
    """RMS tool-rotation change [deg] that ``effect`` causes on its own at q (N, 6) under ``context``."""

    R0, _ = model.fk(q)
    R1, _ = apply_effects(model, [effect], q, context)
    return float(np.degrees(np.sqrt(np.mean(np.sum(so3.log(R1 @ np.swapaxes(R0, -1, -2)) ** 2, axis=1)))))


def make_wrist_case(nominal: PoeModel, gravity: GravityModel, orientation_deg: float, seed: int,
                    design: Design = Design(), n_heldout: int = 300, joint: int = 6
                    ) -> tuple[Twin, Recording, Recording]:
    """A twin with a gear error on wrist ``joint`` seen mainly in the orientation: the tool marker sits a few
    centimetres from that joint's axis (both cell tools are within 35 mm of the joint-6 axis), so the error is
    planted by the RMS tool rotation it causes (``orientation_deg``) and barely moves the position.

    Otherwise like :func:`make_case` (planted geometric errors, the same design, the same held-out recording).
    """

    q, _, cols = design_and_context(design, seed)
    ctx = context_of(cols)
    template = GearTransmission(((joint, (1, 2)),), np.zeros(4))
    twin = Twin.random(nominal, {"gear_transmission": 0.01}, seed, gravity=gravity, offset_std_mm=0.5,
                       tilt_std_rad=5e-4, templates={"gear_transmission": template}, q_ref=q, context=ctx)
    e = twin.effect("gear_transmission")
    e = e.with_values(e.values * orientation_deg / orientation_rms_deg(twin.geometry, e, q, ctx))  # linear in the values
    twin = Twin(twin.geometry, (e,), {**twin.info, "orientation_deg": {"gear_transmission": float(orientation_deg)}})
    rng = np.random.default_rng(seed + 100_000)
    fit = measure(twin, q, cols, design, rng, "synthetic fit")
    qh, colsh = heldout_design(design, n_heldout, seed + 1)
    return twin, fit, measure(twin, qh, colsh, design, rng, "synthetic held-out")


def perturbed_gravity(gravity: GravityModel, model: PoeModel, relative: float, seed: int) -> GravityModel:
    """Link masses and centres of mass that differ from ``gravity`` by ``relative`` (0.3: 30 %): each mass and
    each component of each centre of mass (relative to its joint's axis point) scaled by ``1 +- relative``, the
    signs drawn with ``seed``. The truth of a twin whose real loading is not the YAML's."""

    rng = np.random.default_rng(seed + 7_000)
    m, com = gravity.masses_coms(model)
    o = joint_origins(model)
    m = m * (1 + relative * rng.choice([-1.0, 1.0], m.shape))
    s = (com - o) * (1 + relative * rng.choice([-1.0, 1.0], com.shape))
    return GravityModel.from_links(model, m, o + s, gravity.g)
