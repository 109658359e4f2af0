"""Benchmark the Zenoh mocap stream on loopback: loss and publish-to-receive latency.

A publisher session (listening on a free 127.0.0.1 port) publishes ``--bodies`` rigid bodies at
``--rate`` Hz through :class:`drivers.bus.MocapBridge`; a second session connects to it and reads
through :class:`drivers.bus.ZenohMocapSource`. Latency is the subscriber's receive ``time.time()`` minus
the publish ``time.time()`` written in each payload (same host, same clock).

    python scripts/benchmarks/bench_stream.py [--json FILE] [--seconds 30] [--rate 240] [--bodies 2]
"""

from __future__ import annotations

import argparse
import json
import socket
import sys
import threading
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from cell_config.devices import ZenohConfig
from drivers.base import RigidBodyFrame
from drivers.bus import (
    MocapBridge,
    ZenohMocapSource,
    decode_mocap,
    encode_mocap,
    mocap_key,
    open_session,
    wait_for_subscriber,
)
from drivers.bus.payloads import MOCAP

CELL = "bench"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _codec_us(n: int = 20_000) -> tuple[float, float]:
    """Mean encode and decode time of one mocap payload [us]."""
    frame = RigidBodyFrame(1, np.array([1.0, 2.0, 3.0]), np.array([1.0, 0.0, 0.0, 0.0]), 0.1, True, 0.0, 0)
    t0 = time.perf_counter()
    for _ in range(n):
        payload = encode_mocap(frame, 0.0)
    t1 = time.perf_counter()
    for _ in range(n):
        decode_mocap(payload)
    t2 = time.perf_counter()
    return (t1 - t0) / n * 1e6, (t2 - t1) / n * 1e6


def _out_of_order(numbers: list[int]) -> int:
    """How many frame numbers arrived not greater than their predecessor."""
    return int(np.count_nonzero(np.diff(numbers) <= 0)) if len(numbers) > 1 else 0


def run(seconds: float, rate_hz: float, bodies: int) -> dict:
    """Stream for ``seconds`` and return the figures (see module docstring)."""
    port = _free_port()
    pub_session = open_session(ZenohConfig(listen=(f"tcp/127.0.0.1:{port}",)))
    source = ZenohMocapSource(CELL, config=ZenohConfig(connect=(f"tcp/127.0.0.1:{port}",)),
                              max_buffered_frames=1_000_000)
    source.connect()
    if not wait_for_subscriber(pub_session, mocap_key(CELL, "body0"), 10.0):
        raise SystemExit("subscriber never matched the publisher")
    bridge = MocapBridge(None, pub_session, CELL, names={i: f"body{i}" for i in range(bodies)})

    samples: list = []
    stop = threading.Event()

    def collect() -> None:
        while not stop.is_set():
            samples.extend(source.read_samples(0.05))

    collector = threading.Thread(target=collect, daemon=True)
    collector.start()
    period = 1.0 / rate_hz
    n_ticks = int(round(seconds * rate_hz))
    lateness = np.empty(n_ticks)
    t_start = time.perf_counter()
    for n in tqdm(range(n_ticks), desc="streaming", unit="frame", file=sys.stderr, mininterval=1.0):
        t_due = t_start + n * period
        while (wait := t_due - time.perf_counter()) > 0:
            time.sleep(wait if wait > 0.002 else 0)
        lateness[n] = time.perf_counter() - t_due
        for body in range(bodies):
            bridge.publish(RigidBodyFrame(body, np.array([n, 0.0, 1000.0]), np.array([1.0, 0.0, 0.0, 0.0]),
                                          0.05, True, n * period, n))
    elapsed = (n_ticks - 1) * period + lateness[-1]  # first to last tick [s]
    deadline = time.monotonic() + 2.0
    while len(samples) < bridge.published and time.monotonic() < deadline:
        time.sleep(0.01)
    stop.set()
    collector.join()
    samples.extend(source.read_samples(0.0))
    sent, stats = bridge.published, source.stats
    bridge.close()
    source.close()
    pub_session.close()

    keys = [(s.frame.body_id, s.frame.frame_number) for s in samples]
    out_of_order = sum(_out_of_order([n for b, n in keys if b == body]) for body in range(bodies))
    lat_ms = np.array([s.latency_s for s in samples]) * 1e3
    encode_us, decode_us = _codec_us()

    def pct(p: float) -> float:
        return float(np.percentile(lat_ms, p)) if len(lat_ms) else float("nan")

    return {
        "seconds": seconds, "rate_hz": rate_hz, "bodies": bodies, "payload_bytes": MOCAP.size,
        "frames_sent": sent, "frames_received": len(samples), "frames_lost": sent - len(set(keys)),
        "duplicates": len(keys) - len(set(keys)), "out_of_order": out_of_order,
        "payloads_rejected": stats.rejected, "subscriber_drops": stats.dropped,
        "achieved_rate_hz": (n_ticks - 1) / elapsed if n_ticks > 1 else float("nan"),
        "latency_ms_p50": pct(50), "latency_ms_p90": pct(90), "latency_ms_p99": pct(99),
        "latency_ms_max": float(lat_ms.max()) if len(lat_ms) else float("nan"),
        "publish_lateness_ms_p99": float(np.percentile(lateness, 99) * 1e3),
        "encode_us": encode_us, "decode_us": decode_us,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=Path, help="write the figures to this JSON file")
    parser.add_argument("--seconds", type=float, default=30.0, help="streaming duration [s]")
    parser.add_argument("--rate", type=float, default=240.0, help="frame rate per body [Hz]")
    parser.add_argument("--bodies", type=int, default=2, help="number of rigid bodies")
    args = parser.parse_args(argv)
    if args.seconds <= 0 or args.rate <= 0 or args.bodies < 1:
        print("error: --seconds and --rate must be > 0 and --bodies >= 1", file=sys.stderr)
        return 2
    figures = run(args.seconds, args.rate, args.bodies)
    width = max(map(len, figures))
    for key, value in figures.items():
        print(f"{key:<{width}}  {value:.4g}" if isinstance(value, float) else f"{key:<{width}}  {value}")
    if args.json:
        args.json.write_text(json.dumps(figures, indent=2) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
