"""The options of a fit (:class:`FitOptions`): orientation weight, tolerances, the local prior and ridge grids, the
pi variants, the seed and whether gross rows are rejected."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from calibration.errors import ModelError
from calibration.identification import DEFAULT_ORIENTATION_WEIGHT
from calibration.identification.geometric import check_orientation_weight
from calibration.identification.observability import DEFAULT_RELATIVE_TOLERANCE
from calibration.physics.layout import check_registration_parts

#: The rules FitOptions.local_prior_rule names (implemented in calibration.methods.heldout.CHOICE_RULES).
LOCAL_PRIOR_RULES = ("one_se", "paired_one_se", "paired_two_se", "paired_three_se")


@dataclass(frozen=True)
class FitOptions:
    """Identification settings.

    Attributes:
        a: orientation weight (1641: 1 mm ~ 1 deg).
        tolerance: relative singular value below which a parameter direction counts as unobservable: held at
            its reference by nls0/nls1 (truncation), damped toward nominal by pi (Tikhonov filter at that cutoff).
        fit_tool: identify the flange-point shift too (3 parameters).
        local_prior: ridge strength of local cluster fits toward the pi reference geometry [1/mm-equivalent];
            None (default) chooses it from ``local_prior_grid`` on clusters held out from the training recording
            (the ``linear`` interpolator, one-standard-error rule toward the stronger prior) among the priors
            whose corrections over the workspace stay within ``workspace.WORKSPACE_RATIO_LIMIT`` times those on
            the training poses (the strongest when none does). 0.1 was the fixed value before.
        local_prior_grid: candidate local priors.
        local_prior_rule: how the held-out scores choose among them: ``one_se`` (default), the strongest prior
            within one standard error (each prior's own, over clusters) of the lowest held-out RMS; ``paired_one_se``,
            the same with the standard error of the paired difference to the lowest (the priors are scored on the
            same folds, so this is much smaller); ``paired_two_se``, ``paired_three_se``: within two or three paired
            standard errors; see :data:`calibration.methods.heldout.CHOICE_RULES` and
            ``scripts/studies/local_prior_rule.py``. Not the default (issue 31 part 4): on the simulated R2 the paired
            rules take 0.3 where ``one_se`` takes 1.0 (pi+fbf13 9.3 -> 10.5 % below pi on seed 1433846632, on 9
            other seeds -0.2 to +1.3 points), but ``paired_one_se`` also weakens the prior on 3 of the 7 R1 training
            recordings (0627 before, 0627 after, 0801), and that raised 9 of their 12 pi-based CDC test means (by up to
            5.2 %); ``paired_three_se`` changes no R1 choice, but its k was picked after seeing those R1 test rows.
        fourier_ridge_grid: candidate ridge strengths of fbf13/fbf7 (0 = the paper's least squares), chosen on
            held-out clusters by the same rule. It reaches 10 (times the basis Gram matrix's mean diagonal), where
            the fit is nearly the anchors' mean, so sparse anchors can always fall back to a smooth fit; strengths a
            fold cannot fit (ridge 0 with fewer than 13 anchors) are left out of the choice.
        nls0_clusters: number of clusters nearest q = 0 used by ``nls0``.
        nls0_damping: relative cutoff of ``nls0``'s Tikhonov filter toward nominal (the fraction of the largest
            scaled singular value below which directions are damped); None (default) chooses it from
            ``nls0_damping_grid`` on the training clusters nls0 does not use (see :func:`calibration.methods.constant.fit_nls0`).
        nls0_damping_grid: candidate cutoffs, half-decades from the truncation ``tolerance`` up.
        fbf7_rank: rank of the SVD-reduced Fourier basis.
        cluster_size: samples per anchor when the recording has no cluster column.
        pi_ae_hidden: encoder widths of ``pi+ae``'s autoencoder (the decoder mirrors them). Two layers of 128 since
            issue 14, a third of the training cost of the paper's three of 200
            (:data:`calibration.interpolation.autoencoder.PAPER_HIDDEN`, which ``pi_ae_hidden=PAPER_HIDDEN``
            restores), chosen on clusters held out from the 8 R1 training recordings (``scripts/studies/recommend_days.py``:
            the same recommendation, best method and flags on every day, pi+ae's held-out RMS within about one paired
            standard error over clusters). The paper's ``ae`` keeps the paper's network, as the paper defines it.
            ``pi+nn`` keeps the paper's ``nn`` network (three layers of 200, 300 epochs): two layers of 128 or of 200,
            or 200 epochs, each raised its held-out RMS on every R1 training recording it was run on (5, 7 and 8
            of them; by up to 0.015 mm) and lost it the recommendation on 4, 4 and 3 days
            (``scripts/studies/recommend_days.py --against``, issue 14), so its training time is not traded for ``compare``'s.
        pi_registration_free: which parts of the tool marker's registration on the flange the pi fit leaves out of
            its damping toward nominal (:meth:`ExtendedKinematics.registration_mask`): ``rotation`` (default), the
            tool-marker rotation, which every pose's orientation sees directly; ``shift``, ``all`` or ``none`` (the
            fit before). Chosen with ``scripts/studies/pi_registration.py``: on the synthetic twins of
            ``scripts/benchmarks/bench_frames.py`` (wrist held within 3 deg in training, turned widely on the held-out poses), a
            marker rotated 0.3 deg took a damped pi from 0.26 to 0.41 mm (one arm), a free rotation none of it; on
            the 8 R1 training recordings the free rotation lowers pi's held-out-cluster RMS on every day (by
            0.0001-0.0038 mm) and worsens no extrapolation fold's mean by more than 0.003 mm. Freeing the shift too makes pi immune to a shifted marker on the twins (3 mm:
            0.73 -> 0.25 mm on that arm), but costs 0.001-0.021 mm on the q2-edge folds of 7 of the 8 training days,
            so it is not the default.
        pi_base_free: when True, pi's damping toward nominal acts on its parameters less their best rigid motion of
            the arm (:func:`base_free_prior`), so a base-frame (mocap-to-base) error costs the fit nothing. Off by
            default: on the 8 R1 training recordings its held-out-cluster RMS is lower on 5 days (by 1-5 paired
            standard errors) and higher on 0627 before (by 5), and it worsens the mean of the step folds on 7 days and
            of the q2-edge folds on all 8, by 0.002-0.013 mm (``scripts/studies/pi_base_frame.py``), so a registered base is a
            good prior there. On the synthetic twins a base off by 1.5 mm / 0.1 deg takes the damped pi from 0.26 to
            0.74 mm and leaves the free one at 0.20 (R1 seed 1). The frames-first fit of a recording the frame check finds off turns it on
            (:func:`calibration.frames.check.base_free`).
        seed: random seed of the neural interpolators.
        reject_gross_rows: set aside the training rows whose error under the geometric fit is a gross measurement
            error (:func:`calibration.methods.heldout.gross_rows`: beyond 15 robust SDs of the median error and 1 mm / 1 deg),
            named in a warning and in every model's ``info`` (``Fitter.without_gross_rows``, which ``Fitter.for_arm``
            calls). Ten 50 mm marker swaps in 1736 rows had raised pi's test mean by 89 %.
        epoch_progress: called as ``epoch_progress(epoch, n_epochs)`` after each training epoch of the neural
            interpolators (nn, ae; a progress bar); no effect on any result.
    """

    a: float = DEFAULT_ORIENTATION_WEIGHT
    tolerance: float = DEFAULT_RELATIVE_TOLERANCE
    fit_tool: bool = True
    local_prior: float | None = None
    local_prior_grid: tuple[float, ...] = (0.1, 0.3, 1.0, 3.0, 10.0)
    local_prior_rule: str = "one_se"
    fourier_ridge_grid: tuple[float, ...] = (0.0, 1e-3, 1e-2, 1e-1, 1.0, 10.0)
    nls0_clusters: int = 9
    nls0_damping: float | None = None
    nls0_damping_grid: tuple[float, ...] = (0.01, 0.03, 0.1, 0.3, 1.0)
    fbf7_rank: int = 7
    cluster_size: int = 7
    pi_ae_hidden: tuple[int, ...] = (128, 128)
    pi_registration_free: str = "rotation"
    pi_base_free: bool = False
    seed: int = 0
    epoch_progress: Callable[[int, int], None] | None = field(default=None, compare=False)
    reject_gross_rows: bool = True

    def __post_init__(self) -> None:

        check_orientation_weight(self.a, "orientation weight a (--a)")
        check_registration_parts(self.pi_registration_free, "pi_registration_free")
        if self.local_prior_rule not in LOCAL_PRIOR_RULES:
            raise ModelError(f"unknown local_prior_rule {self.local_prior_rule!r}; valid: {', '.join(LOCAL_PRIOR_RULES)}")
        if self.pi_base_free and not self.fit_tool:
            raise ModelError("pi_base_free needs fit_tool: without the flange-point shift the geometry cannot "
                             "follow a rigid motion of the arm")
