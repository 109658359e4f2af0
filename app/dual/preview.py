"""meshcat preview of a plan: both arms, the gun and the workpiece, name plates, path traces, a waypoint readout.

``preview(cell, plan, html_out=...)`` writes one self-contained HTML page (meshcat's viewer JavaScript is
inlined and every drawing command is an embedded ``data:`` URL, so it opens from disk with no server and no
network). The commands are recorded in-process by a small window object that stands in for meshcat's
zmq server, so no server process or port is needed; ``serve=True`` uses a real meshcat server instead (for
a live view in the browser, bound to 127.0.0.1; :mod:`app.dual.meshcat_server`).

Plans: any plan file (:func:`app.cell.plan_file.read_plan`): a dual plan draws both arms per waypoint; a
single-robot collection plan moves its arm target by target while the other keeps its previous configuration
(the home configuration q = 0 at the start). A plan with a joint beyond its limit is refused, as
export-targets refuses it.

What is drawn (viewer units are metres):

* the arms as the cell's collision capsules (:mod:`app.cell.capsules`, the model the safety checks and the
  dual planner use, radii from the robot YAMLs): a cylinder and two end spheres per capsule, no meshes;
* what each arm carries, R1's spray gun and R2's workpiece, from the tool YAML's ``geometry`` (flange frame;
  :class:`cell_config.loader.ToolShape`), and the tool (marker) frame as a triad;
* "R1 gun" / "R2 workpiece" name plates above the bases;
* the path trace: the gun's and the workpiece's tool points over the plan (cell frame, a line with a dot per
  waypoint) and, moving with the workpiece, the relative pose's target point and where the gun was in the
  workpiece frame at each waypoint (on the target to the plan's residual);
* the waypoint readout (:mod:`app.dual.preview_readout`): index, joints of both arms [deg]
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

from app.cell.capsules import SEGMENTS, CellCapsules
from calibration.errors import DataError
from calibration.files import atomic_write_text
from cell_config.loader import CellSpec

logger = logging.getLogger("cellcal.app")
COLORS = {"R1": 0xFF7F0E, "R2": 0x1F77B4}  # arms: R1 orange (gun), R2 blue (workpiece)
CARRIED_COLORS = {"R1": 0xB03A2E, "R2": 0x2CA02C}  # the gun dark red, the workpiece green
TRACE_COLORS = {"gun": 0x9400D3, "workpiece": 0x00A5B5, "target": 0xE6B800}  # violet, teal, amber
LABELS = {"R1": "R1 gun", "R2": "R2 workpiece"}


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
    """

    n_frames: int
    html_path: Path | None = None
    url: str | None = None
    kind: str = "dual"
    max_residual_mm: float | None = None
    max_residual_deg: float | None = None
    min_limit_margin_deg: float = float("nan")
    limit_margin_at: tuple[int, str, int] | None = None

    def summary(self) -> dict[str, Any]:
        """The ``preview --json`` summary: waypoints, largest residual, files written, joint-limit check."""
        at = self.limit_margin_at
        return {"waypoints": self.n_frames, "kind": self.kind, "max_residual_mm": self.max_residual_mm,
                "max_residual_deg": self.max_residual_deg,
                "files": [str(self.html_path)] if self.html_path else [], "url": self.url,
                "joint_limits": {"checked": True, "within": True, "min_margin_deg": self.min_limit_margin_deg,
                                 "at": None if at is None else {"waypoint": at[0], "robot": at[1], "joint": at[2]}}}


