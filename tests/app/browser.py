"""Headless Chromium for the tests that render a page (the preview, the acceptance report): a screenshot, the DOM
after the page's scripts ran, the page printed to PDF.

One browser serves every page of a test session (the ``chromium`` fixture, ``tests/app/conftest.py``): starting one
per page cost a second or more of a core each. It is driven over the DevTools protocol on a pipe
(``--remote-debugging-pipe``), and each page does what the command-line switches ``--window-size``,
``--virtual-time-budget``, ``--dump-dom``, ``--print-to-pdf`` and ``--screenshot`` did, in the same order (Chromium's
headless command handler): load, run the page for the virtual-time budget, read the DOM, print, take the shot.
Each page opens in a browser context of its own (no cookie or storage left over from another page).

Set ``CELLCAL_SCREENSHOT_DIR=DIR`` to keep every screenshot there, so a person can look at them.
"""

from __future__ import annotations

import base64
import fcntl
import json
import os
import select
import shutil
import signal
import subprocess
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

BROWSERS = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")

#: The serialised DOM as ``--dump-dom`` prints it (doctype, then the document element).
DUMP_DOM = ("(document.doctype ? new XMLSerializer().serializeToString(document.doctype) + '\\n' : '') + "
            "document.documentElement.outerHTML")


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


