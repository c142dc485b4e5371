"""rosbridge endpoint benchmarks; prints a table of medians and ratios vs a bare relay.

Rows (server in its own process, clients in 1-4 worker processes, all on loopback):
  fan-out N subs @1 kHz   publish -> receive latency p50/p99 and delivered msgs/s, a client
                          publishing std_msgs/String at 1 kHz to N subscribers (N = 1, 10, 50);
                          baseline: a bare ``websockets`` relay that forwards each frame to every
                          subscriber (no protocol, no graph), measured in the same run.
                          Targets: p99 < 2 ms with 10 subscribers; >= 30 000 delivered msgs/s.
  saturation, 10 subs     the publisher sends as fast as it can for the window: delivered msgs/s.
  JPEG 640x360 @15 fps    sensor_msgs/CompressedImage to 5 clients: end-to-end latency (publish
                          op in, base64 validated, re-encoded out). Target < 50 ms.
  call_service RTT        sequential calls of an in-process service; baseline: request/reply on
                          the bare relay. Target p50 <= 1 ms.
Anchors: rosbridge_suite ~5 000 msg/s, 12 ms median service call, 6-22 s latency for a
640x360 15 fps image stream (rosboard with JPEG: 96 ms).

Usage: ``python bench/bridge.py [--quick] [--seconds S]``. The server runs with a raised
per-connection rate limit (the default 2 000 frames/s would cap the saturation row).
"""

from __future__ import annotations

import argparse
import asyncio
import base64
import json
import multiprocessing as mp
import os
import socket
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.loopback import free_port  # noqa: E402

TOKEN = "bench-pilot-token"


# -- servers (run as subprocesses) -------------------------------------------------------
def serve_rosbridge(port: int, data_dir: str) -> None:
    import uvicorn
    from fastapi import FastAPI

    from server.graph import Graph
    from server.http.security import Security, TokenStore
    from server.rosbridge.context import BridgeContext
    from server.rosbridge.endpoint import make_router
    from server.settings import Settings

    settings = Settings(port=port, data_dir=Path(data_dir), rate_limit_per_s=1e6, rate_burst=10**6)
    graph = Graph()
    tokens = TokenStore(Path(data_dir), pilot_token=TOKEN)
    ctx = BridgeContext(graph=graph, security=Security(settings, tokens), settings=settings)
    ctx.out_queue_frames = 100_000

    async def echo(args: dict[str, Any]) -> dict[str, Any]:
        return args

    graph.advertise_service("/bench/echo", "bench/Echo", echo)
    app = FastAPI()
    app.include_router(make_router(ctx))
    uvicorn.run(
        app,
        host="127.0.0.1",
        port=port,
        log_level="error",
        ws_ping_interval=None,
        ws_max_size=64 << 20,
    )


def serve_relay(port: int) -> None:
    """The baseline: forwards every publish frame to all subscribers; echoes calls."""
    from websockets.asyncio.server import broadcast, serve

    subs: set[Any] = set()

    async def handler(ws: Any) -> None:
        try:
            async for raw in ws:
                head = raw[:24].replace(" ", "")
                if head.startswith('{"op":"subscribe"'):
                    subs.add(ws)
                elif head.startswith('{"op":"call_service"'):
                    await ws.send(raw)
                elif head.startswith('{"op":"publish"'):
                    broadcast(subs, raw)
        finally:
            subs.discard(ws)

    async def main() -> None:
        async with serve(handler, "127.0.0.1", port, ping_interval=None, max_size=64 << 20):
            await asyncio.Future()

    asyncio.run(main())


def start(kind: str, port: int, data_dir: str) -> subprocess.Popen[bytes]:
    proc = subprocess.Popen(
        [sys.executable, __file__, "--serve", kind, str(port), data_dir], cwd=ROOT
    )
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        try:
            socket.create_connection(("127.0.0.1", port), 0.2).close()
            return proc
        except OSError:
            time.sleep(0.05)
    proc.kill()
    raise RuntimeError(f"{kind} server did not start")


# -- clients ------------------------------------------------------------------------------
def url(kind: str, port: int) -> str:
    return (
        f"ws://127.0.0.1:{port}/rosbridge?token={TOKEN}"
        if kind == "rosbridge"
        else (f"ws://127.0.0.1:{port}/")
    )