@dataclass(frozen=True)
class PreviewPlan:
    """A plan as the preview draws it.

    Attributes:
        kind: ``dual`` or ``collection``.
        q: joint angles per robot (``R1``, ``R2``) per frame [rad], shape (F, 6) each.
        residual_mm, residual_deg: recorded relative-pose residual per frame [mm], [deg], shape (F,); NaN when
            the plan records none.
        converged: per frame whether the planner proved it, shape (F,); None for a collection plan.
        notes: a short status text per frame (``converged``, the planner's reason, the collection target).
        T_wp_gun: the relative pose the dual plan holds (gun in the workpiece frame) [mm]; None for a
            collection plan.
    """

    kind: str
    q: dict[str, np.ndarray]
    residual_mm: np.ndarray
    residual_deg: np.ndarray
    converged: np.ndarray | None
    notes: tuple[str, ...]
    T_wp_gun: np.ndarray | None = None

    @property
    def n_frames(self) -> int:
        return len(self.notes)


def read_preview_plan(plan: Any) -> PreviewPlan:
    """Read a dual or collection plan for drawing.

    A dual plan draws both arms per waypoint; a collection plan moves its arm target by target while the
    other keeps its previous configuration (home, q = 0, at the start).

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
        w = plan.waypoints
        if not w:
            raise DataError("<plan>", None, None, "the plan has no waypoints")
        return PreviewPlan("dual", {"R1": np.array([x.q_R1 for x in w]), "R2": np.array([x.q_R2 for x in w])},
                           np.array([x.residual_mm for x in w]), np.array([x.residual_deg for x in w]),
                           np.array([x.converged for x in w]),
                           tuple("converged" if x.converged else f"NOT converged: {x.reason}" for x in w),
                           np.asarray(plan.T_wp_gun, dtype=float))
    current = {"R1": np.zeros(6), "R2": np.zeros(6)}
    q: dict[str, list[np.ndarray]] = {"R1": [], "R2": []}
    notes = []
    for i, t in enumerate(plan.targets):
        if t.robot not in current:
            raise DataError("<plan>", None, None, f"entry {i}: unknown robot {t.robot!r}; valid: R1, R2")
        current[t.robot] = np.asarray(t.q, dtype=float)
        for name in q:
            q[name].append(current[name].copy())
        notes.append(f"{t.robot} target {i} ({t.kind}, cluster {t.cluster})")
    if not notes:
        raise DataError("<plan>", None, None, "the plan has no waypoints")
    nan = np.full(len(notes), np.nan)
    return PreviewPlan("collection", {k: np.array(v) for k, v in q.items()}, nan, nan.copy(), None, tuple(notes))


def plan_frames(plan: Any) -> list[dict[str, np.ndarray]]:
    """Frames of a dual or collection plan: one ``{"R1": q (6,), "R2": q (6,)}`` per waypoint [rad].

    Raises:
        DataError: as :func:`read_preview_plan`.
    """
    p = read_preview_plan(plan)
    return [{name: p.q[name][f].copy() for name in ("R1", "R2")} for f in range(p.n_frames)]


def _limit_margin(cell: CellSpec, plan: PreviewPlan) -> tuple[float, tuple[int, str, int]]:
    """Refuse a plan with a joint beyond its limit, as export-targets does (a preview must not show what the
    controller would never be sent); otherwise the smallest margin to a limit [deg] and where it is.

    Raises:
        UnsafeTarget: naming the waypoint, robot, joint, value and limit.
    """
    from calibration.errors import UnsafeTarget

    best: tuple[float, tuple[int, str, int]] = (float("inf"), (0, "R1", 1))
    for name in ("R1", "R2"):
        spec = cell.robot(name).robot
        q = plan.q[name]
        bad = (q < spec.lower_rad) | (q > spec.upper_rad)
        if bad.any():
            i, j = (int(v) for v in np.argwhere(bad)[0])
            limit = spec.lower_rad[j] if q[i, j] < spec.lower_rad[j] else spec.upper_rad[j]
            raise UnsafeTarget(name, j + 1, float(q[i, j]), float(limit), f"waypoint {i} of the plan is beyond the "
                                                                          "joint limits; not drawn")
        margin = np.degrees(np.minimum(q - spec.lower_rad, spec.upper_rad - q))
        i, j = np.unravel_index(int(np.argmin(margin)), margin.shape)
        if margin[i, j] < best[0]:
            best = (float(margin[i, j]), (int(i), name, int(j) + 1))
    return best


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
                    cmds.append('fetch("data:application/octet-binary;base64,%s").then(r => r.arrayBuffer())'
                                ".then(b => viewer.handle_command_bytearray(new Uint8Array(b)));"
                                % base64.b64encode(blob).decode())
        return ("<!DOCTYPE html>\n<html><head><meta charset=utf-8><title>cellcal preview</title>"
                "<style>body{margin:0}#meshcat-pane{width:100vw;height:100vh;overflow:hidden}</style></head>"
                f"<body><div id=\"meshcat-pane\"></div><script>{js}</script><script>"
                "var viewer = new MeshCat.Viewer(document.getElementById(\"meshcat-pane\"));\n"
                + "\n".join(cmds) + f"</script>{self.overlay}</body></html>")


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


def _flange_poses(cell: CellSpec, T_cell_tool: np.ndarray, name: str) -> np.ndarray:
    """Flange poses (F, 4, 4) [m] from tool poses [m] and the cell's tool transform (tool in the flange frame)."""
    tool = cell.robot(name).tool
    T_flange_tool = np.eye(4)
    T_flange_tool[:3, :3], T_flange_tool[:3, 3] = tool.R_flange_tool, tool.p_flange_tool * 1e-3
    return T_cell_tool @ np.linalg.inv(T_flange_tool)


