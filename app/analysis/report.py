"""Markdown tables and PNG plots of a comparison (``compare --report DIR``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from app.analysis.compare import Comparison
from calibration.files import atomic_open, atomic_write_text
from calibration.recording import Recording

PAPER_R1_TEST = {  # the paper's Table IV (R1 test set, position mean / std / max mm)
    "nominal": (1.29, 0.21, 1.72), "base": (0.53, 0.25, 1.27), "cpa": (0.44, 0.20, 0.99),
    "nls0": (0.41, 0.21, 0.99), "nls1": (0.92, 0.79, 3.46), "nearest": (0.32, 0.17, 0.81),
    "linear": (0.31, 0.17, 0.81), "cubic": (0.31, 0.17, 0.83), "rbf": (0.31, 0.17, 0.83),
    "fbf13": (0.31, 0.14, 0.74), "fbf7": (0.32, 0.16, 0.81), "nn": (0.34, 0.13, 0.78), "ae": (0.31, 0.14, 0.73),
}


def comparison_table(cmp: Comparison, with_paper: bool = False) -> str:
    """Table IV as Markdown: test and train position/orientation statistics and fit time per method."""
    head = "| method | params | fit s | test pos mean / std / max mm | test ori mean / max deg | train pos mean / max mm |"
    sep = "|---|---:|---:|---|---|---|"
    if with_paper:
        head += " paper test mean / std / max |"
        sep += "---|"
    rows = [head, sep]
    for m, model in cmp.models.items():
        te, tr = cmp.test_errors[m], cmp.train_errors[m]
        seconds = cmp.fit_seconds[m]
        row = (f"| {m} | {model.n_parameters} | {'–' if seconds is None else f'{seconds:.3f}'} | "
               f"{te.position_mm.mean():.3f} / {te.position_mm.std():.3f} / {te.position_mm.max():.3f} | "
               f"{te.orientation_deg.mean():.3f} / {te.orientation_deg.max():.3f} | "
               f"{tr.position_mm.mean():.3f} / {tr.position_mm.max():.3f} |")
        if with_paper:
            paper = PAPER_R1_TEST.get(m)
            row += f" {' / '.join(f'{v:.2f}' for v in paper)} |" if paper else " – |"
        rows.append(row)
    for m, reason in cmp.skipped.items():
        rows.append(f"| {m} | – | – | skipped: {reason} | | |" + (" |" if with_paper else ""))
    return "\n".join(rows)


def write_report(cmp: Comparison, test: Recording, out_dir: str | Path, with_paper: bool = False) -> list[Path]:
    """Write ``report.md`` and the PNG plots into ``out_dir``; returns the files written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files = []
    lines = [f"# Calibration comparison: {cmp.robot}", "", comparison_table(cmp, with_paper), ""]
    a = cmp.analysis
    if "observability" in a:
        o = a["observability"]
        lines += ["## Observability of the training set", "",
                  f"Condition number {o['condition_number']:.3g}; {o['rank']} of {o['parameters']} directions kept.",
                  "", o["warning"] or "Every parameter direction is observable.", ""]
        lines += [f"- {d}" for d in o["hidden_directions"]] + [""]
    if "nominal_error_joint_correlation_test" in a:
        corr = a["nominal_error_joint_correlation_test"]
        lines += ["## Correlation of the nominal position error with each joint (test set, Table II)", "",
                  "| " + " | ".join(f"q{j + 1}" for j in range(len(corr))) + " |",
                  "|" + "---:|" * len(corr), "| " + " | ".join(f"{c:.3f}" for c in corr) + " |", ""]
    for key, title in (("paired_tests_vs_nominal", "the nominal model"), ("paired_tests_vs_fbf13", "the Fourier CDC")):
        if key in a:
            lines += [f"## Paired tests against {title} (test position error, method minus reference)", "",
                      "| method | mean difference mm | t-test p | Wilcoxon p |", "|---|---:|---:|---:|"]
            lines += [f"| {m} | {t['mean_difference']:.3f} | {t['t_pvalue']:.2e} | {t['wilcoxon_pvalue']:.2e} |"
                      for m, t in a[key].items()] + [""]
    if "local_parameter_spread" in a:
        lines += ["## Spread of local parameters over clusters (Table V)", "",
                  "| parameter | mean | std | min | max |", "|---|---:|---:|---:|---:|"]
        lines += [f"| {n} | {s['mean']:.4g} | {s['std']:.4g} | {s['min']:.4g} | {s['max']:.4g} |"
                  for n, s in a["local_parameter_spread"].items()] + [""]
    # Fig. 8: error along the test path (stop-and-go poses along Cartesian lines) per method.
    fig, ax = plt.subplots(figsize=(11, 4.5))
    for m, e in cmp.test_errors.items():
        ax.plot(e.position_mm, lw=0.8, label=m)
    ax.set_xlabel("test pose (along the approach lines)")
    ax.set_ylabel("position error [mm]")
    ax.legend(ncol=5, fontsize=7)
    ax.grid(alpha=0.3)
    files.append(save_figure(fig, out / "error_along_path.png"))
    lines += ["## Plots", "", "![error along the test path](error_along_path.png)", ""]
    if "fbf13" in cmp.models:
        interp = cmp.models["fbf13"].interpolator  # type: ignore[attr-defined]
        s = np.asarray(interp.singular_values())
        fig, ax = plt.subplots(figsize=(6, 4))
        ax.semilogy(np.arange(1, len(s) + 1), s, "o-")
        ax.set_xlabel("singular value index")
        ax.set_ylabel("singular value of the Fourier coefficient matrix")
        ax.grid(alpha=0.3)
        files.append(save_figure(fig, out / "fourier_singular_values.png"))
        fig, ax = plt.subplots(figsize=(6, 5))
        im = ax.imshow(np.abs(interp.right_singular_vectors().T), cmap="viridis")
        ax.set_title("|V^T| of the Fourier coefficient matrix")
        fig.colorbar(im)
        files.append(save_figure(fig, out / "fourier_v_heatmap.png"))
        lines += ["![Fourier singular values](fourier_singular_values.png)", "",
                  "![Fourier V heat map](fourier_v_heatmap.png)", ""]
    md = out / "report.md"
    atomic_write_text(md, "\n".join(lines))
    files.append(md)
    return files


def save_figure(fig: object, path: Path) -> Path:
    """Save a matplotlib figure as PNG (tight layout, 110 dpi), atomically, and close it."""
    import matplotlib.pyplot as plt

    try:
        fig.tight_layout()  # type: ignore[attr-defined]
        with atomic_open(path, binary=True) as f:
            fig.savefig(f, format="png", dpi=110)  # type: ignore[attr-defined]
    finally:
        plt.close(fig)  # type: ignore[arg-type]
    return path
