"""meshcat preview: plan reading, a self-contained static page, and a real render in headless Chromium."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import time

import numpy as np
import pytest

pytest.importorskip("meshcat")

from app.collection.runtime.sim import park_q  # noqa: E402
from app.dual.preview.page import preview
from app.dual.preview.plan import plan_frames  # noqa: E402
from calibration.errors import DataError, ModelError  # noqa: E402
from cell_config.loader import load_cell  # noqa: E402
from tests.app.browser import screenshot_and_dom  # noqa: E402


@pytest.fixture(scope="module")
def cell():
    return load_cell()


@pytest.fixture(scope="module")
def real_plan(cell, tmp_path_factory):
    """A plan file written by the dual planner (8 waypoints of the default sweep, residuals recorded)."""
    from app.collection.plans.dual import save_plan
    from app.dual.paths import plan_dual
    from app.dual.planner import PlannerOptions

    path = tmp_path_factory.mktemp("plan") / "plan.json"
    plan = plan_dual(cell, n=8, options=PlannerOptions(compile="off"))
    assert plan.converged
    save_plan(plan, path)
    return path


def _dual_plan(n: int = 12) -> dict:
    s = np.linspace(0.0, 1.0, n)[:, None]
    q1 = np.radians([0, 15, 5, 0, 30, 0]) + s * np.radians([-10, 10, -30, 10, 50, -15])
    q2 = np.radians([-5, -5, 5, -10, -35, 10]) + s * np.radians([15, 30, -10, 20, 15, -20])
    return {"schema": "cellcal.plan/1", "waypoints": [{"R1": a.tolist(), "R2": b.tolist()} for a, b in zip(q1, q2)]}


def test_load_dual_and_collection_plans(tmp_path):
    p = tmp_path / "plan.json"
    p.write_text(json.dumps(_dual_plan(3)))
    frames = plan_frames(p)
    assert len(frames) == 3 and frames[2]["R1"].shape == (6,)
    coll = {"schema": "cellcal.plan/1", "kind": "collection",
            "targets": [_target("R1", [0.1] * 6), _target("R1", [0.2] * 6)]}
    frames = plan_frames(coll)
    assert len(frames) == 2
    np.testing.assert_array_equal(frames[1]["R1"], [0.2] * 6)
    np.testing.assert_array_equal(frames[1]["R2"], park_q("R2"))  # the other arm stays parked, as plan checked it


def _target(robot: str, q: list) -> dict:
    return {"robot": robot, "q_rad": q, "cluster": 0, "kind": "anchor"}


PLAN = {"schema": "cellcal.plan/1"}


@pytest.mark.parametrize("plan, message", [
    ({"schema": "x"}, "expected a plan with 'waypoints'"),
    ({**PLAN, "kind": "weld"}, "unknown plan kind 'weld'; valid: collection, dual"),
    ({**PLAN, "targets": [_target("R3", [0] * 6)]}, "unknown robot 'R3'; valid: R1, R2"),
    ({**PLAN, "targets": [_target("R1", [0] * 5)]}, "6 finite numbers"),
    ({**PLAN, "waypoints": [{"R1": [0, 0, 0, 0, 0, "a"], "R2": [0] * 6}]}, "6 finite numbers"),
    ({**PLAN, "waypoints": [{"foo": 1}]}, "names no robot"),
    ({**PLAN, "waypoints": []}, "no waypoints"),
])
def test_bad_plans_are_refused_and_nothing_is_written(cell, tmp_path, plan, message):
    out = tmp_path / "p.html"
    with pytest.raises(DataError, match=re.escape(message)):
        preview(cell, plan, html_out=out)
    assert not out.exists()


@pytest.mark.parametrize("plan", [{**PLAN, "waypoints": []}, {**PLAN, "kind": "collection", "targets": []}],
                         ids=["dual", "collection"])
def test_an_empty_plan_file_is_named_in_the_message(cell, tmp_path, plan):
    """The message said '<plan>: the plan has no waypoints' for a file given by its path."""
    path = tmp_path / "empty_plan.json"
    path.write_text(json.dumps(plan))
    with pytest.raises(DataError, match=re.escape(f"{path}: the plan has no waypoints")):
        preview(cell, path, html_out=tmp_path / "p.html")
    assert not (tmp_path / "p.html").exists()


def test_missing_plan_file(tmp_path):
    with pytest.raises(DataError, match="plan file not found"):
        plan_frames(tmp_path / "nope.json")


def test_preview_needs_an_output(cell):
    with pytest.raises(ModelError, match="html_out"):
        preview(cell, _dual_plan(2))


def test_static_page_is_self_contained(cell, tmp_path):
    out = tmp_path / "preview.html"
    r = preview(cell, _dual_plan(), html_out=out)
    assert r.n_frames == 12 and r.html_path == out
    html = out.read_text()
    assert "MeshCat.Viewer" in html and html.count("data:application/octet-binary;base64,") > 20
    assert not re.search(r"<script[^>]+src=|<link[^>]+href=", html)  # nothing loaded from elsewhere
    urls = set(re.findall(r"https?://[^\s\"'()\\]+", html))
    assert urls <= {"http://www.w3.org/1999/xhtml"}, urls  # a namespace name, never fetched


class _Recording:
    """Draw into a recording window and keep it, to read back what the page holds."""

    def __init__(self, monkeypatch):
        import app.dual.preview.page as preview_mod

        self.windows = []
        outer = self

        class Recording(preview_mod.RecordingWindow):
            def __init__(self):
                super().__init__()
                outer.windows.append(self)

        monkeypatch.setattr(preview_mod, "RecordingWindow", Recording)

    def object(self, path: str) -> dict:
        import umsgpack

        return umsgpack.unpackb(self.windows[0].nodes[f"/meshcat/cellcal/{path}"]["object"])["object"]


def _positions(obj: dict) -> np.ndarray:
    """Vertex positions (N, 3) of a recorded Line/Points object."""
    import umsgpack

    attr = obj["geometries"][0]["data"]["attributes"]["position"]
    array = attr["array"]
    data = array.data if isinstance(array, umsgpack.Ext) else array
    return np.frombuffer(data, dtype=np.float32).reshape(-1, 3)


def test_gun_and_workpiece_are_drawn_from_the_tool_yaml(cell, tmp_path, monkeypatch):
    """Issue 12: the carried geometry comes from the tool YAMLs' `geometry`, not from the preview's code."""
    import dataclasses

    from cell_config.loader import ToolShape

    rec = _Recording(monkeypatch)
    preview(cell, _dual_plan(2), html_out=tmp_path / "a.html")
    for name in ("R1", "R2"):
        for shape in cell.robot(name).tool.shapes:
            geom = rec.object(f"{name}/flange/{shape.name}")["geometries"][0]
            if shape.kind == "cylinder":
                assert geom["type"] == "CylinderGeometry"
                assert geom["height"] == pytest.approx(np.linalg.norm(shape.to_mm - shape.from_mm) * 1e-3)
                assert (geom["radiusBottom"], geom["radiusTop"]) == pytest.approx(np.array(shape.radius_mm) * 1e-3)
            else:
                assert geom["type"] == "BoxGeometry"
                assert [geom["width"], geom["height"], geom["depth"]] == pytest.approx(shape.size_mm * 1e-3)
    # another tool file, another drawing
    r1 = cell.robot("R1")
    wide = ToolShape("can", "cylinder", np.zeros(3), np.array([0.0, 0.0, 500.0]), (80.0, 80.0))
    other = dataclasses.replace(cell, robots={**cell.robots, "R1": dataclasses.replace(
        r1, tool=dataclasses.replace(r1.tool, shapes=(wide,)))})
    rec = _Recording(monkeypatch)
    preview(other, _dual_plan(2), html_out=tmp_path / "b.html")
    geom = rec.object("R1/flange/can")["geometries"][0]
    assert geom["height"] == pytest.approx(0.5) and geom["radiusTop"] == pytest.approx(0.08)
    assert "/meshcat/cellcal/R1/flange/barrel" not in rec.windows[0].nodes


def test_labels_and_path_traces(cell, real_plan, tmp_path, monkeypatch):
    """Issue 12: R1/R2 name plates; the gun's and the workpiece's tool-point paths over the plan (cell frame);
    in the workpiece frame the relative pose's target, where the planner's gun sits to its residual."""
    rec = _Recording(monkeypatch)
    preview(cell, real_plan, html_out=tmp_path / "p.html")
    for name, text in (("R1", "R1 gun"), ("R2", "R2 workpiece")):
        textures = rec.object(f"labels/{name}")["textures"]
        assert [t["text"] for t in textures] == [text] and textures[0]["type"] == "_text"
    d = json.loads(real_plan.read_text())
    for key, name in (("gun", "R1"), ("workpiece", "R2")):
        q = np.array([w[name] for w in d["waypoints"]])
        R, p = cell.robot(name).model().fk(q)
        T = cell.robot(name).T_cell_base
        p_cell_m = (p @ T[:3, :3].T + T[:3, 3]) * 1e-3
        for part in ("line", "points"):
            np.testing.assert_allclose(_positions(rec.object(f"trace/{key}/{part}")), p_cell_m, atol=1e-6)
    target = _positions(rec.object("R2/tool/target"))
    np.testing.assert_allclose(target, np.array(d["T_wp_gun"])[None, :3, 3] * 1e-3, atol=1e-7)
    gun_in_wp = _positions(rec.object("R2/tool/gun_path/points"))
    assert len(gun_in_wp) == len(d["waypoints"])
    np.testing.assert_allclose(gun_in_wp, np.repeat(target, len(gun_in_wp), axis=0), atol=2e-6)  # float32 in m


def _embedded_readout(html: str) -> dict:
    m = re.search(r'<script type="application/json" id="cellcal-readout">(.*?)</script>', html, re.S)
    assert m, "no readout data in the page"
    return json.loads(m.group(1))


def test_readout_embeds_the_plan_files_numbers(cell, real_plan, tmp_path):
    out = tmp_path / "p.html"
    preview(cell, real_plan, html_out=out, fps=5.0)
    data, d = _embedded_readout(out.read_text()), json.loads(real_plan.read_text())
    assert data["fps"] == 5.0 and data["converged"] == [True] * len(d["waypoints"])
    for arm in ("R1", "R2"):
        np.testing.assert_allclose(data["q_deg"][arm], np.degrees([w[arm] for w in d["waypoints"]]), rtol=1e-12)
    assert data["residual_mm"] == [w["residual_mm"] for w in d["waypoints"]]
    assert data["residual_deg"] == [w["residual_deg"] for w in d["waypoints"]]
    assert 'id="wp-slider"' in out.read_text() and 'id="wp-next"' in out.read_text()


def test_readout_of_a_plan_without_residuals_says_not_recorded(cell, tmp_path):
    coll = {"schema": "cellcal.plan/1", "kind": "collection",
            "targets": [_target("R1", [0.1] * 6), _target("R2", [0.2] * 6)]}
    out = tmp_path / "p.html"
    r = preview(cell, coll, html_out=out)
    data = _embedded_readout(out.read_text())
    assert data["residual_mm"] == [None, None] and data["converged"] == [None, None]
    assert data["note"] == ["R1 target 0 (anchor, cluster 0)", "R2 target 1 (anchor, cluster 0)"]
    np.testing.assert_allclose(data["q_deg"]["R1"][1], np.degrees([0.1] * 6))  # R1 stays where it was
    assert r.kind == "collection" and r.max_residual_mm is None
    assert "/meshcat/cellcal/R2/tool/target" not in out.read_text()  # no relative pose to show


def test_readout_flags_a_waypoint_the_planner_did_not_prove(cell, real_plan, tmp_path):
    d = json.loads(real_plan.read_text())
    d["waypoints"][2].update(converged=False, reason="clearance 31 mm < 50 mm")
    del d["waypoints"][3]["converged"]  # not marked: unsolved, as every reader treats it
    out = tmp_path / "p.html"
    preview(cell, d, html_out=out)
    data = _embedded_readout(out.read_text())
    assert data["converged"][1:4] == [True, False, False]
    assert data["note"][2] == "NOT converged: clearance 31 mm < 50 mm"
    assert data["note"][3] == "NOT converged: not marked converged"


def test_cli_preview_json_summary(cell, real_plan, tmp_path, capsys):
    from app.cli import main

    out, summary = tmp_path / "p.html", tmp_path / "s.json"
    assert main(["preview", "--plan", str(real_plan), "--html", str(out), "--json", str(summary)]) == 0
    s, d = json.loads(summary.read_text()), json.loads(real_plan.read_text())
    assert s["waypoints"] == len(d["waypoints"]) and s["kind"] == "dual" and s["files"] == [str(out)]
    assert s["max_residual_mm"] == max(w["residual_mm"] for w in d["waypoints"])
    assert s["max_residual_deg"] == max(w["residual_deg"] for w in d["waypoints"])
    margins = []
    for arm in ("R1", "R2"):
        spec = cell.robot(arm).robot
        q = np.array([w[arm] for w in d["waypoints"]])
        margins.append(np.degrees(np.minimum(q - spec.lower_rad, spec.upper_rad - q)).min())
    limits = s["joint_limits"]
    assert limits["checked"] and limits["within"]
    assert limits["min_margin_deg"] == pytest.approx(min(margins), abs=1e-9)
    assert limits["at"]["robot"] == ("R1", "R2")[int(np.argmin(margins))]


def test_cli_preview_json_into_a_folder_writes_nothing(real_plan, tmp_path, capsys):
    from tests.conftest import assert_bad_input

    out = tmp_path / "p.html"
    assert_bad_input(capsys, ["preview", "--plan", str(real_plan), "--html", str(out), "--json", str(tmp_path)],
                     str(tmp_path), "is a folder")
    assert not out.exists()


def _screenshot_and_dom(chromium, tmp_path, page, name: str, fragment: str = ""):
    """The page's screenshot as RGB floats and its DOM after the scripts ran (one page load)."""
    import matplotlib.image as mpimg

    png, dom = screenshot_and_dom(chromium, tmp_path, page.as_uri() + fragment, name)
    img = mpimg.imread(png)[..., :3]
    assert img.shape == (768, 1024, 3)
    return img, dom