def _capsule_transforms(seg_m: np.ndarray) -> dict[str, np.ndarray]:
    """meshcat transforms of one capsule (cylinder + two end spheres) spanning seg_m (2, 3) [m]."""
    import meshcat.transformations as tf

    return {"": _segment_transform(seg_m[0], seg_m[1]), "_end0": tf.translation_matrix(seg_m[0]),
            "_end1": tf.translation_matrix(seg_m[1])}


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
        from app.dual.meshcat_server import start

        _, zmq_url, _ = start(overlay)  # web server on 127.0.0.1 only (meshcat's own listens on every interface)
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
    top["/Cameras/default/rotated/<object>"].set_property("position", [0.0, 0.8, 2.2])
    vis = top["cellcal"]  # the viewer orbits the origin: centre the cell on it
    vis.set_transform(tf.translation_matrix([-1.4, 0.2, -0.4]))
    vis["cell/floor"].set_object(g.Box([4.2, 2.4, 0.02]), g.MeshLambertMaterial(color=0x9E9E8E))
    vis["cell/floor"].set_transform(tf.translation_matrix([1.35, -0.2, capsules.floor_z_mm * 1e-3 - 0.01]))
    return top, vis


def _draw_carried(vis: Any, cell: CellSpec, name: str) -> None:
    """What the arm carries (the tool YAML's ``geometry``, flange frame [mm]) under ``{name}/flange``."""
    import meshcat.geometry as g
    import meshcat.transformations as tf

    mat = g.MeshPhongMaterial(color=CARRIED_COLORS[name])
    for shape in cell.robot(name).tool.shapes:
        node = vis[f"{name}/flange/{shape.name}"]
        if shape.kind == "cylinder":
            a, b = shape.from_mm * 1e-3, shape.to_mm * 1e-3
            r_from, r_to = (r * 1e-3 for r in shape.radius_mm)
            node.set_object(g.Cylinder(float(np.linalg.norm(b - a)), radiusTop=r_to, radiusBottom=r_from), mat)
            node.set_transform(_segment_transform(a, b))
        else:
            node.set_object(g.Box((shape.size_mm * 1e-3).tolist()), mat)
            node.set_transform(tf.translation_matrix(shape.centre_mm * 1e-3))


