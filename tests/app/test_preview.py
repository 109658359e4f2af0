"""meshcat preview: plan reading, a self-contained static page, and a real render in headless Chromium."""

from __future__ import annotations

import json
import os
import re

import numpy as np
import pytest

pytest.importorskip("meshcat")

from app.dual.preview import plan_frames, preview  # noqa: E402
from calibration.errors import DataError, ModelError  # noqa: E402
from cell_config.loader import load_cell  # noqa: E402
from tests.app.browser import browser_or_skip, run_headless  # noqa: E402


@pytest.fixture(scope="module")
def cell():
    return load_cell()


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
    np.testing.assert_array_equal(frames[1]["R2"], np.zeros(6))  # the other arm stays home


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


def test_browser_renders_both_arms(cell, tmp_path):
    import matplotlib.image as mpimg

    out, png = tmp_path / "preview.html", tmp_path / "shot.png"
    browser_or_skip()
    preview(cell, _dual_plan(), html_out=out)
    run_headless(out, tmp_path, screenshot=png)
    img = mpimg.imread(png)[..., :3]
    assert img.shape == (768, 1024, 3)
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    coloured = (img.max(-1) - img.min(-1)) > 0.25  # the background, floor and grid are grey
    assert coloured.mean() > 0.01, f"only {coloured.mean():.2%} coloured pixels: the scene was not drawn"
    orange = ((r > 0.7) & (g > 0.3) & (g < 0.65) & (b < 0.3)).sum()
    blue = ((b > 0.55) & (r < 0.3) & (g > 0.3) & (g < 0.65)).sum()
    assert orange > 1000 and blue > 1000, (orange, blue)  # R1 and R2 both drawn


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