def _masks(img) -> dict:
    """Pixels of each colour the preview draws (the background, floor and overlay are grey or white)."""
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    return {"R1 arm": (r > 0.7) & (g > 0.3) & (g < 0.65) & (b < 0.3),  # orange
            "R2 arm": (b > 0.55) & (r < 0.3) & (g > 0.3) & (g < 0.65),  # blue
            "gun": (r > 0.35) & (g < 0.4 * r) & (b < 0.4 * r),  # dark red
            "workpiece": (g > 0.35) & (r < 0.45 * g) & (b < 0.45 * g),  # green
            "gun trace": (r > 0.35) & (b > 0.5) & (g < 0.2),  # violet
            "workpiece trace": (g > 0.4) & (b > 0.45) & (r < 0.2) & (np.abs(g - b) < 0.15)}  # teal


@pytest.fixture(scope="module")
def first_waypoint(cell, real_plan, tmp_path_factory, chromium):
    """The real plan's static page, its screenshot at waypoint 0 and its DOM there (one page load, shared by the
    render and readout tests: the same page in the same state)."""
    work = tmp_path_factory.mktemp("first_waypoint")
    out = work / "preview.html"
    preview(cell, real_plan, html_out=out)
    img, dom = _screenshot_and_dom(chromium, work, out, "shot.png")
    return out, img, dom


