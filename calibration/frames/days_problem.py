"""The joint problem of several days: one shared arm, each day's own frames and what differs, solved with the
noise floors of each day's own fit (:class:`DaysProblem`); :mod:`calibration.frames.daydiff` turns the solution
into tests."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calibration.data.recording import Recording
from calibration.diagnosis.noise import noise_floor
from calibration.errors import ModelError
from calibration.frames.rebase import corrections
from calibration.identification import DEFAULT_ORIENTATION_WEIGHT, rotation_residual_scale
from calibration.identification.geometric import weighted_residuals
from calibration.identification.observability import DEFAULT_REACH_MM, DEFAULT_RELATIVE_TOLERANCE
from calibration.kinematics import so3
from calibration.kinematics.parameterisation import MinimalParameterisation
from calibration.kinematics.poe import PoeModel
from calibration.models.rebased import wrap_pose

#: A direction is identified by a recording when its singular value is at least this share of the largest.
IDENTIFIED_TOLERANCE = DEFAULT_RELATIVE_TOLERANCE


#: Directions of the parameters a frame change reproduces exactly (on any data): singular values below this share
#: of the largest on a rich design (:meth:`DaysProblem.gauge`; they are ~1e-8, the next ones ~4e-2).
GAUGE_TOLERANCE = 1e-5


#: Clusters per tested direction below which the covariance is the model's, not the cluster-robust sandwich.
CLUSTERS_PER_DIRECTION = 5


#: A direction whose part outside the gauge is below this share of it (squared norm) is a frame change (joint 1's
#: offset leaves ~1e-8, the next smallest named change 0.1).
GAUGE_RESIDUE = 1e-4


#: Poses of the rich design the gauge is found on.
GAUGE_POSES = 300


#: Gauss-Newton iterations of the shared arm and of each recording's own arm.
SHARED_ITERATIONS, OWN_ITERATIONS = 6, 3


#: Finite-difference step in scaled units (mm, or mrad at a 1 m reach).
FD_STEP = 1e-4


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


#: The frames-reduced linearisation of one recording (:meth:`DaysProblem.reduced`), arrays by name.
Reduced = dict[str, np.ndarray]


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

    def reduced(self, day: _Day, x: np.ndarray) -> Reduced:
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

    def solve(self) -> tuple[np.ndarray, list[tuple[np.ndarray, Reduced, np.ndarray]]]:
        """The shared arm ``x`` and each day's own fit, after the noise floors (see the module docstring);
        :func:`calibration.frames.daydiff.compare_days` builds the tests from them."""
        x = self.fit_shared(np.zeros(self.m))
        for d in self.days:  # each recording's own-fit noise floors, then everything again whitened by them
            d.sigma = _sigmas(self, d, self.fit_own(_copy(d), x)[1]["res"], d.sigma)
        x = self.fit_shared(x)
        own = [self.fit_own(d, x) for d in self.days]
        return x, own


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
