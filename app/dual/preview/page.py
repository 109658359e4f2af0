"""meshcat preview of a plan: both arms, the gun and the workpiece, name plates, path traces, a waypoint readout.

``preview(cell, plan, html_out=...)`` writes one self-contained HTML page (meshcat's viewer JavaScript is
inlined and every drawing command is an embedded ``data:`` URL, so it opens from disk with no server and no
network). The commands are recorded in-process by a small window object that stands in for meshcat's
zmq server, so no server process or port is needed; ``serve=True`` uses a real meshcat server instead (for
a live view in the browser, bound to 127.0.0.1; :mod:`app.dual.preview.meshcat_server`).

Plans: any plan file (:func:`app.collection.plans.reader.read_plan`): a dual plan draws both arms per waypoint; a
single-robot collection plan moves its arm target by target while the other keeps its previous configuration
(its parking pose at the start, where ``cellcal plan`` checked the plan with it; the safety checks start there
too). A plan with a joint beyond its limit is refused, as export-targets refuses it. Any other defect of
:func:`app.collection.plan_safety.plan_defects` (the checks every exit of a plan runs: relative pose recomputed from the
models, the step between waypoints, floor and clearances, ...) is drawn, so the person sees it: red dots on the
unsafe waypoints, ``UNSAFE`` and the reason in the readout.

What is drawn (viewer units are metres):

* the arms as the cell's collision capsules (:mod:`cell_config.capsules`, the model the safety checks and the
  dual planner use, radii from the robot YAMLs): a cylinder and two end spheres per capsule, no meshes;
* what each arm carries, R1's spray gun and R2's workpiece, from the tool YAML's ``geometry`` (flange frame;
  :class:`cell_config.loader.ToolShape`), and the tool (marker) frame as a triad;
* "R1 gun" / "R2 workpiece" name plates above the bases;
* the path trace: the gun's and the workpiece's tool points over the plan (cell frame, a line with a dot per
  waypoint) and, moving with the workpiece, the relative pose's target point and where the gun was in the
  workpiece frame at each waypoint (on the target to the plan's residual);
* the waypoint readout (:mod:`app.dual.preview.readout`): index, joints of both arms [deg]
  and the residual the plan records, with a slider, prev/next and play, on the static page and the live one.
"""

from __future__ import annotations

import base64
import contextlib
import io
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from app.collection.plan_safety import NOT_SOLVED, PlanDefect, plan_defects
from app.collection.plans.reader import read_plan
from app.dual.preview import scene
from app.dual.preview.meshcat_server import start
from app.dual.preview.plan import PreviewPlan, limit_margin, plan_frames, read_preview_plan
from app.dual.preview.readout import readout_data, readout_html
from calibration.data.files import atomic_write_text
from calibration.errors import ModelError
from cell_config.capsules import CellCapsules
from cell_config.loader import CellSpec

__all__ = ["PreviewPlan", "PreviewResult", "RecordingWindow", "plan_frames", "preview", "read_preview_plan"]

logger = logging.getLogger("cellcal.app")


@dataclass(frozen=True)
class PreviewResult:
    """What :func:`preview` produced.

    Attributes:
        n_frames: animation frames (plan waypoints).
        html_path: the static page, or None.
        url: the live viewer's address when served, or None.
        kind: the plan's kind, ``dual`` or ``collection``.
        max_residual_mm, max_residual_deg: largest relative-pose residual the plan records [mm], [deg]; None when
            it records none (a collection plan, a hand-written plan).
        min_limit_margin_deg: smallest distance of any joint from its limit over the plan [deg] (the plan was
            refused when negative), with ``limit_margin_at`` = (waypoint, robot, joint 1..6) where it occurs.
        defects: why the plan must not leave (:func:`app.collection.plan_safety.plan_defects`, the checks export-targets
            and collect refuse it for); each unsafe waypoint is drawn with a red marker and its reason in the
            readout. Empty: safe.
    """

    n_frames: int
    html_path: Path | None = None
    url: str | None = None
    kind: str = "dual"
    max_residual_mm: float | None = None
    max_residual_deg: float | None = None
    min_limit_margin_deg: float = float("nan")
    limit_margin_at: tuple[int, str, int] | None = None
    defects: tuple[PlanDefect, ...] = ()

    def summary(self) -> dict[str, Any]:
        """The ``preview --json`` summary: waypoints, largest residual, files written, joint-limit check."""
        at = self.limit_margin_at
        return {"waypoints": self.n_frames, "kind": self.kind, "max_residual_mm": self.max_residual_mm,
                "max_residual_deg": self.max_residual_deg,
                "files": [str(self.html_path)] if self.html_path else [], "url": self.url,
                "safe": not self.defects,
                "unsafe": [{"waypoint": d.waypoint, "reason": d.reason} for d in self.defects],
                "joint_limits": {"checked": True, "within": True, "min_margin_deg": self.min_limit_margin_deg,
                                 "at": None if at is None else {"waypoint": at[0], "robot": at[1], "joint": at[2]}}}