def test_browser_renders_the_task(first_waypoint):
    """Issue 12: the page shows both arms, the gun, the workpiece and the path traces (pixels of each colour)."""
    _, img, _ = first_waypoint
    coloured = (img.max(-1) - img.min(-1)) > 0.25
    assert coloured.mean() > 0.01, f"only {coloured.mean():.2%} coloured pixels: the scene was not drawn"
    counts = {k: int(m.sum()) for k, m in _masks(img).items()}
    minimum = {"R1 arm": 1000, "R2 arm": 1000, "gun": 50, "workpiece": 50, "gun trace": 20, "workpiece trace": 20}
    assert all(counts[k] > n for k, n in minimum.items()), counts


def _readout(dom: str) -> dict:
    """The overlay's texts by element id, from a dumped DOM."""
    from html.parser import HTMLParser

    texts: dict = {}

    class Reader(HTMLParser):
        current = None

        def handle_starttag(self, tag, attrs):
            self.current = dict(attrs).get("id")

        def handle_data(self, data):
            if self.current:
                texts[self.current] = texts.get(self.current, "") + data

        def handle_endtag(self, tag):
            self.current = None

    Reader().feed(dom)
    return texts


def _assert_readout_is_waypoint(texts: dict, plan_file, i: int):
    wp = json.loads(plan_file.read_text())["waypoints"][i]
    assert texts["wp-index"] == str(i) and texts["wp-status"] == "converged"
    for arm in ("R1", "R2"):
        shown = [float(texts[f"q-{arm}-{j}"]) for j in range(1, 7)]
        np.testing.assert_allclose(shown, np.degrees(wp[arm]), atol=5e-4)  # printed to 0.001 deg
    for key, unit in (("res-mm", "residual_mm"), ("res-deg", "residual_deg")):
        assert float(texts[key]) == pytest.approx(wp[unit], rel=5e-3)  # three significant digits


