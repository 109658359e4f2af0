"""The waypoint readout of the static preview page: an HTML overlay that steps the meshcat animation.

The overlay shows, for the selected waypoint, its index, both arms' joint values [deg] and the relative-pose
residual the planner recorded [mm, deg] (``residual_mm`` / ``residual_deg`` of the plan file; "not recorded"
when the plan has none, e.g. a collection plan or a hand-written one). A slider and prev/next buttons pause the
animation and seek it to the waypoint; "play" runs it from there and the readout follows the clip. The page
opens at waypoint 0, or at the one its address names (``preview.html#waypoint=7``).

The numbers are embedded once as JSON (``<script type="application/json" id="cellcal-readout">``) and rendered by
the page's script, so the DOM holds exactly the plan's values (joint angles to 0.001 deg, residuals to three
significant digits). Element ids (``wp-index``, ``q-R1-1`` .. ``q-R2-6``, ``res-mm``, ``res-deg``, ``wp-status``)
are the page's contract with its tests.
"""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np

_STYLE = """
#cellcal-readout-box{position:fixed;bottom:8px;left:8px;z-index:10;background:rgba(255,255,255,.92);
 font:13px/1.35 sans-serif;padding:8px 10px;border:1px solid #888;border-radius:4px;min-width:300px}
#cellcal-readout-box table{border-collapse:collapse;margin-top:4px}
#cellcal-readout-box td,#cellcal-readout-box th{padding:1px 5px;text-align:right}
#cellcal-readout-box .bad{color:#b00;font-weight:bold}
#cellcal-readout-box input[type=range]{width:100%}
"""

_BODY = """
<div id="cellcal-readout-box">
 <div><b>waypoint <span id="wp-index"></span></b> of <span id="wp-count"></span>
  <span id="wp-status"></span></div>
 <input id="wp-slider" type="range" min="0" step="1" value="0">
 <div><button id="wp-prev">&#9664; prev</button> <button id="wp-next">next &#9654;</button>
  <button id="wp-play">play</button></div>
 <table><tr><th>joint [deg]</th><th>1</th><th>2</th><th>3</th><th>4</th><th>5</th><th>6</th></tr>
  <tr><th style="color:{R1}">R1</th><td id="q-R1-1"></td><td id="q-R1-2"></td><td id="q-R1-3"></td>
   <td id="q-R1-4"></td><td id="q-R1-5"></td><td id="q-R1-6"></td></tr>
  <tr><th style="color:{R2}">R2</th><td id="q-R2-1"></td><td id="q-R2-2"></td><td id="q-R2-3"></td>
   <td id="q-R2-4"></td><td id="q-R2-5"></td><td id="q-R2-6"></td></tr></table>
 <div>relative-pose residual: <span id="res-mm"></span> mm, <span id="res-deg"></span> deg</div>
 <div style="font-size:11px;color:#444">traces: <span style="color:{gun}">&#9679; gun tool point</span>
  <span style="color:{workpiece}">&#9679; workpiece tool point</span> (cell frame);
  <span style="color:{target}">&#9679; gun target</span> in the workpiece frame</div>
</div>
"""

