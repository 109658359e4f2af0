"""meshcat preview of a plan: both arms drawn from their kinematic model, tool frames, floor, animation.

``preview(cell, plan, html_out=...)`` writes one self-contained HTML page (meshcat's viewer JavaScript is
inlined and every drawing command is an embedded ``data:`` URL, so it opens from disk with no server and no
network). The commands are recorded in-process by a small window object that stands in for meshcat's
zmq server, so no server process or port is needed; ``serve=True`` uses a real meshcat server instead (for
a live view in the browser).

Plans: any plan file (:func:`app.cell.plan_file.read_plan`): a dual plan draws both arms per waypoint; a
single-robot collection plan moves its arm target by target while the other keeps its previous configuration
(the home configuration q = 0 at the start).
Arms are drawn as the cell's collision capsules (:mod:`app.cell.capsules`, the model the safety checks and the
dual planner use, radii from the robot YAMLs): a cylinder and two end spheres per capsule, no meshes. Viewer
units are metres.
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

from app.cell.capsules import SEGMENTS, CellCapsules
from calibration.errors import DataError
from calibration.files import atomic_write_text
from cell_config.loader import CellSpec

logger = logging.getLogger("cellcal.app")
COLORS = {"R1": 0xFF7F0E, "R2": 0x1F77B4}  # R1 orange (gun), R2 blue (workpiece)


@dataclass(frozen=True)
class PreviewResult:
    """What :func:`preview` produced.

    Attributes:
        n_frames: animation frames (plan waypoints).
        html_path: the static page, or None.
        url: the live viewer's address when served, or None.
    """

    n_frames: int
    html_path: Path | None = None
    url: str | None = None


def plan_frames(plan: Any) -> list[dict[str, np.ndarray]]:
    """Frames of a dual or collection plan: one ``{"R1": q (6,), "R2": q (6,)}`` per waypoint [rad].

    Args:
        plan: a plan file path, its parsed content, a :class:`~app.cell.planning.Plan` or a
            :class:`~app.dual.plan_result.PlanResult` (read with :func:`app.cell.plan_file.read_plan`).

    Raises:
        DataError: unreadable or malformed plan, a robot other than R1/R2, or no waypoints.
    """
    from app.cell.plan_file import read_plan
    from app.dual.plan_result import PlanResult

    plan = read_plan(plan)
    if isinstance(plan, PlanResult):
        frames = [{"R1": w.q_R1.copy(), "R2": w.q_R2.copy()} for w in plan.waypoints]
    else:
        current = {"R1": np.zeros(6), "R2": np.zeros(6)}
        frames = []
        for i, t in enumerate(plan.targets):
            if t.robot not in current:
                raise DataError("<plan>", None, None, f"entry {i}: unknown robot {t.robot!r}; valid: R1, R2")
            current[t.robot] = np.asarray(t.q, dtype=float)
            frames.append({k: v.copy() for k, v in current.items()})
    if not frames:
        raise DataError("<plan>", None, None, "the plan has no waypoints")
    return frames


def _check_limits(cell: CellSpec, frames: list[dict[str, np.ndarray]]) -> None:
    """Refuse a plan with a joint beyond its limit, as export-targets does (a preview must not show what the
    controller would never be sent).

    Raises:
        UnsafeTarget: naming the waypoint, robot, joint, value and limit.
    """
    from calibration.errors import UnsafeTarget

    for name in ("R1", "R2"):
        spec = cell.robot(name).robot
        q = np.array([f[name] for f in frames])
        bad = (q < spec.lower_rad) | (q > spec.upper_rad)
        if bad.any():
            i, j = (int(v) for v in np.argwhere(bad)[0])
            limit = spec.lower_rad[j] if q[i, j] < spec.lower_rad[j] else spec.upper_rad[j]
            raise UnsafeTarget(name, j + 1, float(q[i, j]), float(limit), f"waypoint {i} of the plan is beyond the "
                                                                          "joint limits; not drawn")


class RecordingWindow:
    """Stands in for meshcat's zmq server: keeps the scene and renders it as one static page."""

    def __init__(self) -> None:
        self.nodes: dict[str, dict[str, Any]] = {}

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
                    cmds.append('fetch("data:application/octet-binary;base64,%s").then(r => r.arrayBuffer())'
                                ".then(b => viewer.handle_command_bytearray(new Uint8Array(b)));"
                                % base64.b64encode(blob).decode())
        return ("<!DOCTYPE html>\n<html><head><meta charset=utf-8><title>cellcal preview</title>"
                "<style>body{margin:0}#meshcat-pane{width:100vw;height:100vh;overflow:hidden}</style></head>"
                f"<body><div id=\"meshcat-pane\"></div><script>{js}</script><script>"
                "var viewer = new MeshCat.Viewer(document.getElementById(\"meshcat-pane\"));\n"
                + "\n".join(cmds) + "</script></body></html>")