def test_browser_readout_shows_waypoint_0_and_steps_the_animation(first_waypoint, real_plan, tmp_path, chromium):
    """Issue 12: the readout holds waypoint 0's index, joints [deg] and residual from the plan file; stepping
    to another waypoint (the page's address names it, as the slider does) moves the arms and the numbers."""
    out, first, dom = first_waypoint
    last = len(json.loads(real_plan.read_text())["waypoints"]) - 1
    _assert_readout_is_waypoint(_readout(dom), real_plan, 0)
    moved, dom = _screenshot_and_dom(chromium, tmp_path, out, "last.png", f"#waypoint={last}")
    _assert_readout_is_waypoint(_readout(dom), real_plan, last)
    first, moved = _masks(first)["R2 arm"], _masks(moved)["R2 arm"]
    overlap = (first & moved).sum() / (first | moved).sum()
    assert overlap < 0.8, f"R2 drawn in the same place at waypoints 0 and {last} (overlap {overlap:.2f})"


#: The preview page and its viewer have loaded (the clip's actions exist).
VIEWER_READY = ("document.readyState === 'complete' && typeof viewer !== 'undefined' && "
                "viewer.animator.actions.length > 0")


def test_browser_buttons_slider_and_play_step_the_animation(cell, real_plan, tmp_path, chromium):
    """Issue 12: prev/next and the slider seek the clip to a waypoint and show its numbers; play runs the clip
    to its end with the readout following."""
    out = tmp_path / "preview.html"
    preview(cell, real_plan, html_out=out, fps=10.0)
    d = json.loads(real_plan.read_text())
    last = len(d["waypoints"]) - 1
    snaps = chromium.evaluate(out.as_uri(), """(async () => {
      const $ = (id) => document.getElementById(id), sleep = (ms) => new Promise(r => setTimeout(r, ms));
      const out = [], snap = () => out.push({index: $("wp-index").textContent, slider: $("wp-slider").value,
        q: [1, 2, 3, 4, 5, 6].map(j => $("q-R2-" + j).textContent), t: viewer.animator.actions[0].time});
      snap(); $("wp-next").click(); snap(); $("wp-next").click(); snap(); $("wp-prev").click(); snap();
      const s = $("wp-slider"); s.value = 5; s.dispatchEvent(new Event("input")); snap();
      $("wp-play").click(); await sleep(2000); snap();
      return out;
    })()""", ready=VIEWER_READY)
    expected = [0, 1, 2, 1, 5, last]
    assert [int(x["index"]) for x in snaps] == expected and [int(x["slider"]) for x in snaps] == expected
    for snap, i in zip(snaps, expected):
        np.testing.assert_allclose([float(v) for v in snap["q"]], np.degrees(d["waypoints"][i]["R2"]), atol=5e-4)
        assert snap["t"] == pytest.approx(i / 10.0, abs=1e-6)  # the clip sits on the waypoint shown


