"""A meshcat server that listens on loopback only, for ``cellcal preview --serve``.

meshcat's own server (``meshcat.servers.zmqserver``) binds its ZeroMQ socket to 127.0.0.1 but starts its web
server (tornado) on every interface, so a live preview was reachable from the whole network on port 7000. This
module runs the same bridge with the web server bound to 127.0.0.1 too, and prints the two URLs the way meshcat's
server does, so :func:`start` can read them. Run as ``python -m app.dual.preview.meshcat_server [--page-extra FILE]``:
the HTML in FILE (the preview's waypoint readout) is added to the end of the viewer page's body.
"""

from __future__ import annotations

import atexit
import re
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

HOST = "127.0.0.1"


def _bridge_class(page_extra: str = "") -> Any:
    import tornado.web
    from meshcat.servers.zmqserver import (
        VIEWER_HTML,
        VIEWER_ROOT,
        StaticFileHandlerNoCache,
        WebSocketHandler,
        ZMQWebSocketBridge,
    )

    class ViewerPage(tornado.web.RequestHandler):
        """meshcat's viewer page with ``page_extra`` at the end of its body."""

        def get(self, *_: Any) -> None:
            page = (Path(VIEWER_ROOT) / VIEWER_HTML).read_text(encoding="utf-8")
            self.set_header("Content-Type", "text/html; charset=utf-8")
            self.write(page.replace("</body>", page_extra + "</body>", 1))

    class LoopbackBridge(ZMQWebSocketBridge):  # type: ignore[misc]  # meshcat ships no stubs: its class is Any
        """meshcat's bridge whose web server listens on :data:`HOST` only and whose page carries ``page_extra``."""

        def make_app(self) -> Any:
            app = tornado.web.Application([  # meshcat's own two routes, after the page's
                (r"/static/(index\.html)?", ViewerPage),
                (r"/static/(.*)", StaticFileHandlerNoCache, {"path": VIEWER_ROOT, "default_filename": VIEWER_HTML}),
                (r"/", WebSocketHandler, {"bridge": self})])
            listen = app.listen
            # patched on this instance on purpose: meshcat calls app.listen(port), which binds every interface
            app.listen = lambda port, **kwargs: listen(port, address=HOST, **kwargs)  # type: ignore[method-assign]
            return app

    return LoopbackBridge


def start(page_extra: str = "") -> tuple[subprocess.Popen[str], str, str]:
    """Start the server as a subprocess (killed when this process exits): ``(process, zmq_url, web_url)``.

    Args:
        page_extra: HTML added to the end of the viewer page's body (the waypoint readout).

    Raises:
        RuntimeError: the server exited or printed no URLs.
    """
    with tempfile.TemporaryDirectory() as folder:  # the server reads the page's extra before printing its URLs
        extra = Path(folder) / "page_extra.html"
        extra.write_text(page_extra, encoding="utf-8")
        proc = subprocess.Popen([sys.executable, "-u", "-m", "app.dual.preview.meshcat_server", "--page-extra", str(extra)],
                                stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, start_new_session=True)
        atexit.register(_kill_and_wait, proc)
        urls: dict[str, str] = {}
        while len(urls) < 2:
            line = proc.stdout.readline() if proc.stdout is not None else ""
            if not line:
                raise RuntimeError(f"the meshcat server exited (code {proc.poll()}) before printing its URLs")
            m = re.match(r"(zmq_url|web_url)=(\S+)", line.strip())
            if m:
                urls[m.group(1)] = m.group(2)
    return proc, urls["zmq_url"], urls["web_url"]


def _kill_and_wait(proc: subprocess.Popen[str]) -> None:
    proc.kill()
    proc.wait()


def main(argv: list[str] | None = None) -> None:
    import argparse

    parser = argparse.ArgumentParser(prog="python -m app.dual.preview.meshcat_server", description=__doc__.split("\n")[0])
    parser.add_argument("--page-extra", help="file of HTML to add to the end of the viewer page's body")
    args = parser.parse_args(argv)
    extra = Path(args.page_extra).read_text(encoding="utf-8") if args.page_extra else ""
    bridge = _bridge_class(extra)(host=HOST)
    print(f"zmq_url={bridge.zmq_url}", flush=True)
    print(f"web_url={bridge.web_url}", flush=True)
    try:
        bridge.run()
    except KeyboardInterrupt:
        pass


if __name__ == "__main__":
    main()