# Runs after the viewer script: `viewer` is meshcat's Viewer; its animation arrives asynchronously (each
# command is a fetched data: URL), so seeking waits until the clip's actions exist.
_SCRIPT = r"""
(function () {
  const R = JSON.parse(document.getElementById("cellcal-readout").textContent);
  const n = R.q_deg.R1.length, $ = (id) => document.getElementById(id);
  const slider = $("wp-slider");
  slider.max = n - 1;
  $("wp-count").textContent = n;
  let current = 0, playing = false;
  const fmt = (v, f) => (v === null ? "not recorded" : f(v));
  function render(i) {
    current = i;
    slider.value = i;
    $("wp-index").textContent = i;
    for (const arm of ["R1", "R2"])
      for (let j = 0; j < 6; j++) $("q-" + arm + "-" + (j + 1)).textContent = R.q_deg[arm][i][j].toFixed(3);
    $("res-mm").textContent = fmt(R.residual_mm[i], (v) => v.toExponential(2));
    $("res-deg").textContent = fmt(R.residual_deg[i], (v) => v.toExponential(2));
    const st = $("wp-status");
    st.textContent = R.note[i];
    st.className = R.converged[i] === false ? "bad" : "";
  }
  const animator = () => (typeof viewer !== "undefined" && viewer.animator.actions.length ? viewer.animator : null);
  function seek(i) {
    i = Math.max(0, Math.min(n - 1, i));
    render(i);
    const a = animator();
    if (!a) return;
    playing = false;
    if (a.playing) a.pause();
    for (const act of a.actions) { act.paused = false; act.play(); }  // an action applies only while active
    a.seek(i / R.fps);
  }
  slider.addEventListener("input", () => seek(parseInt(slider.value, 10)));
  $("wp-prev").addEventListener("click", () => seek(current - 1));
  $("wp-next").addEventListener("click", () => seek(current + 1));
  function play() {
    const a = animator();
    if (!a) return;
    seek(current >= n - 1 ? 0 : current);
    a.play();
    playing = true;
  }
  $("wp-play").addEventListener("click", play);
  setInterval(() => {  // the readout follows a playing clip
    const a = animator();
    if (!a || !playing) return;
    if (a.playing) render(Math.min(n - 1, Math.round(a.actions[0].time * R.fps)));
    else seek(n - 1);  // the clip ran to its end (meshcat then rewinds its actions): stay on the last waypoint
  }, 100);
  // open at waypoint 0, or at the one the address names (preview.html#waypoint=7)
  const asked = /waypoint=(\d+)/.exec(location.hash);
  const first = asked ? Math.min(n - 1, parseInt(asked[1], 10)) : 0;
  render(first);
  const wait = setInterval(() => { if (animator()) { clearInterval(wait); seek(first); } }, 50);
})();
"""


def readout_data(q_deg: dict[str, np.ndarray], residual_mm: np.ndarray, residual_deg: np.ndarray,
                 converged: np.ndarray | None, notes: list[str], fps: float) -> dict[str, Any]:
    """The overlay's numbers as JSON-ready lists (NaN, "not recorded", becomes null).

    Args:
        q_deg: joint angles per robot [deg], shape (F, 6) each.
        residual_mm, residual_deg: recorded relative-pose residual per waypoint, shape (F,), NaN when absent.
        converged: per waypoint whether the planner proved it, shape (F,); None when the plan does not say.
        notes: one short status text per waypoint.
        fps: animation frames (waypoints) per second.
    """
    def nums(a: np.ndarray) -> list[float | None]:
        return [None if not math.isfinite(v) else float(v) for v in np.asarray(a, dtype=float)]

    return {"fps": float(fps), "q_deg": {k: np.asarray(v, dtype=float).tolist() for k, v in q_deg.items()},
            "residual_mm": nums(residual_mm), "residual_deg": nums(residual_deg),
            "converged": None if converged is None else [bool(c) for c in converged], "note": list(notes)}


def readout_html(data: dict[str, Any], colors: dict[str, int]) -> str:
    """The overlay (style, markup, embedded numbers, script) to place at the end of the page's body.

    Args:
        data: from :func:`readout_data`.
        colors: the scene's colours (0xRRGGBB) of ``R1``, ``R2`` and the traces ``gun``, ``workpiece``, ``target``,
            for the table's row heads and the legend.
    """
    if data["converged"] is None:
        data = {**data, "converged": [None] * len(data["note"])}
    payload = json.dumps(data, allow_nan=False).replace("</", "<\\/")  # cannot close the script element
    body = _BODY.format(**{k: f"#{v:06x}" for k, v in colors.items()})
    return (f"<style>{_STYLE}</style>{body}"
            f'<script type="application/json" id="cellcal-readout">{payload}</script>'
            f"<script>{_SCRIPT}</script>")