class Chromium:
    """One headless Chromium, driven over the DevTools protocol on a pipe; started on first use, restarted after a
    page that did not finish.

    WebGL runs through SwiftShader (``--use-angle=swiftshader --enable-unsafe-swiftshader``); with ``--disable-gpu``
    headless Chromium now and then never exits.

    Args:
        browser: the browser's executable.
        work: a folder for the profile and the browser's log.
    """

    def __init__(self, browser: str, work: Path) -> None:
        self.browser, self.work = browser, work
        self.proc: subprocess.Popen[bytes] | None = None
        self._to_browser = self._from_browser = -1
        self._buffer = b""
        self._events: list[dict[str, Any]] = []
        self._next_id = 0
        self.starts = 0

    @property
    def log(self) -> Path:
        return self.work / "browser.log"

    def start(self) -> None:
        """Start the browser with the pipe on its descriptors 3 (commands in) and 4 (replies out)."""
        self.starts += 1
        commands_r, commands_w = os.pipe()
        replies_r, replies_w = os.pipe()
        # above 4, so that moving them onto 3 and 4 in the child cannot overwrite one with the other
        child_in, child_out = (fcntl.fcntl(fd, fcntl.F_DUPFD, 10) for fd in (commands_r, replies_w))
        os.close(commands_r)
        os.close(replies_w)

        def onto_3_and_4() -> None:
            os.dup2(child_in, 3)
            os.dup2(child_out, 4)

        cmd = [self.browser, "--headless", "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
               "--disable-quic", "--no-first-run", "--disable-background-networking", "--disable-component-update",
               "--disable-sync", f"--user-data-dir={self.work / f'profile{self.starts}'}", "--remote-debugging-pipe",
               "about:blank"]
        with open(self.log, "a") as err:  # no stdout pipe: chromium's helpers would keep it open
            self.proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=err,
                                         pass_fds=(3, 4), preexec_fn=onto_3_and_4, start_new_session=True)
        os.close(child_in)
        os.close(child_out)
        self._to_browser, self._from_browser = commands_w, replies_r
        self._buffer, self._events = b"", []

    def close(self) -> None:
        """Ask the browser to close, then make sure it and its helpers are gone."""
        if self.proc is None:
            return
        try:
            if self.proc.poll() is None:
                self.send("Browser.close", deadline=time.monotonic() + 10)
                self.proc.wait(timeout=10)
        except (OSError, TimeoutError, EOFError, RuntimeError, subprocess.TimeoutExpired):
            pass
        finally:
            self._kill()

    def _kill(self) -> None:
        if self.proc is None:
            return
        try:
            os.killpg(self.proc.pid, signal.SIGKILL)  # the browser we started, and its helpers
        except ProcessLookupError:
            pass
        self.proc.wait()
        self.proc = None
        for fd in (self._to_browser, self._from_browser):
            os.close(fd)

    def send(self, method: str, params: dict[str, Any] | None = None, session: str | None = None, *,
             deadline: float) -> dict[str, Any]:
        """Send one DevTools command and return its result; events that arrive meanwhile are kept.

        Raises:
            TimeoutError: no reply by ``deadline`` (time.monotonic()).
            RuntimeError: the browser answered with an error.
        """
        self._next_id += 1
        message: dict[str, Any] = {"id": self._next_id, "method": method, "params": params or {}}
        if session is not None:
            message["sessionId"] = session
        os.write(self._to_browser, json.dumps(message).encode() + b"\0")
        while True:
            reply = self._receive(deadline)
            if reply.get("id") == self._next_id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return dict(reply["result"])
            self._events.append(reply)

    def wait_event(self, matches: Callable[[dict[str, Any]], bool], deadline: float) -> dict[str, Any]:
        """The first event (kept or new) for which ``matches`` is true."""
        for i, event in enumerate(self._events):
            if matches(event):
                return self._events.pop(i)
        while True:
            event = self._receive(deadline)
            if matches(event):
                return event
            self._events.append(event)

    def _receive(self, deadline: float) -> dict[str, Any]:
        while b"\0" not in self._buffer:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError("the browser did not answer in time")
            if select.select([self._from_browser], [], [], left)[0]:
                chunk = os.read(self._from_browser, 1 << 20)
                if not chunk:
                    raise EOFError("the browser closed its pipe")
                self._buffer += chunk
        message, self._buffer = self._buffer.split(b"\0", 1)
        return dict(json.loads(message))

    def render(self, url: str, *, size: tuple[int, int] = (1024, 768), budget_ms: int = 5000,
               screenshot: Path | None = None, pdf: Path | None = None, timeout_s: float = 90.0) -> str:
        """Load ``url`` in a window of ``size`` (width, height) [px], run it for ``budget_ms`` of virtual time, and
        return its DOM; print it to ``pdf`` (no header or footer, the page's own ``@page`` size) and take a
        ``screenshot`` (PNG, ``size``) when given. A page that does not finish in ``timeout_s`` fails the test."""

        def run(s: str, deadline: float) -> str:
            self.send("Emulation.setVirtualTimePolicy", {"policy": "pauseIfNetworkFetchesPending", "budget": budget_ms,
                                                         "maxVirtualTimeTaskStarvationCount": 9999}, s, deadline=deadline)
            self.wait_event(lambda m: m.get("sessionId") == s
                            and m.get("method") == "Emulation.virtualTimeBudgetExpired", deadline)
            dom = str(self.send("Runtime.evaluate", {"expression": DUMP_DOM}, s, deadline=deadline)["result"]["value"])
            if pdf is not None:
                printed = self.send("Page.printToPDF", {"displayHeaderFooter": False, "generateTaggedPDF": True,
                                                        "printBackground": True, "preferCSSPageSize": True}, s,
                                    deadline=deadline)
                pdf.write_bytes(base64.b64decode(printed["data"]))
            if screenshot is not None:
                shot = self.send("Page.captureScreenshot", {"format": "png", "clip": {
                    "x": 0, "y": 0, "width": size[0], "height": size[1], "scale": 1.0}}, s, deadline=deadline)
                screenshot.write_bytes(base64.b64decode(shot["data"]))
            return dom

        return str(self._on_page(url, size, timeout_s, run))

    def evaluate(self, url: str, expression: str, *, ready: str, size: tuple[int, int] = (1024, 768),
                 timeout_s: float = 90.0) -> Any:
        """Load ``url``, wait (polling every 0.1 s) until the page's ``ready`` expression is true, evaluate
        ``expression`` (a promise is awaited) and return its value. Real time, not virtual time: the page's clocks
        run. An exception in the page or a page not ready in ``timeout_s`` fails the test."""

        def run(s: str, deadline: float) -> Any:
            while True:
                done = self.send("Runtime.evaluate", {"expression": ready, "returnByValue": True}, s, deadline=deadline)
                if done["result"].get("value") is True:
                    break
                if time.monotonic() > deadline:
                    raise TimeoutError(f"the page was not ready ({ready})")
                time.sleep(0.1)
            result = self.send("Runtime.evaluate", {"expression": expression, "awaitPromise": True,
                                                    "returnByValue": True}, s, deadline=deadline)
            if "exceptionDetails" in result:
                raise RuntimeError(f"the page's script failed: {result['exceptionDetails']}")
            return result["result"]["value"]

        return self._on_page(url, size, timeout_s, run)

    def _on_page(self, url: str, size: tuple[int, int], timeout_s: float, run: Callable[[str, float], Any]) -> Any:
        """``run(session, deadline)`` on ``url`` loaded in a new page of ``size`` in a browser context of its own."""
        if self.proc is None or self.proc.poll() is not None:
            if self.proc is not None:
                self._kill()
            self.start()
        deadline = time.monotonic() + timeout_s
        try:
            context = self.send("Target.createBrowserContext", deadline=deadline)["browserContextId"]
            target = self.send("Target.createTarget", {"url": "about:blank", "browserContextId": context},
                               deadline=deadline)["targetId"]
            s = self.send("Target.attachToTarget", {"targetId": target, "flatten": True},
                          deadline=deadline)["sessionId"]
            self.send("Emulation.setDeviceMetricsOverride", {"width": size[0], "height": size[1],
                                                             "deviceScaleFactor": 1, "mobile": False}, s,
                      deadline=deadline)
            self.send("Page.enable", session=s, deadline=deadline)
            self.send("Page.setLifecycleEventsEnabled", {"enabled": True}, s, deadline=deadline)
            frame = self.send("Page.navigate", {"url": url}, s, deadline=deadline)["frameId"]
            self.wait_event(lambda m: m.get("sessionId") == s and m.get("method") == "Page.lifecycleEvent"
                            and m["params"]["name"] == "load" and m["params"]["frameId"] == frame, deadline)
            value = run(s, deadline)
            self._events = [e for e in self._events if e.get("sessionId") not in (s, None)]
            self.send("Target.closeTarget", {"targetId": target}, deadline=deadline)
            self.send("Target.disposeBrowserContext", {"browserContextId": context}, deadline=deadline)
        except (TimeoutError, EOFError, RuntimeError) as e:
            self._kill()  # the next page starts a new browser
            pytest.fail(f"headless browser failed on {url}: {e}: {self.log.read_text()[-1000:]}")
        return value