def subscriber_worker(
    kind: str, port: int, topic: str, type_name: str, n: int, seconds: float, ready: Any, out: Any
) -> None:
    """Run ``n`` subscribers; report latencies (s) and message count after ``seconds``."""
    from websockets.asyncio.client import connect

    async def one(lat: list[float], counts: list[int], end: float) -> None:
        loop = asyncio.get_running_loop()
        async with connect(url(kind, port), ping_interval=None, max_size=None) as ws:
            sub = {"op": "subscribe", "topic": topic, "type": type_name}
            await ws.send(json.dumps(sub, separators=(",", ":")))
            ready.put(1)
            while (left := end - loop.time()) > 0:
                try:
                    raw = await asyncio.wait_for(ws.recv(), left)
                except TimeoutError:
                    break
                now = time.monotonic()
                frame = json.loads(raw)
                if frame.get("op") != "publish":
                    print("unexpected frame:", str(frame)[:200], file=sys.stderr)
                    continue
                msg = frame["msg"]
                t = float(msg["header"]["frame_id"] if "header" in msg else msg["data"])
                lat.append(now - t)
                counts[0] += 1

    async def main() -> None:
        lat: list[float] = []
        counts = [0]
        end = asyncio.get_running_loop().time() + seconds
        await asyncio.gather(*(one(lat, counts, end) for _ in range(n)))
        out.put((lat, counts[0]))

    asyncio.run(main())


async def publisher(
    kind: str,
    port: int,
    topic: str,
    type_name: str,
    rate_hz: float | None,
    seconds: float,
    make_msg: Any,
) -> int:
    from websockets.asyncio.client import connect

    sent = 0
    async with connect(url(kind, port), ping_interval=None, max_size=None) as ws:
        await ws.send(json.dumps({"op": "advertise", "topic": topic, "type": type_name}))
        loop = asyncio.get_running_loop()
        start_t = loop.time()
        end = start_t + seconds
        while loop.time() < end:
            body = json.dumps(
                {"op": "publish", "topic": topic, "msg": make_msg()}, separators=(",", ":")
            )
            await ws.send(body)
            sent += 1
            if rate_hz:
                next_t = start_t + sent / rate_hz
                delay = next_t - loop.time()
                if delay > 0:
                    await asyncio.sleep(delay)
            elif sent % 50 == 0:
                await asyncio.sleep(0)
    return sent


