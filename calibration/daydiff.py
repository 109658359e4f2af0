"""What differs between recordings (days) of one arm: frames, kinematic parameters, named physical changes.

Model, for the poses of recording ``d`` (poses in millimetres)::

    T_meas ~= T_base(delta_d) @ T_arm(q; x) @ T_tool(delta_d)

``x`` are the minimal POE parameters (:class:`calibration.parameterisation.MinimalParameterisation`, the
deviations from the nominal arm) and ``delta_d`` the 12 frame corrections of :func:`calibration.rebase.corrections`
(base: mocap to base, tool: marker to flange), one pair per recording. Steps:

1. **Shared arm**: one ``x`` for every recording, each with its own frames, by Gauss-Newton on the frames-reduced
   normal equations (the Schur complement of each recording's frames). Directions of ``x`` that a frame change
   explains exactly (joint 1's placement is the base frame's, the flange's the tool frame's) are a gauge: the step
   is the pseudo-inverse's, so the shared arm has none of them.
2. **Each recording's own arm** from the shared one, moved only along the directions *that recording* identifies:
   eigenvectors of its frames-reduced information (scaled: tilts to millimetres at a 1 m reach) whose singular
   value is at least ``IDENTIFIED_TOLERANCE`` of the largest. A recording that hardly moves joints 1, 4-6 does
   not identify their parameters; they are reported as unidentified, not fitted to noise.
3. **Noise**: residuals are whitened per channel by each recording's own-fit noise floors
   (:func:`calibration.diagnosis.noise.noise_floor`, the fit-residual estimates: a kinematic model does not reach
   the repeatability, so the scatter the parameters are judged against is its own residual). The covariance of
   each recording's parameters is the cluster-robust sandwich ``A^+ B A^+`` (``B`` sums each cluster's score):
   the residual of neighbouring poses is correlated, and counting every pose as independent would call noise a
   difference. With fewer than ``CLUSTERS_PER_DIRECTION`` clusters per direction it is ``A^+`` (see
   :func:`covariance`).
4. **Tests** against the first recording (the reference, as in :mod:`calibration.multiday`), each recording
   independent: ``d = x_day - x_ref`` on the directions both identify, covariance ``C_day + C_ref``; a joint
   chi-square over those directions and a z per parameter whose direction both identify (at least
   ``IDENTIFIED_SHARE`` of it), at a family-wise level ``ALPHA`` (Bonferroni over recordings and parameters).
   Frames likewise, per component. Every pair of recordings gets the joint test too (who agrees with whom).
5. **Named changes**: the difference is explained greedily by physical directions (a joint's zero offset, a
   link's length, a uniform growth of every link, the way heat would act) while one still reduces the chi-square
   significantly; what remains beyond the noise is reported as unexplained.
6. **Drift within a recording**: only when it carries time order (``t`` or ``temp_c``, see
   ``../shared/spec/recording-format.md``): its early and late halves (whole clusters) are compared the same way.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from scipy import special  # not scipy.stats: its import costs ~1 s per command (the same values, bit for bit)

from calibration import so3
from calibration.diagnosis.noise import noise_floor
from calibration.errors import DataError, ModelError
from calibration.identification import DEFAULT_ORIENTATION_WEIGHT, rotation_residual_scale
from calibration.identification.geometric import weighted_residuals
from calibration.identification.observability import DEFAULT_REACH_MM, DEFAULT_RELATIVE_TOLERANCE
from calibration.models.rebased import wrap_pose
from calibration.parameterisation import MinimalParameterisation
from calibration.poe import PoeModel
from calibration.rebase import DIRECTION_NAMES, corrections
from calibration.recording import Recording

#: A direction is identified by a recording when its singular value is at least this share of the largest.
IDENTIFIED_TOLERANCE = DEFAULT_RELATIVE_TOLERANCE
#: A parameter (or named change) is tested when at least this share of it (squared norm) lies in the directions
#: both recordings identify; otherwise it is reported as unidentified.
IDENTIFIED_SHARE = 0.5
#: Directions of the parameters a frame change reproduces exactly (on any data): singular values below this share
#: of the largest on a rich design (:meth:`DaysProblem.gauge`; they are ~1e-8, the next ones ~4e-2).
GAUGE_TOLERANCE = 1e-5
#: Clusters per tested direction below which the covariance is the model's, not the cluster-robust sandwich.
CLUSTERS_PER_DIRECTION = 5
#: A direction whose part outside the gauge is below this share of it (squared norm) is a frame change (joint 1's
#: offset leaves ~1e-8, the next smallest named change 0.1).
GAUGE_RESIDUE = 1e-4
#: Two poses are the same when every joint is within this [deg]; two recordings cover the same poses when at least
#: ``SAME_POSES`` of each's are in the other. Otherwise a kinematic difference between them may be a
#: configuration-dependent effect the geometric model leaves out: on the shared days, the lower and the upper
#: anchors of one training recording "differ" by up to 2 mm of link length, while its even and odd clusters agree.
POSE_MATCH_DEG = 1.0
SAME_POSES = 0.9
#: Poses of the rich design the gauge is found on.
GAUGE_POSES = 300
#: Family-wise false-alarm level of the tests (Bonferroni over recordings and the parameters tested).
ALPHA = 0.01
#: A recording whose nominal arm, with its frames fitted, still misses by more than this mean [mm] is not a
#: recording of this robot (the shared R1 days leave 0.3-0.6 mm; another arm's link lengths leave centimetres).
OTHER_ROBOT_MM = 5.0
#: Gauss-Newton iterations of the shared arm and of each recording's own arm.
SHARED_ITERATIONS, OWN_ITERATIONS = 6, 3
#: Most named changes tried together on one recording.
MAX_NAMED = 3
#: Finite-difference step in scaled units (mm, or mrad at a 1 m reach).
FD_STEP = 1e-4
#: Units the 12 frame corrections are reported in (shifts mm, rotations deg).
FRAME_UNITS = ("mm",) * 3 + ("deg",) * 3 + ("mm",) * 3 + ("deg",) * 3


@dataclass(frozen=True)
class Named:
    """A physical change: its name, unit, direction in the parameters and the tool-frame change that comes with
    it (the flange moves with the links downstream; the parameters hold the flange point), both per unit."""

    name: str
    unit: str
    direction: np.ndarray
    tool: np.ndarray


def named_changes(nominal: PoeModel) -> list[Named]:
    """Joint zero offsets (per deg), link lengths (per mm, links of at least 1 mm) and a uniform growth of every
    link (per ppm) as directions of the minimal parameters, each with its tool-frame part."""
    par_tool = MinimalParameterisation(nominal, fit_tool=True)
    par = MinimalParameterisation(nominal)
    H, P, n = nominal.H, nominal.P, nominal.n_joints
    R0, p0 = nominal.fk(np.zeros((1, n)))
    origins = np.cumsum(P, axis=1)
    eps = 1e-3  # deg, mm or ppm * 1e3: small enough to be linear

    def change(name: str, unit: str, H2: np.ndarray, P2: np.ndarray, G_R: np.ndarray, G_p: np.ndarray, per: float
               ) -> Named:
        v = par_tool.from_geometry(H2, P2)[:-3] / per
        Ra, pa = par.pose(np.zeros((1, n)), v * per)
        Rt, pt = G_R @ R0[0], G_R @ p0[0] + G_p  # the true marker pose at q = 0
        tool = np.concatenate([Ra[0].T @ (pt - pa[0]), so3.log(Ra[0].T @ Rt)]) / per
        return Named(name, unit, v, tool)

    out = []
    for j in range(n):
        R = so3.exp(np.radians(eps) * H[:, j])
        H2, P2 = H.copy(), P.copy()
        H2[:, j + 1:] = R @ H[:, j + 1:]
        P2[:, j + 1:] = R @ P[:, j + 1:]
        o = origins[:, j]
        out.append(change(f"joint {j + 1} zero offset", "deg", H2, P2, R, o - R @ o, eps))
    for k in range(1, n):
        length = float(np.linalg.norm(P[:, k]))
        if length >= 1.0:
            P2 = P.copy()
            P2[:, k] *= 1 + eps / length
            out.append(change(f"link {k}-{k + 1} length", "mm", H, P2, np.eye(3), P2[:, k] - P[:, k], eps))
    P2 = P.copy()
    P2[:, :n] *= 1 + eps * 1e-6
    out.append(change("uniform growth of every link (thermal-like)", "ppm", H, P2, np.eye(3),
                      np.sum(P2[:, :n] - P[:, :n], axis=1), eps))
    return out


@dataclass
class _Day:
    """One recording's data and its linearisation at the current estimate (internal)."""

    name: str
    q: np.ndarray
    R: np.ndarray
    p: np.ndarray
    groups: np.ndarray
    delta: np.ndarray = field(default_factory=lambda: np.zeros(12))
    sigma: tuple[float, float] = (1.0, 1.0 / rotation_residual_scale(DEFAULT_ORIENTATION_WEIGHT))

    @classmethod
    def of(cls, rec: Recording, name: str | None = None) -> _Day:
        return cls(name or rec.source, rec.q, rec.R, rec.p, rec.clusters())