def _listening(port: int) -> list[str]:
    """Local addresses (hex, as /proc/net shows them) of the sockets listening on ``port``."""
    found = []
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        try:
            lines = open(table).read().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            local, state = line.split()[1], line.split()[3]
            if state == "0A" and int(local.rsplit(":", 1)[1], 16) == port:
                found.append(local.rsplit(":", 1)[0])
    return found


@pytest.mark.skipif(not os.path.exists("/proc/net/tcp"), reason="needs /proc/net/tcp to see the listening sockets")
def test_the_live_viewer_listens_on_loopback_only(cell):
    """Issue 12: `preview --serve` listened on 0.0.0.0:7000 (meshcat's own web server binds every interface)."""
    result = preview(cell, _dual_plan(3), serve=True)
    port = int(re.search(r":(\d+)/", result.url).group(1))
    addresses = _listening(port)
    assert addresses and set(addresses) == {"0100007F"}, addresses  # 127.0.0.1 and nothing else
    assert result.url.startswith("http://127.0.0.1:")


def test_a_plan_beyond_the_joint_limits_is_refused_like_export_targets(cell, tmp_path):
    """Issue 12: preview drew plans with joints outside the limits that export-targets refuses."""
    from calibration.errors import UnsafeTarget

    plan = _dual_plan(3)
    plan["waypoints"][1]["R2"][3] = float(np.radians(200.0))  # MA1440 joint 4 stops at 150 deg
    with pytest.raises(UnsafeTarget, match="waypoint 1") as e:
        preview(cell, plan, html_out=tmp_path / "p.html")
    assert e.value.robot == "R2" and e.value.joint == 4
    assert not (tmp_path / "p.html").exists()