def _segment_transform(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pose of a meshcat cylinder (axis y, centred) spanning a -> b [m]."""
    d = b - a
    n = np.linalg.norm(d)
    y = d / n if n > 1e-12 else np.array([0.0, 1.0, 0.0])
    helper = np.array([1.0, 0, 0]) if abs(y[0]) < 0.9 else np.array([0, 0, 1.0])
    x = np.cross(y, helper)
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, y, np.cross(x, y)])
    T[:3, 3] = 0.5 * (a + b)
    return T


def _tool_poses(cell: CellSpec, model: Any, name: str, q: np.ndarray) -> np.ndarray:
    """Tool poses in the cell frame for joint angles q (F, 6) [rad], shape (F, 4, 4) [m]."""
    c = model.chain(q)
    T = cell.robot(name).T_cell_base
    out = np.tile(np.eye(4), (len(q), 1, 1))
    out[:, :3, :3] = T[:3, :3] @ c.R_base_tool
    out[:, :3, 3] = (c.p_base_tool @ T[:3, :3].T + T[:3, 3]) * 1e-3
    return out


def _capsule_transforms(seg_m: np.ndarray) -> dict[str, np.ndarray]:
    """meshcat transforms of one capsule (cylinder + two end spheres) spanning seg_m (2, 3) [m]."""
    import meshcat.transformations as tf

    return {"": _segment_transform(seg_m[0], seg_m[1]), "_end0": tf.translation_matrix(seg_m[0]),
            "_end1": tf.translation_matrix(seg_m[1])}


def _windows(static: bool, serve: bool) -> tuple[list[Any], str | None]:
    """The windows to draw in: a recording window for the static page, a live meshcat server's; its URL."""
    import meshcat

    windows: list[Any] = [RecordingWindow()] if static else []
    url = None
    if serve:
        from app.dual.meshcat_server import start

        _, zmq_url, _ = start()  # web server on 127.0.0.1 only (meshcat's own listens on every interface)
        with contextlib.redirect_stdout(io.StringIO()):  # meshcat prints the URL; we return and log it
            live = meshcat.Visualizer(zmq_url=zmq_url)
        url = live.url()
        logger.info("meshcat viewer at %s (the server lives as long as this process)", url)
        windows.append(live.window)
    return windows, url


def _scene(window: Any, capsules: CellCapsules) -> tuple[Any, Any]:
    """Background, camera and floor in ``window``: ``(viewer, the cellcal node the arms are drawn under)``."""
    import meshcat
    import meshcat.geometry as g
    import meshcat.transformations as tf

    top = meshcat.Visualizer(window=window)
    top["/Background"].set_property("top_color", [0.93, 0.93, 0.93])
    top["/Background"].set_property("bottom_color", [0.75, 0.75, 0.75])
    top["/Grid"].set_property("visible", False)
    top["/Axes"].set_property("visible", False)
    top["/Cameras/default/rotated/<object>"].set_property("position", [0.0, 1.4, 3.4])
    vis = top["cellcal"]  # the viewer orbits the origin: centre the cell on it
    vis.set_transform(tf.translation_matrix([-1.35, 0.2, -0.1]))
    vis["cell/floor"].set_object(g.Box([4.2, 2.4, 0.02]), g.MeshLambertMaterial(color=0x9E9E8E))
    vis["cell/floor"].set_transform(tf.translation_matrix([1.35, -0.2, capsules.floor_z_mm * 1e-3 - 0.01]))
    return top, vis


def _draw_arm(vis: Any, anim: Any, cell: CellSpec, capsules: CellCapsules, name: str, q: np.ndarray,
              model: Any) -> None:
    """One arm's capsules and tool triad, animated over its joint angles q [rad] (F, 6)."""
    import meshcat.geometry as g

    segs = capsules.segments(name, q, model) * 1e-3  # (F, 6, 2, 3) [m]
    tools = _tool_poses(cell, model, name, q)
    mat = g.MeshPhongMaterial(color=COLORS[name])
    for k, seg in enumerate(SEGMENTS):
        r = float(capsules.radii(name)[k]) * 1e-3
        length = float(np.linalg.norm(segs[0, k, 1] - segs[0, k, 0]))
        vis[f"{name}/capsules/{seg}"].set_object(g.Cylinder(length, r), mat)
        vis[f"{name}/capsules/{seg}_end0"].set_object(g.Sphere(r), mat)
        vis[f"{name}/capsules/{seg}_end1"].set_object(g.Sphere(r), mat)
    vis[f"{name}/tool"].set_object(g.triad(0.25))
    if name == "R2":
        vis["R2/tool/workpiece"].set_object(g.Box([0.12, 0.12, 0.01]), g.MeshLambertMaterial(color=0xD0D0D0))
    for f in range(len(q)):
        with anim.at_frame(vis, f) as af:
            for k, seg in enumerate(SEGMENTS):
                for suffix, T in _capsule_transforms(segs[f, k]).items():
                    af[f"{name}/capsules/{seg}{suffix}"].set_transform(T)
            af[f"{name}/tool"].set_transform(tools[f])
    # the first frame as static transforms too, so the page shows the arms before the clip starts
    for k, seg in enumerate(SEGMENTS):
        for suffix, T in _capsule_transforms(segs[0, k]).items():
            vis[f"{name}/capsules/{seg}{suffix}"].set_transform(T)
    vis[f"{name}/tool"].set_transform(tools[0])


def preview(cell: CellSpec, plan: Any, html_out: str | Path | None = None, serve: bool = False,
            models: dict[str, Any] | None = None, fps: float = 10.0) -> PreviewResult:
    """Draw the cell and animate a plan.

    Args:
        cell: the loaded cell.
        plan: plan file path, its parsed dict, a ``Plan`` or a ``PlanResult``.
        html_out: write the self-contained static page here.
        serve: also start a meshcat server (a subprocess on 127.0.0.1, alive while this process runs) and draw
            there; the URL is returned. The caller keeps the process alive (e.g. waits for Enter).
        models: PoeModel per robot used for drawing (``chain``); the cell's nominal models when None.
        fps: animation frames (waypoints) per second.

    Returns:
        The :class:`PreviewResult`.

    Raises:
        DataError: the plan is malformed. ModelError: neither ``html_out`` nor ``serve`` was asked for.
    """
    import meshcat
    from meshcat.animation import Animation

    from calibration.errors import ModelError

    if html_out is None and not serve:
        raise ModelError("preview needs html_out (a static page) or serve=True (a live viewer)")
    frames = plan_frames(plan)
    _check_limits(cell, frames)
    models = models or {n: cell.robot(n).model() for n in ("R1", "R2")}
    capsules = CellCapsules(cell)
    windows, url = _windows(html_out is not None, serve)
    for window in windows:
        top, vis = _scene(window, capsules)
        anim = Animation(default_framerate=fps)
        for name in ("R1", "R2"):
            _draw_arm(vis, anim, cell, capsules, name, np.array([frame[name] for frame in frames]), models[name])
        top.set_animation(anim, play=True, repetitions=1)
    path = None
    if html_out is not None:
        path = Path(html_out)
        atomic_write_text(path, meshcat.Visualizer(window=windows[0]).static_html())
        logger.info("wrote preview of %d frames to %s", len(frames), path)
    return PreviewResult(len(frames), path, url)