class DaysProblem:
    """The shared arm and each recording's own arm, built once from the recordings, then solved.

    Args:
        nominal: the robot's nominal arm (with its tool marker).
        recs: two or more recordings of that robot.
        names: one label per recording (default: their sources).
        reach_mm: the reach that scales tilts and rotations to millimetres.
    """

    def __init__(self, nominal: PoeModel, recs: list[Recording], names: list[str] | None = None,
                 reach_mm: float = DEFAULT_REACH_MM) -> None:
        if len(recs) < 2:
            raise ModelError(f"comparing recordings needs at least two, got {len(recs)}")
        self.par = MinimalParameterisation(nominal)
        self.m = self.par.size
        frame = np.r_[np.ones(3), np.full(3, 1 / reach_mm)]
        self.scale = np.concatenate([self.par.scale(reach_mm), frame, frame])
        self.days = [_Day.of(r, n) for r, n in zip(recs, names or [r.source for r in recs])]
        self.names = self.par.names()

    # -- residuals and their linearisation ----------------------------------------------------------------------

    def residual(self, day: _Day, x: np.ndarray, delta: np.ndarray) -> np.ndarray:
        """Whitened residual rows (N, 6): position / sigma_p, rotation / sigma_r."""
        R, p = self.par.pose(day.q, x)
        T_b, T_t = corrections(delta)
        R, p = wrap_pose(T_b, R, p, T_t)
        r, _ = weighted_residuals(day.R, day.p, R, p, day.sigma[0] / day.sigma[1])
        return r / day.sigma[0]

    def jacobian(self, day: _Day, x: np.ndarray, delta: np.ndarray) -> np.ndarray:
        """d residual / d (scaled x, scaled delta): (N, 6, m + 12). The arm's columns are analytic (the
        parameterisation's Jacobian carried through the frames), the frames' 12 by central differences."""
        R, p, J = self.par.jacobian(day.q, x)  # rows d[p; theta] / dx in the arm's base frame
        T_b, T_t = corrections(delta)
        R_b, p_t = T_b[:3, :3], T_t[:3, 3]
        Rw, pw = wrap_pose(T_b, R, p, T_t)
        w = day.sigma[0] / day.sigma[1]
        _, e = weighted_residuals(day.R, day.p, Rw, pw, w)
        lever = np.einsum("nij,j->ni", R, p_t)  # the marker's offset from the flange, in the arm's base frame
        dp = J[:, :3] - np.cross(lever[:, :, None], J[:, 3:], axis=1)
        Jk = np.empty_like(J)
        Jk[:, :3] = -np.einsum("ij,njk->nik", R_b, dp)
        Jk[:, 3:] = -w * (so3.right_jacobian_inv(e) @ np.einsum("ij,njk->nik", R_b, J[:, 3:]))
        Jk *= self.scale[:self.m] / day.sigma[0]
        cols = []
        for i in range(12):
            h = FD_STEP * self.scale[self.m + i]
            dp_, dm_ = delta.copy(), delta.copy()
            dp_[i] += h
            dm_[i] -= h
            cols.append((self.residual(day, x, dp_) - self.residual(day, x, dm_)) / (2 * FD_STEP))
        return np.concatenate([Jk, np.stack(cols, axis=-1)], axis=-1)

    def jacobian_fd(self, day: _Day, x: np.ndarray, delta: np.ndarray) -> np.ndarray:
        """:meth:`jacobian` by central differences in every column (the check of the analytic one)."""
        z = np.concatenate([x, delta])
        cols = []
        for i in range(z.size):
            h = FD_STEP * self.scale[i]
            zp, zm = z.copy(), z.copy()
            zp[i] += h
            zm[i] -= h
            cols.append((self.residual(day, zp[:self.m], zp[self.m:])
                         - self.residual(day, zm[:self.m], zm[self.m:])) / (2 * FD_STEP))
        return np.stack(cols, axis=-1)

    def reduced(self, day: _Day, x: np.ndarray) -> dict[str, np.ndarray]:
        """The frames-reduced linearisation of one recording at ``x`` and its frames: information ``A`` (m, m),
        gradient ``b`` (m,) (scaled), the frames' blocks, and per-cluster scores for the sandwich."""
        r = self.residual(day, x, day.delta)
        J = self.jacobian(day, x, day.delta)
        N = r.shape[0]
        Jf = J[..., self.m:].reshape(N * 6, 12)
        Jk = J[..., :self.m].reshape(N * 6, self.m)
        rv = r.reshape(N * 6)
        Aff_inv = np.linalg.pinv(Jf.T @ Jf, rcond=IDENTIFIED_TOLERANCE ** 2)
        Jt = Jk - Jf @ (Aff_inv @ (Jf.T @ Jk))  # kinematic columns with what the frames explain taken out
        rows = np.repeat(day.groups, 6)
        _, cl = np.unique(rows, return_inverse=True)
        scores_k = np.zeros((cl.max() + 1, self.m))
        np.add.at(scores_k, cl, Jt * rv[:, None])
        return {"A": Jt.T @ Jt, "b": -Jt.T @ rv, "Jf": Jf, "Jk": Jk, "r": rv, "Aff_inv": Aff_inv,
                "Bk": scores_k.T @ scores_k, "cl": cl, "res": r}

    def gauge(self, x: np.ndarray) -> np.ndarray:
        """Basis (m, g) of the scaled parameter directions that a frame change reproduces exactly, whatever the
        data: the null space of the frames-reduced information on a rich design (every joint over +-57 deg)."""
        rng = np.random.default_rng(0)
        q = rng.uniform(-1.0, 1.0, (GAUGE_POSES, self.m // 4))
        R, p = self.par.pose(q, x)
        A = self.reduced(_Day("rich design", q, R, p, np.arange(GAUGE_POSES)), x)["A"]
        w, V = np.linalg.eigh(A)
        return V[:, np.sqrt(np.clip(w, 0, None)) < GAUGE_TOLERANCE * np.sqrt(w.max())]

    def _frames_step(self, day: _Day, lin: dict[str, np.ndarray], dx_scaled: np.ndarray) -> None:
        g = -lin["Jf"].T @ (lin["r"] + lin["Jk"] @ dx_scaled)
        day.delta = day.delta + (lin["Aff_inv"] @ g) * self.scale[self.m:]

    # -- the fits -----------------------------------------------------------------------------------------------

    def fit_shared(self, x: np.ndarray) -> np.ndarray:
        """The shared arm (scaled steps by the pooled pseudo-inverse; each recording's frames follow)."""
        for _ in range(SHARED_ITERATIONS):
            lins = [self.reduced(d, x) for d in self.days]
            A = sum(lin["A"] for lin in lins)
            dz = np.linalg.pinv(A, rcond=IDENTIFIED_TOLERANCE ** 2, hermitian=True) @ sum(lin["b"] for lin in lins)
            for d, lin in zip(self.days, lins):
                self._frames_step(d, lin, dz)
            x = x + dz * self.scale[:self.m]
            if np.max(np.abs(dz)) < 1e-6:
                break
        return x

    def fit_own(self, day: _Day, x_shared: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray], np.ndarray]:
        """One recording's own arm from the shared one, along its identified directions: (x, linearisation, U)."""
        x = x_shared.copy()
        for _ in range(OWN_ITERATIONS):
            lin = self.reduced(day, x)
            U = identified(lin["A"])
            dz = U @ np.linalg.solve(U.T @ lin["A"] @ U, U.T @ lin["b"])
            self._frames_step(day, lin, dz)
            x = x + dz * self.scale[:self.m]
        lin = self.reduced(day, x)
        return x, lin, identified(lin["A"])

    def solve(self) -> DaysResult:
        """Shared arm, noise floors, own arms, tests (see the module docstring)."""
        x = self.fit_shared(np.zeros(self.m))
        for d in self.days:  # each recording's own-fit noise floors, then everything again whitened by them
            d.sigma = _sigmas(self, d, self.fit_own(_copy(d), x)[1]["res"], d.sigma)
        x = self.fit_shared(x)
        own = [self.fit_own(d, x) for d in self.days]
        return DaysResult.build(self, x, own)


def _copy(day: _Day) -> _Day:
    return _Day(day.name, day.q, day.R, day.p, day.groups, day.delta.copy(), day.sigma)


def _sigmas(problem: DaysProblem, day: _Day, res: np.ndarray, sigma: tuple[float, float]) -> tuple[float, float]:
    """Per-axis noise (mm, rad) from a whitened own-fit residual: the fit-residual floors of each channel."""
    raw = np.concatenate([res[:, :3] * sigma[0], res[:, 3:] * sigma[1]], axis=1)  # mm, rad
    floor = noise_floor(raw, day.groups, problem.m + 12, w_rot=1.0)
    return floor.fit_residual_mm / np.sqrt(3), np.radians(floor.fit_residual_deg) / np.sqrt(3)


def identified(A: np.ndarray) -> np.ndarray:
    """Orthonormal basis (m, k) of the directions information ``A`` identifies (``IDENTIFIED_TOLERANCE``)."""
    w, V = np.linalg.eigh(A)
    keep = np.sqrt(np.clip(w, 0, None)) >= IDENTIFIED_TOLERANCE * np.sqrt(max(w.max(), 1e-300))
    return V[:, keep]


def share_in(W: np.ndarray, G: np.ndarray, v: np.ndarray) -> float:
    """Share (squared norm) of ``v``'s part outside the gauge ``G`` that lies in the directions ``W``."""
    rest = v - G @ (G.T @ v)
    n2 = float(rest @ rest)
    if n2 <= GAUGE_RESIDUE * float(v @ v) or n2 <= 1e-24:  # a frame change does it (joint 1's or 6's offset)
        return 0.0
    return float(np.sum((W.T @ rest) ** 2) / n2)


def sparsest(d: np.ndarray, G: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The description of a parameter difference ``d`` (scaled) that changes the fewest millimetres in total.

    ``d`` is known up to the gauge ``G`` (what a frame change does exactly), so "which parameters differ" needs a
    convention: the one of least L1 norm, ``min |d + G g|_1`` (a single moved joint origin stays a single moved
    origin instead of spreading over every origin). It zeroes ``G.shape[1]`` coordinates (the ones the frames carry
    instead); the map onto it is linear, ``T = I - G (G_S)^-1 E_S``, so covariances follow.

    Returns:
        ``T`` (m, m) and the zeroed coordinates ``S``.
    """
    from scipy.optimize import linprog

    m, k = G.shape
    if k == 0:
        return np.eye(m), np.zeros(0, dtype=int)
    # variables [g (k), t (m)]: minimise sum t with -t <= d + G g <= t
    c = np.r_[np.zeros(k), np.ones(m)]
    A = np.block([[G, -np.eye(m)], [-G, -np.eye(m)]])
    b = np.r_[-d, d]
    sol = linprog(c, A_ub=A, b_ub=b, bounds=[(None, None)] * k + [(0, None)] * m, method="highs")
    g = sol.x[:k] if sol.success else -np.linalg.lstsq(G, d, rcond=None)[0]
    S = np.sort(np.argsort(np.abs(d + G @ g))[:k])
    if np.linalg.matrix_rank(G[S]) < k:  # not a vertex: the k coordinates the gauge moves most independently
        from scipy.linalg import qr

        S = np.sort(qr(G.T, pivoting=True)[2][:k])
    T = np.eye(m) - G @ np.linalg.solve(G[S], np.eye(m)[S])
    return T, S


def pose_overlap(q_a: np.ndarray, q_b: np.ndarray) -> float:
    """Share of the poses of each recording within ``POSE_MATCH_DEG`` (every joint) of a pose of the other, the
    smaller of the two."""
    from scipy.spatial import cKDTree

    tol = np.radians(POSE_MATCH_DEG)
    a_in_b = np.mean(cKDTree(q_b).query(q_a, p=np.inf)[0] <= tol)
    b_in_a = np.mean(cKDTree(q_a).query(q_b, p=np.inf)[0] <= tol)
    return float(min(a_in_b, b_in_a))


def common(U1: np.ndarray, U2: np.ndarray) -> np.ndarray:
    """The directions both bases span (principal angles under ~25 deg)."""
    w, V = np.linalg.eigh(0.5 * (U1 @ U1.T + U2 @ U2.T))
    return V[:, w > 0.95]


def covariance(A: np.ndarray, B: np.ndarray, U: np.ndarray, n_clusters: int) -> np.ndarray:
    """Covariance (m, m, scaled) of the directions ``U`` from information ``A`` and cluster scores ``B``: the
    cluster-robust sandwich ``A^+ B A^+`` when there are ``CLUSTERS_PER_DIRECTION`` clusters per direction or
    more, else ``A^+`` (the residuals are whitened by the noise floors; a sandwich over few clusters is
    singular and would call noise a difference)."""
    Ainv = U @ np.linalg.solve(U.T @ A @ U, U.T)
    return Ainv @ B @ Ainv if n_clusters >= CLUSTERS_PER_DIRECTION * U.shape[1] else Ainv


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
            shown = sorted((f for f in self.frames if f.value is not None), key=lambda f: -abs(f.value / f.se))[:3]
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


@dataclass(frozen=True)
class DaysResult:
    """Outcome of :meth:`DaysProblem.solve`.

    Attributes:
        reference: the first recording's name (frames and kinematics are compared with it).
        shared: the shared arm's parameters (names -> value, units in the names) and their standard errors.
        days: each other recording against the reference.
        pairs: the joint kinematic test of every pair of recordings (i, j, test).
        pair_overlap: per pair, the share of poses the two recordings share (:func:`pose_overlap`).
        unidentified: parameters no recording identifies (the frames' gauge or data that never move them).
        deltas: each recording's 12 frame corrections against the shared arm (:func:`calibration.rebase.corrections`).
        drift: the late half against the early half of each recording with time order (:func:`compare_days`).
        drift_note: why drift was not tested, when it was not.
    """

    reference: str
    names: tuple[str, ...]
    shared: dict[str, tuple[float, float | None]]
    days: tuple[DayDiff, ...]
    pairs: tuple[tuple[str, str, Test], ...]
    unidentified: tuple[str, ...]
    deltas: tuple[np.ndarray, ...] = ()
    pair_overlap: tuple[float, ...] = ()
    drift: tuple[DayDiff, ...] = ()
    drift_note: str = ""

    @classmethod
    def build(cls, problem: DaysProblem, x: np.ndarray, own: list[tuple[np.ndarray, dict, np.ndarray]]
              ) -> DaysResult:
        D = len(own)
        sm = problem.scale[:problem.m]
        covs = [covariance(lin["A"], lin["Bk"], U, lin["cl"].max() + 1) for _, lin, U in own]
        named = named_changes(problem.par.nominal)
        n_tests = max(D - 1, 1) * (problem.m + 12 + len(named))
        z_crit = float(-special.ndtri(ALPHA / (2 * n_tests)))
        alpha_joint = ALPHA / max(D - 1, 1)
        ref_x, _, ref_U = own[0]
        pooled_A = sum(lin["A"] for _, lin, _ in own)
        G = problem.gauge(x)
        days = []
        for (x_d, lin, U), C, day in zip(own[1:], covs[1:], problem.days[1:]):
            days.append(_compare(problem, day, x_d, U, C, ref_x, ref_U, covs[0], problem.days[0], own[0][1], lin,
                                 named, G, z_crit, alpha_joint))
        pairs = []
        for i in range(D):
            for j in range(i + 1, D):
                W = common(own[i][2], own[j][2])
                d = W.T @ ((own[j][0] - own[i][0]) / sm)
                pairs.append((problem.days[i].name, problem.days[j].name,
                              Test.of(d, W.T @ (covs[i] + covs[j]) @ W, ALPHA / max(D * (D - 1) // 2, 1))))
        Up = identified(pooled_A)
        Cp = np.linalg.pinv(pooled_A, rcond=IDENTIFIED_TOLERANCE ** 2, hermitian=True)
        share = np.array([share_in(Up, G, e) for e in np.eye(problem.m)])
        shared = {n: (float(x[i]), float(np.sqrt(Cp[i, i]) * sm[i]) if share[i] >= IDENTIFIED_SHARE else None)
                  for i, n in enumerate(problem.names)}
        unid = tuple(n for n, s in zip(problem.names, share) if s < IDENTIFIED_SHARE)
        overlap = tuple(pose_overlap(problem.days[i].q, problem.days[j].q) for i in range(D) for j in range(i + 1, D))
        return cls(problem.days[0].name, tuple(d.name for d in problem.days), shared, tuple(days), tuple(pairs), unid,
                   tuple(d.delta.copy() for d in problem.days), overlap)

    @property
    def kinematics_changed(self) -> bool:
        return any(d.kinematics_differ for d in self.days)

    def summary(self) -> str:
        lines = [f"What differs between {len(self.names)} recordings (against {self.reference}; tests at a "
                 f"family-wise {ALPHA:g}, cluster-robust noise):"]
        lines += [d.summary(self.reference) for d in self.days]
        agree = [f"{a} ~ {b}" for a, b, t in self.pairs if not t.differs]
        same = [f"{a} / {b}: {'differ' if t.differs else 'agree'} (chi2 {t.chi2:.0f} over {t.dof})"
                for (a, b, t), o in zip(self.pairs, self.pair_overlap) if o >= SAME_POSES]
        if same:
            lines.append("  kinematics of recordings on the same poses (no pose-dependent confound): "
                         + "; ".join(same))
        if len(self.pairs) > len(self.days):
            lines.append("  pairs whose kinematics agree: " + (", ".join(agree) or "none"))
        if self.unidentified:
            lines.append(f"  unidentified by every recording (absorbed by the frames or never moved): "
                         f"{', '.join(self.unidentified)}")
        for d in self.drift:
            lines.append("  drift within a recording (late half against early half): " + d.summary("its early half")
                         .strip())
        if self.drift_note:
            lines.append(f"  drift within a recording: {self.drift_note}")
        lines.append("Significance: the arm's own kinematic parameters differ between recordings beyond the "
                     "measurement noise." if self.kinematics_changed else
                     "Significance: the arm's own kinematic parameters are the same within the measurement noise; "
                     "the frames carry the differences.")
        return "\n".join(lines)

    def to_json(self) -> dict[str, Any]:
        return {"reference": self.reference, "recordings": list(self.names), "alpha": ALPHA,
                "identified_tolerance": IDENTIFIED_TOLERANCE, "identified_share": IDENTIFIED_SHARE,
                "shared_parameters": {n: {"value": float(f"{v:.6g}"), "se": None if s is None else float(f"{s:.3g}")}
                                      for n, (v, s) in self.shared.items()},
                "unidentified": list(self.unidentified), "days": [d.to_json() for d in self.days],
                "pairs": [{"a": a, "b": b, **t.to_json(), "pose_overlap": round(o, 3)} for (a, b, t), o in
                          zip(self.pairs, self.pair_overlap)],
                "kinematics_changed": bool(self.kinematics_changed),
                "drift": {"tested": bool(self.drift), "note": self.drift_note,
                          "halves": [d.to_json() for d in self.drift]}}


def _compare(problem: DaysProblem, day: _Day, x_d: np.ndarray, U_d: np.ndarray, C_d: np.ndarray, x_r: np.ndarray,
             U_r: np.ndarray, C_r: np.ndarray, ref: _Day, lin_r: dict, lin_d: dict, named: list[Named],
             G: np.ndarray, z_crit: float, alpha: float) -> DayDiff:
    sm = problem.scale[:problem.m]
    W = common(U_d, U_r)
    dz = (x_d - x_r) / sm
    dW, VW = W.T @ dz, W.T @ (C_d + C_r) @ W
    kin_test = Test.of(dW, VW, alpha)
    share = [share_in(W, G, e) for e in np.eye(problem.m)]
    T, pinned = sparsest(W @ dW, G)
    dproj, V = T @ (W @ dW), T @ W @ VW @ W.T @ T.T
    for i in pinned:  # the frames carry these in the sparsest description
        share[i] = 0.0
    params = []
    for i, n in enumerate(problem.names):
        unit = "mm" if n.endswith("_mm") else "rad"
        if share[i] < IDENTIFIED_SHARE:
            params.append(Quantity(n, unit, None, None, False, float(share[i])))
            continue
        se = float(np.sqrt(V[i, i]))
        params.append(Quantity(n, unit, float(dproj[i] * sm[i]), se * sm[i], abs(dproj[i]) > z_crit * se,
                               float(share[i])))
    testable = [k for k, nm in enumerate(named) if share_in(W, G, nm.direction / sm) >= IDENTIFIED_SHARE]
    found, rest, alternatives = _name(named, sm, W, testable, dW, VW, z_crit)
    # the frames net of what the named changes bring with them: their tool part, and the part of each change
    # outside the directions this recording's arm moves along, which its frames took up
    explained = np.zeros(12)
    for k, value, _ in found:
        v = named[k].direction / sm
        outside = v - U_d @ (U_d.T @ v)
        explained += value * (np.r_[np.zeros(6), named[k].tool] / problem.scale[problem.m:]
                              + lin_d["Aff_inv"] @ (lin_d["Jf"].T @ (lin_d["Jk"] @ outside)))
    frames, frames_test = _frames(problem, day, ref, lin_d, lin_r, U_d, U_r, z_crit, alpha, explained)
    return DayDiff(day.name, day.q.shape[0], day.sigma[0] * np.sqrt(3), float(np.degrees(day.sigma[1]) * np.sqrt(3)),
                   frames, frames_test, tuple(params), kin_test,
                   tuple(Quantity(named[k].name, named[k].unit, v, se, True, 1.0) for k, v, se in found), rest,
                   alternatives, pose_overlap(day.q, ref.q))


def _name(named: list[Named], sm: np.ndarray, W: np.ndarray, testable: list[int], d: np.ndarray, V: np.ndarray,
          z_crit: float
          ) -> tuple[list[tuple[int, float, float]], Test, tuple[str, ...]]:
    """Named changes that explain ``d`` (coordinates on the common directions ``W``), and the test of what remains.

    The fewest changes (up to ``MAX_NAMED``) whose remainder is within the noise, the best such set; when no set
    is, the largest set each of whose changes still cuts the chi-square by ``z_crit**2``. Only the ``testable``
    changes are tried (joint 1's offset is the base frame's rotation, joint 6's the tool frame's). Returns (index
    into ``named``, value, standard error) per change found, the test of the remainder,
    and up to three other sets (of the same size or one more) that explain it as well: the data cannot tell them apart.
    """
    from itertools import combinations

    M = np.linalg.inv(V)
    scaled = [nm.direction / sm for nm in named]
    K_all = np.stack([W.T @ v for v in scaled], axis=1)

    def fit(sel: tuple[int, ...]) -> tuple[float, np.ndarray, np.ndarray]:
        if not sel:
            return float(d @ M @ d), np.zeros(0), np.zeros((0, 0))
        K = K_all[:, list(sel)]
        F = K.T @ M @ K
        c = np.linalg.solve(F, K.T @ M @ d)
        e = d - K @ c
        return float(e @ M @ e), c, np.linalg.inv(F)

    def within(chi2: float, k: int) -> bool:
        dof = d.size - k
        return dof <= 0 or chi2 <= special.chdtri(dof, ALPHA)

    best: list[tuple[float, tuple[int, ...]]] = [(fit(())[0], ())]
    for k in range(1, min(MAX_NAMED, len(testable)) + 1):
        best.append(min((fit(sel)[0], sel) for sel in combinations(testable, k)))
    chosen = next((sel for chi2, sel in best if within(chi2, len(sel))), None)
    if chosen is None:
        k = 0
        while k + 1 < len(best) and best[k][0] - best[k + 1][0] >= z_crit ** 2:
            k += 1
        chosen = best[k][1]
    chi2, coef, cov = fit(chosen)
    dof = d.size - len(chosen)
    p = float(special.chdtrc(dof, chi2)) if dof > 0 else 1.0
    others = sorted((fit(sel)[0], sel) for k in {len(chosen), len(chosen) + 1} if 0 < k <= MAX_NAMED
                    for sel in combinations(testable, k)
                    if not set(chosen) <= set(sel) and within(fit(sel)[0], k))  # a superset adds nothing
    alternatives = (tuple(" + ".join(named[k].name for k in sel) for _, sel in others[:3])
                    if within(chi2, len(chosen)) else ())
    return ([(k, float(coef[i]), float(np.sqrt(cov[i, i]))) for i, k in enumerate(chosen)],
            Test(chi2, dof, p, bool(not within(chi2, len(chosen)))), alternatives)


def _frames(problem: DaysProblem, day: _Day, ref: _Day, lin_d: dict, lin_r: dict, U_d: np.ndarray,
            U_r: np.ndarray, z_crit: float, alpha: float, explained: np.ndarray) -> tuple[tuple[Quantity, ...], Test]:
    """The frame corrections of ``day`` against the reference's, net of ``explained`` (scaled), per component, with
    sandwich errors."""
    sf = problem.scale[problem.m:]
    covs, Us = [], []
    for lin, U_k in ((lin_d, U_d), (lin_r, U_r)):  # marginal over the arm's own directions, not given them
        Jz = np.concatenate([lin["Jk"] @ U_k, lin["Jf"]], axis=1)
        scores = np.zeros((lin["cl"].max() + 1, Jz.shape[1]))
        np.add.at(scores, lin["cl"], Jz * lin["r"][:, None])
        C = covariance(Jz.T @ Jz, scores.T @ scores, np.eye(Jz.shape[1]), lin["cl"].max() + 1)
        Ainv = np.linalg.inv(Jz.T @ Jz)
        C = C[-12:, -12:]
        covs.append(C)
        Us.append(identified(np.linalg.pinv(Ainv[-12:, -12:], hermitian=True)))  # the frames' marginal information
    W = common(*Us)
    dz = (day.delta - ref.delta) / sf - explained
    dW, VW = W.T @ dz, W.T @ (covs[0] + covs[1]) @ W
    V, dproj, share = W @ VW @ W.T, W @ dW, np.sum(W ** 2, axis=1)
    out = []
    for i, (name, unit) in enumerate(zip(DIRECTION_NAMES, FRAME_UNITS)):
        conv = 1.0 if unit == "mm" else np.degrees(1.0)
        if share[i] < IDENTIFIED_SHARE:
            out.append(Quantity(name, unit, None, None, False, float(share[i])))
            continue
        se = float(np.sqrt(V[i, i]))
        out.append(Quantity(name, unit, float(dproj[i] * sf[i] * conv), se * sf[i] * conv,
                            abs(dproj[i]) > z_crit * se, float(share[i])))
    return tuple(out), Test.of(dW, VW, alpha)


def check_same_robot(nominal: PoeModel, recs: list[Recording], robot: str) -> None:
    """Refuse a recording that is not of ``robot``: its nominal arm with both frames fitted still misses by more
    than ``OTHER_ROBOT_MM`` on average.

    Raises:
        DataError: the first such recording.
    """
    from calibration.frames import fit_frames
    from calibration.models import ConstantModel

    model = ConstantModel(robot, "nominal", nominal, 0, {})
    for r in recs:
        fit = fit_frames(model, r)
        if fit.mean_after_mm > OTHER_ROBOT_MM:
            raise DataError(r.source, None, None, f"the nominal {robot} with its frames fitted still misses this "
                                                  f"recording by {fit.mean_after_mm:.1f} mm on average (more than "
                                                  f"{OTHER_ROBOT_MM:g} mm): not a recording of {robot}?")


def halves(rec: Recording, column: str) -> tuple[Recording, Recording]:
    """Early and late halves of ``rec`` by ``column`` (whole clusters, split at the median of their means)."""
    c = rec.clusters()
    ids, inv = np.unique(c, return_inverse=True)
    mean = np.bincount(inv, rec.extra[column]) / np.bincount(inv)
    late = mean[inv] > np.median(mean)
    return rec.subset(~late), rec.subset(late)


def day_names(sources: list[str]) -> list[str]:
    """Short names of recordings for the messages: each one's file or folder name (``test0801_R1``), or the
    sources as given when two share a name."""
    short = [Path(s).name or str(s) for s in sources]
    return short if len(set(short)) == len(short) else [str(s) for s in sources]


def compare_days(nominal: PoeModel, recs: list[Recording], names: list[str] | None = None) -> DaysResult:
    """What differs between ``recs`` (see the module docstring), with the drift within each recording that
    carries time order (``t``, else ``temp_c``)."""
    result = DaysProblem(nominal, recs, names).solve()
    drift, untested = [], []
    for r, name in zip(recs, result.names):
        column = next((c for c in ("t", "temp_c") if c in r.extra), None)
        if column is None:
            untested.append(name)
            continue
        early, late = halves(r, column)
        if len(early) == 0 or len(late) == 0:
            untested.append(name)
            continue
        half = DaysProblem(nominal, [early, late], [f"{name} early ({column})", f"{name} late ({column})"]).solve()
        drift.extend(half.days)
    note = (f"not tested on {', '.join(untested)}: no t or temp_c column (the recording format's time order)"
            if untested else "")
    return replace(result, drift=tuple(drift), drift_note=note)
