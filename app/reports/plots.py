"""The report's plots (matplotlib, Agg): one fixed style per method, error over the workspace, error CDFs,
the Fourier model's spectrum and its correction over (q2, q3).

Every axis carries a label with its unit. Each method of :data:`calibration.method_names.METHODS` has its own
colour, line style and marker (:data:`METHOD_STYLES`), so 15 methods stay apart in one legend; other rows
(a model file, "candidate", "in service") take the extra styles in order.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from calibration.data.files import atomic_open
from calibration.evaluation.metrics import Errors


@dataclass(frozen=True)
class Style:
    """How one method is drawn."""

    color: str
    linestyle: Any
    marker: str


#: One style per method; every colour differs (nominal is black, fbf7 purple).
METHOD_STYLES: dict[str, Style] = {
    "nominal": Style("#000000", "-", "o"), "base": Style("#7f7f7f", "--", "s"),
    "cpa": Style("#bcbd22", "-.", "^"), "nls0": Style("#17becf", ":", "v"),
    "nls1": Style("#1f77b4", "-", "D"), "nearest": Style("#9ecae1", "--", "<"),
    "linear": Style("#ff7f0e", "-.", ">"), "cubic": Style("#fdae6b", ":", "p"),
    "rbf": Style("#2ca02c", "-", "*"), "fbf13": Style("#d62728", "-", "h"),
    "fbf7": Style("#9467bd", "--", "X"), "nn": Style("#8c564b", "-.", "P"),
    "ae": Style("#e377c2", ":", "d"), "pi": Style("#74c476", "--", "8"),
    "diagnosed": Style("#393b79", "-.", "H"),
}
# The CDC methods built on pi: the marker of the paper's construction of the same interpolator, a short dash and
# a colour of their own.
METHOD_STYLES.update({f"pi+{k}": Style(c, (0, (2, 2)), METHOD_STYLES[k].marker) for k, c in zip(
    ("nearest", "linear", "cubic", "rbf", "fbf13", "fbf7", "nn", "ae"),
    ("#843c39", "#ad494a", "#d6616b", "#7b4173", "#a55194", "#ce6dbd", "#637939", "#8ca252"))})
_EXTRA_STYLES = (Style("#636363", (0, (5, 1, 1, 1)), "x"), Style("#e6550d", (0, (1, 1)), "+"),
                 Style("#3182bd", (0, (3, 1, 1, 1, 1, 1)), "1"), Style("#31a354", (0, (6, 2)), "2"))


def method_style(name: str, extra_index: int = 0) -> Style:
    """The style of a method; a row that is no method gets the ``extra_index``-th extra style."""
    return METHOD_STYLES.get(name) or _EXTRA_STYLES[extra_index % len(_EXTRA_STYLES)]


def styles_for(names: list[str]) -> dict[str, Style]:
    """A style for each row name, the non-methods taking the extra styles in order."""
    out, k = {}, 0
    for n in names:
        if n in METHOD_STYLES:
            out[n] = METHOD_STYLES[n]
        else:
            out[n] = method_style(n, k)
            k += 1
    return out


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig: Any, path: Path) -> Path:
    """Save a matplotlib figure as PNG (tight layout, 110 dpi), atomically, and close it."""
    plt = _pyplot()
    try:
        if fig.get_layout_engine() is None:
            fig.tight_layout()
        with atomic_open(path, binary=True) as f:
            fig.savefig(f, format="png", dpi=110)
    finally:
        plt.close(fig)
    return path


def workspace_figure(errs: dict[str, Errors], p_mm: np.ndarray, tolerance_mm: float | None = None,
                     highlight: str | None = None) -> Any:
    """Position error over the workspace: measured tool x against height z, one panel per row, shared colours.

    Args:
        errs: row name -> errors on the poses ``p_mm``.
        p_mm: measured tool-marker positions in the robot base frame [mm], shape (N, 3).
        tolerance_mm: drawn as a tick on the colour bar when given.
        highlight: the row whose panel is framed and titled "(recommended)".
    """
    plt = _pyplot()
    names = list(errs)
    cols = min(5, len(names))
    rows = -(-len(names) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(3.1 * cols + 1.2, 2.9 * rows), squeeze=False,
                             sharex=True, sharey=True, layout="constrained")
    from matplotlib.colors import LogNorm

    every = np.concatenate([np.asarray(e.position_mm) for e in errs.values()])
    vmax = float(np.max(every)) if np.max(every) > 0 else 1.0
    positive = every[every > 0]
    vmin = max(float(np.min(positive)) if len(positive) else vmax / 1e3, vmax / 1e3)
    norm = LogNorm(vmin=vmin, vmax=max(vmax, vmin * 1.01))  # errors span decades: nominal mm, CDC tens of um
    for ax, n in zip(axes.flat, names):
        sc = ax.scatter(p_mm[:, 0], p_mm[:, 2], c=np.clip(errs[n].position_mm, vmin, None), s=9, cmap="viridis",
                        norm=norm)
        ax.set_title(f"{n} (recommended)" if n == highlight else n, fontsize=9,
                     fontweight="bold" if n == highlight else "normal")
        if n == highlight:
            for spine in ax.spines.values():
                spine.set_color("#e0b000")
                spine.set_linewidth(2.5)
        ax.grid(alpha=0.3)
    for ax in axes.flat[len(names):]:
        ax.remove()
    for k, ax in enumerate(axes.flat[:len(names)]):
        if k >= len(names) - cols:
            ax.set_xlabel("tool x in the base frame [mm]")
            ax.xaxis.set_tick_params(labelbottom=True)
        if k % cols == 0:
            ax.set_ylabel("tool height z [mm]")
    bar = fig.colorbar(sc, ax=list(axes.flat[:len(names)]), shrink=0.9)
    bar.set_label("position error [mm] (log scale)")
    if tolerance_mm is not None and vmin <= tolerance_mm <= vmax:
        bar.ax.axhline(tolerance_mm, color="r", lw=1.5)
    return fig


def cdf_figure(errs: dict[str, Errors], tolerance_mm: float, tolerance_deg: float, highlight: str | None = None) -> Any:
    """Cumulative distribution of the position and orientation errors per row, with the tolerances.

    ``highlight`` (the recommended row) is drawn thick, on top, and named so in the legend; the legend sits below
    the panels, clear of the curves.
    """
    from matplotlib.ticker import FormatStrFormatter, LogLocator, NullFormatter

    plt = _pyplot()
    styles = styles_for(list(errs))
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(12, 4.9), layout="constrained")
    for n, e in errs.items():
        s = styles[n]
        top = n == highlight
        for ax, values in ((a1, e.position_mm), (a2, e.orientation_deg)):
            v = np.sort(np.clip(values, 1e-6, None))  # log axis: an exact zero drawn at 1e-6
            frac = np.arange(1, len(v) + 1) / len(v)
            ax.step(v, frac, where="post", color=s.color, ls="-" if top else s.linestyle, lw=3.2 if top else 1.3,
                    label=f"{n} (recommended)" if top else n, marker=s.marker, markevery=max(1, len(v) // 6),
                    ms=7 if top else 5, zorder=5 if top else 2, alpha=1.0 if top or highlight is None else 0.85)
    for ax, tol, unit in ((a1, tolerance_mm, "position error [mm]"), (a2, tolerance_deg, "orientation error [deg]")):
        ax.axvline(tol, color="r", ls="--", lw=1.0, label=f"tolerance {tol:g}")
        ax.set_xscale("log")
        ax.xaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))  # 0.01, 0.02, 0.05, 0.1 ...
        ax.xaxis.set_major_formatter(FormatStrFormatter("%g"))
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_xlabel(unit + " (log scale)")
        ax.set_ylabel("fraction of poses with a smaller error [-]")
        ax.set_ylim(0, 1.02)
        ax.grid(alpha=0.3)
    handles, labels = a1.get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=min(len(labels), 7), fontsize=9, frameon=False)
    return fig


def mask_runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """``(first, last)`` row indices of each run of True in ``mask`` (N,), in order."""
    m = np.concatenate([[False], np.asarray(mask, dtype=bool), [False]])
    edges = np.flatnonzero(np.diff(m.astype(int)))
    return [(int(a), int(b) - 1) for a, b in zip(edges[::2], edges[1::2])]


def sigma_along_task_figure(sigma_mm: np.ndarray, error_mm: np.ndarray, outside: np.ndarray,
                            tolerance_mm: float | None = None, model: str = "model") -> Any:
    """Predicted position uncertainty along the poses, in their order: 2 sigma as a band from zero, the measured
    error as dots (those beyond 2 sigma marked), the poses outside the training joint range shaded.

    Args:
        sigma_mm: predicted position sigma (RMS of the error norm) per pose [mm], shape (N,).
        error_mm: measured position error of ``model`` per pose [mm], shape (N,).
        outside: poses outside the joint range of the data the sigma was predicted from, shape (N,).
        tolerance_mm: drawn as a dashed line when given.
    """
    plt = _pyplot()
    sigma, err = np.asarray(sigma_mm, dtype=float), np.asarray(error_mm, dtype=float)
    x = np.arange(len(sigma))
    fig, ax = plt.subplots(figsize=(12, 4.2), layout="constrained")
    for k, (a, b) in enumerate(mask_runs(outside)):
        ax.axvspan(a - 0.5, b + 0.5, color="#f4a261", alpha=0.25, lw=0,
                   label="outside the training joint range (extrapolation)" if k == 0 else None)
    ax.fill_between(x, 0, 2 * sigma, color="#2a6f97", alpha=0.25, step="mid", label="predicted 2 sigma")
    ax.plot(x, 2 * sigma, color="#2a6f97", lw=1.2, drawstyle="steps-mid")
    beyond = err > 2 * sigma
    ax.plot(x[~beyond], err[~beyond], ".", color="#333333", ms=3, label=f"{model}: measured error")
    ax.plot(x[beyond], err[beyond], "x", color="#d62828", ms=5,
            label=f"{model}: error beyond 2 sigma ({100 * beyond.mean():.1f} % of the poses)")
    if tolerance_mm is not None:
        ax.axhline(tolerance_mm, color="r", ls="--", lw=1.0, label=f"tolerance {tolerance_mm:g} mm")
    ax.set_xlabel("pose (row of the recording, in order) [-]")
    ax.set_ylabel("position error [mm]")
    ax.set_xlim(-0.5, len(sigma) - 0.5)
    ax.set_ylim(0, None)
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left", fontsize=8, ncol=2)
    return fig


def singular_values_figure(s: np.ndarray) -> Any:
    """Singular values of the Fourier coefficient matrix (log scale)."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.semilogy(np.arange(1, len(s) + 1), s, "o-", color=METHOD_STYLES["fbf13"].color)
    ax.set_xlabel("singular value index [-]")
    ax.set_ylabel("singular value of the Fourier coefficient matrix [-]")
    ax.grid(alpha=0.3)
    return fig