def test_the_live_viewer_carries_the_readout(cell, real_plan, chromium):
    """--serve: the live page (our loopback server's) has the same readout, and it steps the live scene."""
    import urllib.request

    result = preview(cell, real_plan, serve=True)
    with urllib.request.urlopen(result.url, timeout=10) as reply:
        page = reply.read().decode()
    data, d = _embedded_readout(page), json.loads(real_plan.read_text())
    np.testing.assert_allclose(data["q_deg"]["R2"], np.degrees([w["R2"] for w in d["waypoints"]]), rtol=1e-12)
    assert "MeshCat.Viewer" in page and "viewer.connect()" in page  # meshcat's own page, extended
    last = len(d["waypoints"]) - 1
    _assert_readout_is_waypoint(_readout(chromium.render(result.url + f"#waypoint={last}")), real_plan, last)


@pytest.mark.parametrize("size", [(600, 1000)])
def test_the_camera_frames_both_arms_in_any_window_shape(cell, real_plan, tmp_path, size, chromium):
    """Issue 34: a portrait window cropped the arms at its sides; the page now fits the camera to the window."""
    import matplotlib.image as mpimg

    out = tmp_path / "preview.html"
    preview(cell, real_plan, html_out=out)
    png, _ = screenshot_and_dom(chromium, tmp_path, out.as_uri(), f"preview_{size[0]}x{size[1]}.png", size=size)
    img = mpimg.imread(png)[..., :3]
    assert img.shape == (size[1], size[0], 3)
    masks = _masks(img)
    edge = max(2, size[0] // 100)  # the outermost 1 % of columns on either side
    for arm in ("R1 arm", "R2 arm"):
        assert masks[arm].sum() > 1000, f"{arm} not drawn"
        cols = np.flatnonzero(masks[arm].any(axis=0))
        assert cols.min() >= edge and cols.max() < size[0] - edge, (arm, cols.min(), cols.max())


def test_serve_keeps_serving_without_a_terminal_until_sigint(real_plan, tmp_path):
    """Issue 34: `preview --serve` waited for Enter and so exited at once when stdin was not a terminal."""
    import sys

    # SIGINT as a terminal delivers it: a suite started as a background job of a non-interactive shell runs with
    # SIGINT ignored, and a child inherits that (as in test_cli.py's Ctrl-C test)
    proc = subprocess.Popen([sys.executable, "-m", "app.cli", "preview", "--plan", str(real_plan), "--serve"],
                            stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        line = ""
        deadline = time.monotonic() + 60
        while "live viewer at" not in line and time.monotonic() < deadline:
            line = proc.stdout.readline()
            assert line or proc.poll() is None, "preview --serve exited before serving"
        assert "live viewer at http://127.0.0.1:" in line
        time.sleep(1.5)
        assert proc.poll() is None, "preview --serve stopped serving with stdin at end of file"
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=20) == 0
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