def _text(text: str, width_m: float) -> Any:
    """A square plane showing ``text`` (meshcat viewer's ``_text`` canvas texture; meshcat-python 0.3 has no
    SceneText), facing -y of its parent frame with +z up."""
    import meshcat.geometry as g

    class TextTexture(g.Texture):
        def lower(self, object_data: Any) -> dict[str, Any]:
            return {"uuid": self.uuid, "type": "_text", "text": text, "font_size": 64, "font_face": "sans-serif"}

    class Plane(g.Geometry):
        def lower(self, object_data: Any) -> dict[str, Any]:
            return {"uuid": self.uuid, "type": "PlaneGeometry", "width": width_m, "height": width_m,
                    "widthSegments": 1, "heightSegments": 1}

        def intrinsic_transform(self) -> np.ndarray:  # the plane's normal (+z) to -y, its up (+y) to +z
            R = np.array([[1.0, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]])
            return R.T  # meshcat flattens row by row, three.js reads the list column by column

    return g.Mesh(Plane(), g.MeshBasicMaterial(map=TextTexture(), transparent=True))


def _draw_labels(vis: Any, cell: CellSpec) -> None:
    """R1/R2 name plates above each arm's base."""
    import meshcat.transformations as tf

    for name, text in LABELS.items():
        p_m = cell.robot(name).T_cell_base[:3, 3] * 1e-3 + np.array([0.0, 0.0, 1.45])
        vis[f"labels/{name}"].set_object(_text(text, 0.7))
        vis[f"labels/{name}"].set_transform(tf.translation_matrix(p_m))


def _polyline(points_m: np.ndarray, color: int, point_size_m: float) -> tuple[Any, Any]:
    """A line through points (N, 3) [m] and a dot at each, as two meshcat objects."""
    import meshcat.geometry as g

    xyz = np.asarray(points_m, dtype=np.float32).T
    rgb = np.array([(color >> 16) & 255, (color >> 8) & 255, color & 255], dtype=np.float32) / 255.0
    pts = g.PointsGeometry(xyz, np.repeat(rgb[:, None], xyz.shape[1], axis=1))  # meshcat's points use vertex colours
    return (g.Line(pts, g.LineBasicMaterial(color=color)),
            g.Points(pts, g.PointsMaterial(size=point_size_m, color=color)))


def _draw_traces(vis: Any, plan: PreviewPlan, tools: dict[str, np.ndarray]) -> None:
    """The path trace: the gun's and the workpiece's tool points over the plan (cell frame), and, in the
    workpiece frame (moving with R2's tool), the relative pose's target point and where the gun actually was.

    Args:
        vis: the cellcal node (cell frame).
        plan: the plan (``T_wp_gun`` for the target).
        tools: tool poses per robot in the cell frame, shape (F, 4, 4) [m].
    """
    for key, name in (("gun", "R1"), ("workpiece", "R2")):
        line, dots = _polyline(tools[name][:, :3, 3], TRACE_COLORS[key], 0.025)
        vis[f"trace/{key}/line"].set_object(line)
        vis[f"trace/{key}/points"].set_object(dots)
    if plan.T_wp_gun is not None:
        p_wp_gun = np.einsum("fij,fj->fi", np.linalg.inv(tools["R2"]), np.c_[tools["R1"][:, :3, 3],
                                                                              np.ones(plan.n_frames)])[:, :3]
        line, dots = _polyline(p_wp_gun, TRACE_COLORS["gun"], 0.012)
        vis["R2/tool/gun_path/line"].set_object(line)
        vis["R2/tool/gun_path/points"].set_object(dots)
        _, target = _polyline(plan.T_wp_gun[None, :3, 3] * 1e-3, TRACE_COLORS["target"], 0.04)
        vis["R2/tool/target"].set_object(target)


