"""A meshcat server that listens on loopback only, for ``cellcal preview --serve``.

meshcat's own server (``meshcat.servers.zmqserver``) binds its ZeroMQ socket to 127.0.0.1 but starts its web
server (tornado) on every interface, so a live preview was reachable from the whole network on port 7000. This
module runs the same bridge with the web server bound to 127.0.0.1 too, and prints the two URLs the way meshcat's
server does, so :func:`start` can read them. Run as ``python -m app.dual.meshcat_server``.
"""

from __future__ import annotations

import atexit
import re
import subprocess
import sys
from typing import Any

HOST = "127.0.0.1"


def _bridge_class() -> Any:
    from meshcat.servers.zmqserver import ZMQWebSocketBridge

    class LoopbackBridge(ZMQWebSocketBridge):
        """meshcat's bridge whose web server listens on :data:`HOST` only."""

        def make_app(self) -> Any:
            app = super().make_app()
            listen = app.listen
            app.listen = lambda port, **kwargs: listen(port, address=HOST, **kwargs)
            return app

    return LoopbackBridge


def start(timeout_s: float = 30.0) -> tuple[subprocess.Popen, str, str]:
    """Start the server as a subprocess (killed when this process exits): ``(process, zmq_url, web_url)``.

    Raises:
        RuntimeError: the server exited or printed no URLs.
    """
    proc = subprocess.Popen([sys.executable, "-u", "-m", "app.dual.meshcat_server"], stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, text=True, start_new_session=True)
    atexit.register(lambda: (proc.kill(), proc.wait()))
    urls: dict[str, str] = {}
    while len(urls) < 2:
        line = proc.stdout.readline() if proc.stdout is not None else ""
        if not line:
            raise RuntimeError(f"the meshcat server exited (code {proc.poll()}) before printing its URLs")
        m = re.match(r"(zmq_url|web_url)=(\S+)", line.strip())
        if m:
            urls[m.group(1)] = m.group(2)
    return proc, urls["zmq_url"], urls["web_url"]


def main() -> None:
    bridge = _bridge_class()(host=HOST)
    print(f"zmq_url={bridge.zmq_url}", flush=True)
    print(f"web_url={bridge.web_url}", flush=True)
    try:
        bridge.run()
    except KeyboardInterrupt:
        pass


if __name__ == "__main__":
    main()
