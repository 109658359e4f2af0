"""What the preview draws in a meshcat window: the arms, what they carry, name plates and the path traces.

Viewer units are metres; the cellcal node is the cell frame (R1's base), shifted so the viewer orbits the
middle of the cell. meshcat is imported here at the top: only :func:`app.dual.preview.page.preview` imports this
module.
"""

from __future__ import annotations

from typing import Any

import meshcat
import meshcat.geometry as g
import meshcat.transformations as tf
import numpy as np

from app.dual.preview.plan import PreviewPlan
from cell_config.capsules import SEGMENTS, CellCapsules
from cell_config.loader import CellSpec

COLORS = {"R1": 0xFF7F0E, "R2": 0x1F77B4}  # arms: R1 orange (gun), R2 blue (workpiece)
CARRIED_COLORS = {"R1": 0xB03A2E, "R2": 0x2CA02C}  # the gun dark red, the workpiece green
TRACE_COLORS = {"gun": 0x9400D3, "workpiece": 0x00A5B5, "target": 0xE6B800}  # violet, teal, amber
LABELS = {"R1": "R1 gun", "R2": "R2 workpiece"}


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
    T_cell_flange: np.ndarray = T_cell_tool @ np.linalg.inv(T_flange_tool)
    return T_cell_flange


def _capsule_transforms(seg_m: np.ndarray) -> dict[str, np.ndarray]:
    """meshcat transforms of one capsule (cylinder + two end spheres) spanning seg_m (2, 3) [m]."""
    return {"": _segment_transform(seg_m[0], seg_m[1]), "_end0": tf.translation_matrix(seg_m[0]),
            "_end1": tf.translation_matrix(seg_m[1])}


#: Width / height of the window below which the default camera would crop the cell sideways: at 16:9 the arms
#: and their name plates take the middle 64 % of the width (measured on the 8-waypoint default sweep), so below
#: 1.4 (some margin) the page widens the view by camera zoom (:data:`FIT_CAMERA_JS`).
FRAMED_ASPECT = 1.4

#: A script for the viewer page (static or live): fits the camera's field of view to the window at any size, so a
#: portrait window shows the whole cell instead of cropping the arms; on load and on every resize. The zoom of a
#: three.js perspective camera narrows or widens its view about its axis and meshcat never sets it, so it holds
#: whatever the scene commands do to the camera's position.
FIT_CAMERA_JS = (
    "<script>(function () {\n"
    "  function fit() {\n"
    "    if (typeof viewer === 'undefined' || !viewer.camera) { return; }\n"
    "    var aspect = window.innerWidth / Math.max(1, window.innerHeight);\n"
    f"    viewer.camera.zoom = Math.min(1, aspect / {FRAMED_ASPECT});\n"
    "    viewer.camera.updateProjectionMatrix();\n"
    "    viewer.set_dirty();\n"
    "  }\n"
    "  window.addEventListener('resize', fit);\n"
    "  window.addEventListener('load', fit);\n"
    "  fit();\n"
    "})();</script>")


def scene(window: Any, capsules: CellCapsules) -> tuple[Any, Any]:
    """Background, camera and floor in ``window``: ``(viewer, the cellcal node the arms are drawn under)``."""
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
    mat = g.MeshPhongMaterial(color=CARRIED_COLORS[name])
    for shape in cell.robot(name).tool.shapes:
        node = vis[f"{name}/flange/{shape.name}"]
        if shape.kind == "cylinder":
            from_mm, to_mm, radius_mm = shape.cylinder()
            a, b = from_mm * 1e-3, to_mm * 1e-3
            r_from, r_to = (r * 1e-3 for r in radius_mm)
            node.set_object(g.Cylinder(float(np.linalg.norm(b - a)), radiusTop=r_to, radiusBottom=r_from), mat)
            node.set_transform(_segment_transform(a, b))
        else:
            centre_mm, size_mm = shape.box()
            node.set_object(g.Box((size_mm * 1e-3).tolist()), mat)
            node.set_transform(tf.translation_matrix(centre_mm * 1e-3))


