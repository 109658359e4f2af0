"""Headless Chromium for the tests that render a page (the preview, the acceptance report): a screenshot, or
the DOM after the page's scripts ran.

Set ``CELLCAL_SCREENSHOT_DIR=DIR`` to keep every screenshot there, so a person can look at them.
"""

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
    """The browser, or skip the test naming the ones tried."""
    browser = find_browser()
    if browser is None:
        pytest.skip(f"no headless browser found (tried {', '.join(BROWSERS)}); apt-get install chromium")
    return browser


def run_browser(work: Path, url: str, *mode: str, size: tuple[int, int] = (1024, 768), budget_ms: int = 5000,
                timeout_s: float = 90.0) -> str:
    """Run headless Chromium on ``url`` with ``mode`` (``--screenshot=F`` or ``--dump-dom``); its stdout.

    WebGL runs through SwiftShader (``--use-angle=swiftshader --enable-unsafe-swiftshader``); with
    ``--disable-gpu`` headless Chromium now and then never exits after the shot. A browser that wrote the
    shot but hung on exit still rendered the page; otherwise a browser that does not finish fails the test.
    """
    browser = browser_or_skip()
    cmd = [browser, "--headless", "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
           "--disable-quic", "--no-first-run", "--disable-background-networking", "--disable-component-update",
           "--disable-sync", f"--user-data-dir={work / 'profile'}", *mode,
           f"--window-size={size[0]},{size[1]}", f"--virtual-time-budget={budget_ms}", url]
    log, out = work / "browser.log", work / "browser.out"
    with open(log, "w") as err, open(out, "w") as stdout:  # no pipes: chromium's helpers would keep them open
        proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=stdout, stderr=err, start_new_session=True)
        try:
            proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)  # the browser we started, and its helpers
            proc.wait()
            shot = [m[len("--screenshot="):] for m in mode if m.startswith("--screenshot=")]
            if not (shot and os.path.exists(shot[0])):
                pytest.fail(f"headless browser did not finish in {timeout_s:g} s: {log.read_text()[-1000:]}")
    return out.read_text()


def screenshot_and_dom(work: Path, url: str, name: str, size: tuple[int, int] = (1024, 768),
                       budget_ms: int = 5000, extra: tuple[str, ...] = ()) -> tuple[Path, str]:
    """A PNG screenshot of ``url`` as ``work/name`` (kept in ``$CELLCAL_SCREENSHOT_DIR`` too when set) and the DOM
    after the page's scripts ran, from one browser run (each run costs seconds of a core: SwiftShader WebGL)."""
    png = work / name
    dom = run_browser(work, url, f"--screenshot={png}", "--dump-dom", *extra, size=size, budget_ms=budget_ms)
    assert png.exists(), (work / "browser.log").read_text()[-2000:]
    keep = os.environ.get("CELLCAL_SCREENSHOT_DIR")  # to look at them: CELLCAL_SCREENSHOT_DIR=DIR pytest ...
    if keep:
        os.makedirs(keep, exist_ok=True)
        shutil.copy(png, os.path.join(keep, name))
    return png, dom


def screenshot_dom_pdf(work: Path, url: str, name: str, size: tuple[int, int] = (1280, 800),
                       budget_ms: int = 3000) -> tuple[Path, str, Path]:
    """One browser run: a first-screen PNG ``work/name`` (see :func:`screenshot_and_dom`), the DOM after the page's
    scripts ran and the page printed to PDF (``work/name`` with ``.pdf``, no header or footer, the page's own
    ``@page`` size). Chromium prints before it takes the shot, so the shot shows the page as printed (what the print
    stylesheet's script unfolded stays open); the DOM positions of the sign-off parts are read on load, before."""
    pdf = work / Path(name).with_suffix(".pdf").name
    png, dom = screenshot_and_dom(work, url, name, size, budget_ms, extra=(f"--print-to-pdf={pdf}",
                                                                           "--no-pdf-header-footer"))
    assert pdf.exists(), (work / "browser.log").read_text()[-2000:]
    return png, dom, pdf


def screenshot(work: Path, url: str, name: str, size: tuple[int, int] = (1024, 768), budget_ms: int = 5000) -> Path:
    """A PNG screenshot of ``url`` as ``work/name`` (see :func:`screenshot_and_dom`)."""
    return screenshot_and_dom(work, url, name, size, budget_ms)[0]