def correction_map_figure(model: Any, reference: Any, q_rad: np.ndarray, label: str) -> Any:
    """|p_model - p_reference| over a (q2, q3) grid, the other joints at the median of ``q_rad``.

    Cells where ``model`` would extrapolate (outside the region it was fitted on) are left blank.

    Args:
        model: the configuration-dependent model (e.g. fbf13).
        reference: the model it is compared with (e.g. nominal).
        q_rad: configurations whose (q2, q3) range and median pose set the grid [rad], shape (N, 6).
        label: model names for the title, e.g. "fbf13 - nominal".
    """
    plt = _pyplot()
    q2 = np.linspace(q_rad[:, 1].min(), q_rad[:, 1].max(), 60)
    q3 = np.linspace(q_rad[:, 2].min(), q_rad[:, 2].max(), 60)
    g2, g3 = np.meshgrid(q2, q3)
    q = np.tile(np.median(q_rad, axis=0), (g2.size, 1))
    q[:, 1], q[:, 2] = g2.ravel(), g3.ravel()
    d = np.linalg.norm(model.fk(q)[1] - reference.fk(q)[1], axis=1)
    d[np.asarray(model.out_of_range(q), dtype=bool)] = np.nan
    fig, ax = plt.subplots(figsize=(6.4, 5))
    im = ax.pcolormesh(np.degrees(q2), np.degrees(q3), d.reshape(g2.shape), cmap="viridis", shading="auto")
    ax.set_xlabel("q2 [deg]")
    ax.set_ylabel("q3 [deg]")
    ax.set_title(f"position correction {label} (other joints at their median)", fontsize=9)
    bar = fig.colorbar(im, ax=ax)
    bar.set_label(f"|p {label}| [mm]")
    return fig


