"""The demo's ``report.html``: one page with the comparison table of each arm and its plots.

The page has no scripts or external resources; it references the PNG plots written next to it
(``R1/error_along_path.png`` ...), so the folder can be zipped and opened anywhere.
"""

from __future__ import annotations

import html
from pathlib import Path
from typing import Any

from app.analysis.report import write_report
from calibration.files import atomic_write_text

_STYLE = """body{font-family:system-ui,sans-serif;margin:2em;max-width:1200px;color:#222}
table{border-collapse:collapse;margin:1em 0}th,td{border:1px solid #bbb;padding:4px 8px;text-align:right}
th{background:#eee}td:first-child,th:first-child{text-align:left}tr.best td{background:#e6f4e6}
img{max-width:100%;border:1px solid #ddd;margin:0.5em 0}code{background:#f4f4f4;padding:1px 4px}
.note{color:#555}"""


def _e(value: Any) -> str:
    return html.escape(str(value), quote=True)


def method_table(robot_summary: dict[str, Any]) -> str:
    """HTML table of one arm's test statistics per method; the lowest mean position error is highlighted."""
    methods = robot_summary["methods"]
    best = min(methods, key=lambda m: methods[m]["test"]["position_mm"]["mean"]) if methods else None
    rows = ["<table><tr><th>method</th><th>params</th><th>fit s</th><th>pos mean mm</th><th>pos std mm</th>"
            "<th>pos max mm</th><th>pos RMS mm</th><th>ori mean deg</th><th>ori max deg</th></tr>"]
    for m, v in methods.items():
        p, o = v["test"]["position_mm"], v["test"]["orientation_deg"]
        cls = ' class="best"' if m == best else ""
        rows.append(f"<tr{cls}><td>{_e(m)}</td><td>{v['n_parameters']}</td><td>{v['fit_seconds']:.2f}</td>"
                    f"<td>{p['mean']:.3f}</td><td>{p['std']:.3f}</td><td>{p['max']:.3f}</td><td>{p['rms']:.3f}</td>"
                    f"<td>{o['mean']:.4f}</td><td>{o['max']:.4f}</td></tr>")
    for m, reason in robot_summary["skipped_methods"].items():
        rows.append(f'<tr><td>{_e(m)}</td><td colspan="8" style="text-align:left">skipped: {_e(reason)}</td></tr>')
    rows.append("</table>")
    return "\n".join(rows)


def write_html(out_dir: Path, comparisons: dict[str, Any], tests: dict[str, Any], summary: dict[str, Any]) -> Path:
    """Write each arm's Markdown report and plots into ``out_dir/<robot>/`` and ``out_dir/report.html``.

    Args:
        out_dir: the demo folder.
        comparisons: robot -> :class:`~app.analysis.compare.Comparison`.
        tests: robot -> test :class:`~calibration.recording.Recording`.
        summary: the demo summary (see :func:`app.demo.run.run_demo`).

    Returns:
        The path of ``report.html``.
    """
    out_dir = Path(out_dir)
    cfg, planted = summary["config"], summary["planted"]
    body = ["<h1>cellcal demo: calibration of the simulated cell</h1>",
            f"<p>Both arms simulated with planted geometric errors (joint origins &sigma; {planted['origin_std_mm']} mm, "
            f"axis tilts &sigma; {planted['tilt_std_deg']} deg) and a gravity joint compliance "
            f"({planted['compliance_rms_mm']} mm RMS); mocap noise {planted['mocap_noise_mm']} mm per axis per frame, "
            f"{cfg['mocap_rate_hz']:g} Hz, carried over Zenoh on loopback "
            f"({summary['mocap_frames_received']} frames received). Anchor grid step {cfg['anchor_step_deg']:g} deg, "
            f"{cfg['validation_poses']} random validation poses per arm as the test set. Seed {cfg['seed']}, "
            f"simulated time x{cfg['time_scale']:g}.</p>"]
    for robot, cmp in comparisons.items():
        r = summary["robots"][robot]
        files = write_report(cmp, tests[robot], out_dir / robot, with_paper=False)
        body.append(f"<h2>{_e(robot)}</h2>")
        body.append(f"<p>{r['samples']} samples measured of {r['targets']} targets ({r['skipped_targets']} skipped): "
                    f"{r['train_samples']} training, {r['cpa_samples']} CPA sweep, {r['test_samples']} test; "
                    f"collection took {r['collect_seconds']:.1f} s. Test-set errors:</p>")
        body.append(method_table(r))
        if r.get("observability_warning"):
            body.append(f"<p class='note'>Observability: {_e(r['observability_warning'])}</p>")
        body.append(f"<p class='note'>Details (correlations, paired tests, local parameter spread): "
                    f"<a href='{_e(robot)}/report.md'>{_e(robot)}/report.md</a>; recordings "
                    f"<code>{_e(robot)}/train.csv</code>, <code>{_e(robot)}/cpa.csv</code>, "
                    f"<code>{_e(robot)}/test.csv</code>; models in <code>{_e(robot)}/models/</code>.</p>")
        for f in files:
            if f.suffix == ".png":
                body.append(f"<img src='{_e(robot)}/{_e(f.name)}' alt='{_e(f.stem)}'>")
    body.append(f"<p class='note'>Run time {summary['seconds']:.1f} s (report written before the final figure).</p>")
    page = ("<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'><title>cellcal demo</title>"
            f"<style>{_STYLE}</style></head><body>\n" + "\n".join(body) + "\n</body></html>\n")
    path = out_dir / "report.html"
    atomic_write_text(path, page)
    return path
