"""Headless Chromium for the tests that render a page: a screenshot, or the DOM after the page's scripts ran."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
from pathlib import Path

import pytest

BROWSERS = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


def find_browser() -> str | None:
    """The first headless-capable browser on PATH, or None."""
    for name in BROWSERS:
        path = shutil.which(name)
        if path:
            return path
    return None


def browser_or_skip() -> str:
    """The browser, or skip the test with the names tried."""
    browser = find_browser()
    if browser is None:
        pytest.skip(f"no headless browser found (tried {', '.join(BROWSERS)}); apt-get install chromium")
    return browser


def run_headless(page: Path, work: Path, *, screenshot: Path | None = None, dump_dom: bool = False,
                 size: tuple[int, int] = (1024, 768), budget_ms: int = 5000, timeout_s: float = 90.0) -> str:
    """Open ``page`` in headless Chromium: write a screenshot, or return the DOM (``--dump-dom``).

    WebGL goes through SwiftShader: with --disable-gpu, headless Chromium now and then never exits after the
    shot. A browser that wrote the shot but hung on exit still rendered the page; otherwise the test fails.
    """
    browser = browser_or_skip()
    cmd = [browser, "--headless", "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
           "--disable-quic", "--no-first-run", "--disable-background-networking", "--disable-component-update",
           "--disable-sync", f"--user-data-dir={work / 'profile'}", f"--window-size={size[0]},{size[1]}",
           f"--virtual-time-budget={budget_ms}"]
    cmd += [f"--screenshot={screenshot}"] if screenshot is not None else []
    cmd += ["--dump-dom"] if dump_dom else []
    log, dom = work / "browser.log", work / "dom.html"
    # files, no pipes: chromium's helpers would keep them open and block the wait
    with open(log, "w") as err, open(dom, "w") as out:
        proc = subprocess.Popen(cmd + [page.as_uri()], stdin=subprocess.DEVNULL, stdout=out, stderr=err,
                                start_new_session=True)
        try:
            proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)  # the browser we started, and its helpers
            proc.wait()
            done = screenshot.exists() if screenshot is not None else dom.stat().st_size > 0
            if not done:
                pytest.fail(f"headless browser did not finish in {timeout_s:g} s: {log.read_text()[-1000:]}")
    if screenshot is not None:
        assert screenshot.exists(), log.read_text()[-2000:]
    return dom.read_text()