def _keep(png: Path) -> None:
    keep = os.environ.get("CELLCAL_SCREENSHOT_DIR")  # to look at them: CELLCAL_SCREENSHOT_DIR=DIR pytest ...
    if keep:
        os.makedirs(keep, exist_ok=True)
        shutil.copy(png, os.path.join(keep, png.name))


def screenshot_and_dom(chromium: Chromium, work: Path, url: str, name: str, size: tuple[int, int] = (1024, 768),
                       budget_ms: int = 5000) -> tuple[Path, str]:
    """A PNG screenshot of ``url`` as ``work/name`` (kept in ``$CELLCAL_SCREENSHOT_DIR`` too when set) and the DOM
    after the page's scripts ran, from one page load (each costs seconds of a core: SwiftShader WebGL)."""
    png = work / name
    dom = chromium.render(url, size=size, budget_ms=budget_ms, screenshot=png)
    assert png.exists(), chromium.log.read_text()[-2000:]
    _keep(png)
    return png, dom


def screenshot_dom_pdf(chromium: Chromium, work: Path, url: str, name: str, size: tuple[int, int] = (1280, 800),
                       budget_ms: int = 3000) -> tuple[Path, str, Path]:
    """One page load: a first-screen PNG ``work/name`` (see :func:`screenshot_and_dom`), the DOM after the page's
    scripts ran and the page printed to PDF (``work/name`` with ``.pdf``, no header or footer, the page's own
    ``@page`` size). Chromium prints before it takes the shot, so the shot shows the page as printed (what the print
    stylesheet's script unfolded stays open); the DOM positions of the sign-off parts are read on load, before."""
    png, pdf = work / name, work / Path(name).with_suffix(".pdf").name
    dom = chromium.render(url, size=size, budget_ms=budget_ms, screenshot=png, pdf=pdf)
    assert png.exists() and pdf.exists(), chromium.log.read_text()[-2000:]
    _keep(png)
    return png, dom, pdf
