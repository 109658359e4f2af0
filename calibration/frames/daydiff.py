"""What differs between recordings (days) of one arm: frames, kinematic parameters, named physical changes.

Model, for the poses of recording ``d`` (poses in millimetres)::

    T_meas ~= T_base(delta_d) @ T_arm(q; x) @ T_tool(delta_d)

``x`` are the minimal POE parameters (:class:`calibration.kinematics.parameterisation.MinimalParameterisation`, the
deviations from the nominal arm) and ``delta_d`` the 12 frame corrections of :func:`calibration.frames.rebase.corrections`
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
4. **Tests** against the first recording (the reference, as in :mod:`calibration.frames.multiday`), each recording
   independent: ``d = x_day - x_ref`` on the directions both identify, covariance ``C_day + C_ref``; a joint
   chi-square over those directions and a z per parameter whose direction both identify (at least
   ``IDENTIFIED_SHARE`` of it), at a family-wise level ``ALPHA`` (Bonferroni over recordings and parameters).
   Frames likewise, per component. Every pair of recordings gets the joint test too (who agrees with whom).
5. **Named changes**: the difference is explained greedily by physical directions (a joint's zero offset, a
   link's length, a uniform growth of every link, the way heat would act) while one still reduces the chi-square
   significantly; what remains beyond the noise is reported as unexplained.
6. **Drift within a recording**: only when it carries time order (``t`` or ``temp_c``, see
   ``docs/formats/recording.md``): its early and late halves (whole clusters) are compared the same way.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, cast

import numpy as np
from scipy import special  # not scipy.stats: its import costs ~1 s per command (the same values, bit for bit)

from calibration.data.recording import Recording
from calibration.errors import DataError
from calibration.frames.check import fit_frames
from calibration.frames.day_tests import SAME_POSES, DayDiff, Quantity, Test, pose_overlap
from calibration.frames.days_problem import (
    IDENTIFIED_TOLERANCE,
    DaysProblem,
    Named,
    Reduced,
    _Day,
    common,
    covariance,
    identified,
    named_changes,
    share_in,
    sparsest,
)
from calibration.frames.rebase import DIRECTION_NAMES
from calibration.kinematics.poe import PoeModel
from calibration.models import ConstantModel

#: A parameter (or named change) is tested when at least this share of it (squared norm) lies in the directions
#: both recordings identify; otherwise it is reported as unidentified.
IDENTIFIED_SHARE = 0.5
#: Family-wise false-alarm level of the tests (Bonferroni over recordings and the parameters tested).
ALPHA = 0.01
#: A recording whose nominal arm, with its frames fitted, still misses by more than this mean [mm] is not a
#: recording of this robot (the shared R1 days leave 0.3-0.6 mm; another arm's link lengths leave centimetres).
OTHER_ROBOT_MM = 5.0
#: Most named changes tried together on one recording.
MAX_NAMED = 3
#: Units the 12 frame corrections are reported in (shifts mm, rotations deg).
FRAME_UNITS = ("mm",) * 3 + ("deg",) * 3 + ("mm",) * 3 + ("deg",) * 3


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
        deltas: each recording's 12 frame corrections against the shared arm (:func:`calibration.frames.rebase.corrections`).
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
    def build(cls, problem: DaysProblem, x: np.ndarray, own: list[tuple[np.ndarray, Reduced, np.ndarray]]
              ) -> DaysResult:
        D = len(own)
        sm = problem.scale[:problem.m]
        covs = [covariance(lin["A"], lin["Bk"], U, lin["cl"].max() + 1) for _, lin, U in own]
        named = named_changes(problem.par.nominal)
        n_tests = max(D - 1, 1) * (problem.m + 12 + len(named))
        z_crit = float(-special.ndtri(ALPHA / (2 * n_tests)))
        alpha_joint = ALPHA / max(D - 1, 1)
        ref_x, _, ref_U = own[0]
        pooled_A = cast(np.ndarray, sum(lin["A"] for _, lin, _ in own))  # not the empty sum 0: two recordings or more
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
             U_r: np.ndarray, C_r: np.ndarray, ref: _Day, lin_r: Reduced, lin_d: Reduced, named: list[Named],
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


def _frames(problem: DaysProblem, day: _Day, ref: _Day, lin_d: Reduced, lin_r: Reduced, U_d: np.ndarray,
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
    result = _solved(DaysProblem(nominal, recs, names))
    drift: list[DayDiff] = []
    untested: list[str] = []
    for r, name in zip(recs, result.names):
        column = next((c for c in ("t", "temp_c") if c in r.extra), None)
        if column is None:
            untested.append(name)
            continue
        early, late = halves(r, column)
        if len(early) == 0 or len(late) == 0:
            untested.append(name)
            continue
        half = _solved(DaysProblem(nominal, [early, late], [f"{name} early ({column})", f"{name} late ({column})"]))
        drift.extend(half.days)
    note = (f"not tested on {', '.join(untested)}: no t or temp_c column (the recording format's time order)"
            if untested else "")
    return replace(result, drift=tuple(drift), drift_note=note)


def _solved(problem: DaysProblem) -> DaysResult:
    """The problem solved, as a result (the problem module does not know the result type)."""
    x, own = problem.solve()
    return DaysResult.build(problem, x, own)