def _draw_arm(vis: Any, anim: Any, cell: CellSpec, capsules: CellCapsules, name: str, q: np.ndarray,
              model: Any) -> np.ndarray:
    """One arm's capsules, what it carries and its tool triad, animated over its joint angles q [rad] (F, 6).

    Returns:
        The tool poses in the cell frame, shape (F, 4, 4) [m].
    """
    import meshcat.geometry as g

    segs = capsules.segments(name, q, model) * 1e-3  # (F, 6, 2, 3) [m]
    tools = _tool_poses(cell, model, name, q)
    flanges = _flange_poses(cell, tools, name)
    mat = g.MeshPhongMaterial(color=COLORS[name])
    for k, seg in enumerate(SEGMENTS):
        r = float(capsules.radii(name)[k]) * 1e-3
        length = float(np.linalg.norm(segs[0, k, 1] - segs[0, k, 0]))
        vis[f"{name}/capsules/{seg}"].set_object(g.Cylinder(length, r), mat)
        vis[f"{name}/capsules/{seg}_end0"].set_object(g.Sphere(r), mat)
        vis[f"{name}/capsules/{seg}_end1"].set_object(g.Sphere(r), mat)
    vis[f"{name}/tool"].set_object(g.triad(0.15))
    _draw_carried(vis, cell, name)
    for f in range(len(q)):
        with anim.at_frame(vis, f) as af:
            for k, seg in enumerate(SEGMENTS):
                for suffix, T in _capsule_transforms(segs[f, k]).items():
                    af[f"{name}/capsules/{seg}{suffix}"].set_transform(T)
            af[f"{name}/tool"].set_transform(tools[f])
            af[f"{name}/flange"].set_transform(flanges[f])
    # the first frame as static transforms too, so the page shows the arms before the clip starts
    for k, seg in enumerate(SEGMENTS):
        for suffix, T in _capsule_transforms(segs[0, k]).items():
            vis[f"{name}/capsules/{seg}{suffix}"].set_transform(T)
    vis[f"{name}/tool"].set_transform(tools[0])
    vis[f"{name}/flange"].set_transform(flanges[0])
    return tools


def preview(cell: CellSpec, plan: Any, html_out: str | Path | None = None, serve: bool = False,
            models: dict[str, Any] | None = None, fps: float = 10.0) -> PreviewResult:
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

    Returns:
        The :class:`PreviewResult`.

    Raises:
        DataError: the plan is malformed. UnsafeTarget: a joint beyond its limit. ModelError: neither
        ``html_out`` nor ``serve`` was asked for.
    """
    import meshcat
    from meshcat.animation import Animation

    from app.dual.preview_readout import readout_data, readout_html
    from calibration.errors import ModelError

    if html_out is None and not serve:
        raise ModelError("preview needs html_out (a static page) or serve=True (a live viewer)")
    p = read_preview_plan(plan)
    margin, margin_at = _limit_margin(cell, p)
    models = models or {n: cell.robot(n).model() for n in ("R1", "R2")}
    capsules = CellCapsules(cell)
    overlay = readout_html(readout_data({n: np.degrees(p.q[n]) for n in ("R1", "R2")}, p.residual_mm,
                                        p.residual_deg, p.converged, list(p.notes), fps), {**COLORS, **TRACE_COLORS})
    windows, url = _windows(html_out is not None, serve, overlay)
    for window in windows:
        top, vis = _scene(window, capsules)
        anim = Animation(default_framerate=fps)
        tools = {name: _draw_arm(vis, anim, cell, capsules, name, p.q[name], models[name]) for name in ("R1", "R2")}
        _draw_traces(vis, p, tools)
        _draw_labels(vis, cell)
        top.set_animation(anim, play=False, repetitions=1)  # the readout opens it at waypoint 0; "play" runs it
    path = None
    if html_out is not None:
        path = Path(html_out)
        atomic_write_text(path, meshcat.Visualizer(window=windows[0]).static_html())
        logger.info("wrote preview of %d frames to %s", p.n_frames, path)

    def worst(a: np.ndarray) -> float | None:
        return float(np.nanmax(a)) if np.isfinite(a).any() else None

    return PreviewResult(p.n_frames, path, url, p.kind, worst(p.residual_mm), worst(p.residual_deg), margin,
                         margin_at)