def fan_out(
    kind: str,
    port: int,
    n_subs: int,
    rate_hz: float | None,
    seconds: float,
    topic: str,
    type_name: str,
    make_msg: Any,
) -> dict[str, float]:
    procs_n = min(4, n_subs)
    ctx = mp.get_context("spawn")
    ready, out = ctx.Queue(), ctx.Queue()
    per = [n_subs // procs_n + (1 if i < n_subs % procs_n else 0) for i in range(procs_n)]
    window = seconds + 1.5
    procs = [
        ctx.Process(
            target=subscriber_worker,
            args=(kind, port, topic, type_name, k, window + 2.0, ready, out),
        )
        for k in per
    ]
    for p in procs:
        p.start()
    for _ in range(n_subs):
        ready.get(timeout=60)
    time.sleep(0.5)  # let the subscriptions take effect
    print(f"  {kind}: {n_subs} subscribers on {topic}", file=sys.stderr, flush=True)
    sent = asyncio.run(publisher(kind, port, topic, type_name, rate_hz, seconds, make_msg))
    lat: list[float] = []
    got = 0
    for _ in procs:
        part, count = out.get(timeout=120)
        lat += part
        got += count
    for p in procs:
        p.join(30)
    lat.sort()
    q = statistics.quantiles(lat, n=100) if len(lat) >= 2 else [float("nan")] * 99
    return {
        "p50_ms": 1e3 * statistics.median(lat) if lat else float("nan"),
        "p99_ms": 1e3 * q[98],
        "delivered_per_s": got / seconds,
        "delivery": got / max(1, sent * n_subs),
    }


async def rtt(kind: str, port: int, n: int) -> dict[str, float]:
    from websockets.asyncio.client import connect

    lat: list[float] = []
    async with connect(url(kind, port), ping_interval=None) as ws:
        for i in range(n):
            t = time.perf_counter()
            await ws.send(
                json.dumps(
                    {
                        "op": "call_service",
                        "id": f"c{i}",
                        "service": "/bench/echo",
                        "args": {"i": i},
                    }
                )
            )
            while json.loads(await asyncio.wait_for(ws.recv(), 10))["id"] != f"c{i}":
                pass
            lat.append(time.perf_counter() - t)
    q = statistics.quantiles(lat, n=100)
    return {"p50_ms": 1e3 * statistics.median(lat), "p99_ms": 1e3 * q[98]}


def jpeg_bytes() -> bytes:
    import cv2
    import numpy as np

    rng = np.random.default_rng(1)
    img = np.zeros((360, 640, 3), np.uint8)
    img[:] = (40, 90, 140)
    for _ in range(60):
        x, y = int(rng.integers(0, 600)), int(rng.integers(0, 330))
        color = tuple(int(c) for c in rng.integers(0, 255, 3))
        cv2.rectangle(img, (x, y), (x + 40, y + 30), color, -1)
    img = cv2.GaussianBlur(img, (3, 3), 0)
    ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 80])
    assert ok
    return bytes(buf)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--seconds", type=float, default=None)
    ap.add_argument("--serve", nargs="+", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.serve:
        import faulthandler
        import signal

        faulthandler.register(signal.SIGUSR1)  # `kill -USR1 PID` dumps a stuck server's stacks
        if args.serve[0] == "rosbridge":
            serve_rosbridge(int(args.serve[1]), args.serve[2])
        else:
            serve_relay(int(args.serve[1]))
        return 0
    seconds = args.seconds or (1.5 if args.quick else 4.0)
    import tempfile

    tmp = tempfile.mkdtemp(prefix="uavc-bench-")
    ports = {"rosbridge": free_port(), "relay": free_port()}
    servers = [start(k, p, tmp) for k, p in ports.items()]
    rows: list[tuple[str, dict[str, float], dict[str, float] | None]] = []
    try:
        n_calls = 500 if args.quick else 2000
        rows.append(
            (
                "call_service RTT",
                asyncio.run(rtt("rosbridge", ports["rosbridge"], n_calls)),
                asyncio.run(rtt("relay", ports["relay"], n_calls)),
            )
        )

        def string_msg() -> dict[str, Any]:
            return {"data": repr(time.monotonic())}

        for n in (1, 10, 50):
            res = {
                k: fan_out(k, p, n, 1000.0, seconds, f"/bench/s{n}", "std_msgs/String", string_msg)
                for k, p in ports.items()
            }
            rows.append((f"fan-out {n} subs @1 kHz", res["rosbridge"], res["relay"]))
        res = {
            k: fan_out(k, p, 10, None, seconds, "/bench/sat", "std_msgs/String", string_msg)
            for k, p in ports.items()
        }
        rows.append(("saturation, 10 subs", res["rosbridge"], res["relay"]))
        jpeg = base64.b64encode(jpeg_bytes()).decode()

        def image_msg() -> dict[str, Any]:
            return {"header": {"frame_id": repr(time.monotonic())}, "format": "jpeg", "data": jpeg}

        res = {
            k: fan_out(
                k, p, 5, 15.0, seconds, "/bench/image", "sensor_msgs/CompressedImage", image_msg
            )
            for k, p in ports.items()
        }
        rows.append(
            (
                f"JPEG 640x360 ({len(jpeg) * 3 // 4 // 1024} KiB) @15 fps, 5 subs",
                res["rosbridge"],
                res["relay"],
            )
        )
    finally:
        for s in servers:
            s.terminate()
            s.wait(10)
    print(
        f"rosbridge endpoint vs bare websockets relay; {os.cpu_count()} CPUs; "
        f"{seconds:g} s windows\n"
    )
    head = (
        f"| {'case':38} | {'p50 ms':>7} | {'p99 ms':>7} | {'msgs/s':>8} | {'delivered':>9} "
        f"| {'relay p50':>9} | {'relay p99':>9} | {'relay msgs/s':>12} | {'p50 ratio':>9} |"
    )
    print(head)
    print("|" + "|".join("-" * (len(c)) for c in head.split("|")[1:-1]) + "|")
    for name, ours, base in rows:
        rate = ours.get("delivered_per_s", float("nan"))
        deliv = ours.get("delivery", float("nan"))
        b = base or {}
        ratio = ours["p50_ms"] / b["p50_ms"] if b.get("p50_ms") else float("nan")
        print(
            f"| {name:38} | {ours['p50_ms']:7.2f} | {ours['p99_ms']:7.2f} | {rate:8.0f} | "
            f"{deliv:9.1%} | {b.get('p50_ms', float('nan')):9.2f} | "
            f"{b.get('p99_ms', float('nan')):9.2f} | "
            f"{b.get('delivered_per_s', float('nan')):12.0f} | {ratio:9.2f} |"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