class RecordingWindow:
    """Stands in for meshcat's zmq server: keeps the scene and renders it as one static page.

    Attributes:
        nodes: the scene's commands per path.
        overlay: HTML placed after the viewer at the end of the page's body (the waypoint readout).
    """

    def __init__(self) -> None:
        self.nodes: dict[str, dict[str, Any]] = {}
        self.overlay = ""

    def send(self, command: Any) -> None:
        import umsgpack

        data = command.lower()
        kind, path = data["type"], data["path"]
        if kind == "delete":
            self.nodes = {p: n for p, n in self.nodes.items() if p != path and not p.startswith(path + "/")}
            return
        node = self.nodes.setdefault(path, {"object": None, "transform": None, "properties": [], "animation": None})
        blob = umsgpack.packb(data)
        if kind == "set_object":
            node["object"], node["properties"] = blob, []
        elif kind == "set_transform":
            node["transform"] = blob
        elif kind == "set_property":
            node["properties"].append(blob)
        elif kind == "set_animation":
            node["animation"] = blob

    def get_scene(self) -> str:
        from meshcat.servers.zmqserver import VIEWER_ROOT

        js = (Path(VIEWER_ROOT) / "main.min.js").read_text(encoding="utf-8")
        cmds = []
        for node in self.nodes.values():
            for blob in [node["object"], *node["properties"], node["transform"], node["animation"]]:
                if blob is not None:
                    data = base64.b64encode(blob).decode()
                    cmds.append(f'fetch("data:application/octet-binary;base64,{data}").then(r => r.arrayBuffer())'
                                ".then(b => viewer.handle_command_bytearray(new Uint8Array(b)));")
        return ("<!DOCTYPE html>\n<html><head><meta charset=utf-8><title>cellcal preview</title>"
                "<style>body{margin:0}#meshcat-pane{width:100vw;height:100vh;overflow:hidden}</style></head>"
                f"<body><div id=\"meshcat-pane\"></div><script>{js}</script><script>"
                "var viewer = new MeshCat.Viewer(document.getElementById(\"meshcat-pane\"));\n"
                + "\n".join(cmds) + f"</script>{self.overlay}</body></html>")


def _windows(static: bool, serve: bool, overlay: str) -> tuple[list[Any], str | None]:
    """The windows to draw in: a recording window for the static page, a live meshcat server's; its URL.

    Both pages carry ``overlay`` (the waypoint readout) at the end of their body.
    """
    import meshcat

    windows: list[Any] = []
    if static:
        windows.append(RecordingWindow())
        windows[0].overlay = overlay
    url = None
    if serve:

        _, zmq_url, _ = start(overlay)  # web server on 127.0.0.1 only (meshcat's own listens on every interface)
        with contextlib.redirect_stdout(io.StringIO()):  # meshcat prints the URL; we return and log it
            live = meshcat.Visualizer(zmq_url=zmq_url)
        url = live.url()
        logger.info("meshcat viewer at %s (the server lives as long as this process)", url)
        windows.append(live.window)
    return windows, url