class _TextTexture(g.Texture):  # type: ignore[misc]  # meshcat ships no stubs: its classes are Any
    """The meshcat viewer's ``_text`` texture: ``text`` drawn on a 256 x 256 canvas (meshcat-python 0.3 has no
    ``TextTexture``/``SceneText``)."""
    def __init__(self, text: str, font_size: int = 64) -> None:
        super().__init__()
        self.text, self.font_size = text, font_size

    def lower(self, object_data: Any) -> dict[str, Any]:
        return {"uuid": self.uuid, "type": "_text", "text": self.text, "font_size": self.font_size,
                "font_face": "sans-serif"}


class _Plate(g.Geometry):  # type: ignore[misc]  # meshcat ships no stubs: its classes are Any
    """A square plane of side ``width_m`` [m] facing -y of its parent frame (the camera), its up along +z."""
    def __init__(self, width_m: float) -> None:
        super().__init__()
        self.width_m = width_m

    def lower(self, object_data: Any) -> dict[str, Any]:
        return {"uuid": self.uuid, "type": "PlaneGeometry", "width": self.width_m, "height": self.width_m,
                "widthSegments": 1, "heightSegments": 1}

    def intrinsic_transform(self) -> np.ndarray:  # the plane's normal (+z) to -y, its up (+y) to +z
        R = np.array([[1.0, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]])
        return R.T  # meshcat flattens row by row, three.js reads the list column by column


def draw_labels(vis: Any, cell: CellSpec) -> None:
    """R1/R2 name plates above each arm's base."""
    for name, label in LABELS.items():
        p_m = cell.robot(name).T_cell_base[:3, 3] * 1e-3 + np.array([0.0, 0.0, 1.45])
        vis[f"labels/{name}"].set_object(g.Mesh(_Plate(0.7), g.MeshBasicMaterial(map=_TextTexture(label),
                                                                                   transparent=True)))
        vis[f"labels/{name}"].set_transform(tf.translation_matrix(p_m))


def _polyline(points_m: np.ndarray, color: int, point_size_m: float) -> tuple[Any, Any]:
    """A line through points (N, 3) [m] and a dot at each, as two meshcat objects."""
    xyz = np.asarray(points_m, dtype=np.float32).T
    rgb = np.array([(color >> 16) & 255, (color >> 8) & 255, color & 255], dtype=np.float32) / 255.0
    pts = g.PointsGeometry(xyz, np.repeat(rgb[:, None], xyz.shape[1], axis=1))  # meshcat's points use vertex colours
    return (g.Line(pts, g.LineBasicMaterial(color=color)),
            g.Points(pts, g.PointsMaterial(size=point_size_m, color=color)))


def draw_traces(vis: Any, plan: PreviewPlan, tools: dict[str, np.ndarray]) -> None:
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


#: Colour of the markers on unsafe waypoints (:func:`draw_unsafe`).
UNSAFE_COLOR = 0xE00000


def draw_unsafe(vis: Any, tools: dict[str, np.ndarray], frames: np.ndarray) -> None:
    """A large red dot on both tool points of every unsafe waypoint (cell frame); nothing when there is none.

    Args:
        tools: tool poses per robot in the cell frame, shape (F, 4, 4) [m].
        frames: indices of the unsafe waypoints.
    """
    if len(frames) == 0:
        return
    points = np.concatenate([tools[name][frames, :3, 3] for name in ("R1", "R2")])
    _, dots = _polyline(points, UNSAFE_COLOR, 0.06)
    vis["unsafe/points"].set_object(dots)


def draw_arm(vis: Any, anim: Any, cell: CellSpec, capsules: CellCapsules, name: str, q: np.ndarray,
             model: Any) -> np.ndarray:
    """One arm's capsules, what it carries and its tool triad, animated over its joint angles q [rad] (F, 6).

    Returns:
        The tool poses in the cell frame, shape (F, 4, 4) [m].
    """
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