def preview(cell: CellSpec, plan: Any, html_out: str | Path | None = None, serve: bool = False,
            models: dict[str, Any] | None = None, fps: float = 10.0,
            plan_models: dict[str, Any] | None = None) -> PreviewResult:
    """Draw the cell and animate a plan.

    Args:
        cell: the loaded cell.
        plan: plan file path, its parsed dict, a ``Plan`` or a ``PlanResult``.
        html_out: write the self-contained static page here (with the waypoint readout).
        serve: also start a meshcat server (a subprocess on 127.0.0.1, alive while this process runs) and draw
            there; the URL is returned. The caller keeps the process alive (e.g. waits for Enter). The live
            page carries the same waypoint readout.
        models: PoeModel per robot used for drawing (``chain``); the cell's nominal models when None.
        fps: animation frames (waypoints) per second.
        plan_models: the models a dual plan was solved with, per robot (nominal when not given): its relative pose
            is recomputed from them by the safety checks (:func:`app.collection.plan_safety.plan_defects`).

    Returns:
        The :class:`PreviewResult`.

    Raises:
        DataError: the plan is malformed. UnsafeTarget: a joint beyond its limit. ModelError: neither
        ``html_out`` nor ``serve`` was asked for.
    """
    import meshcat
    from meshcat.animation import Animation


    if html_out is None and not serve:
        raise ModelError("preview needs html_out (a static page) or serve=True (a live viewer)")
    p = read_preview_plan(plan)
    margin, margin_at = limit_margin(cell, p)
    from app.collection.runtime.sim import park_q

    start = None if p.kind == "dual" else {n: park_q(n) for n in cell.robots}  # where plan checked it from
    defects = tuple(plan_defects(cell, read_plan(plan), models=plan_models, q_start=start))
    unsafe = _unsafe_frames(p.n_frames, defects)
    said = [[r for r in unsafe[f] if not r.startswith(NOT_SOLVED)] for f in range(p.n_frames)]  # the note says it
    notes = [f"UNSAFE: {'; '.join(said[f])} | {n}" if said[f] else n for f, n in enumerate(p.notes)]
    ok = np.array([not unsafe[f] for f in range(p.n_frames)])
    converged = ok if p.converged is None and not ok.all() else None if p.converged is None else p.converged & ok
    models = models or {n: cell.robot(n).model() for n in ("R1", "R2")}
    capsules = CellCapsules(cell)
    q_deg = {n: np.degrees(p.q[n]) for n in ("R1", "R2")}
    overlay = readout_html(readout_data(q_deg, p.residual_mm, p.residual_deg, converged, notes, fps),
                           {**scene.COLORS, **scene.TRACE_COLORS}) + scene.FIT_CAMERA_JS
    windows, url = _windows(html_out is not None, serve, overlay)
    for window in windows:
        top, vis = scene.scene(window, capsules)
        anim = Animation(default_framerate=fps)
        tools = {n: scene.draw_arm(vis, anim, cell, capsules, n, p.q[n], models[n]) for n in ("R1", "R2")}
        scene.draw_traces(vis, p, tools)
        scene.draw_unsafe(vis, tools, np.flatnonzero(~ok))
        scene.draw_labels(vis, cell)
        top.set_animation(anim, play=False, repetitions=1)  # the readout opens it at waypoint 0; "play" runs it
    path = None
    if html_out is not None:
        path = Path(html_out)
        atomic_write_text(path, meshcat.Visualizer(window=windows[0]).static_html())
        logger.info("wrote preview of %d frames to %s", p.n_frames, path)

    def worst(a: np.ndarray) -> float | None:
        return float(np.nanmax(a)) if np.isfinite(a).any() else None

    if defects:
        logger.warning("the plan is unsafe (%d defects, marked in red); first: %s", len(defects), defects[0])
    return PreviewResult(p.n_frames, path, url, p.kind, worst(p.residual_mm), worst(p.residual_deg), margin,
                         margin_at, defects)


def _unsafe_frames(n_frames: int, defects: tuple[PlanDefect, ...]) -> list[list[str]]:
    """Per frame, the reasons it is unsafe (a plan-wide defect marks every frame)."""
    out: list[list[str]] = [[] for _ in range(n_frames)]
    for d in defects:
        for f in range(n_frames) if d.waypoint is None else [d.waypoint]:
            if 0 <= f < n_frames:
                out[f].append(d.reason)
    return out
