"""Issue 14's attacks against the rosbridge door, measured as the stall they cause on the loop
the drones' safety shares. Prints a table of medians; the baseline is the same loop idle.

Rows (the server's event loop runs a 5 ms ticker; the stall is the worst lateness of a tick):
  idle                          nothing but the ticker (baseline).
  PNG 900k chunks, no token     the frame that froze the loop for 12 s: now refused unread.
  PNG 900k chunks, pilot        the same after auth: refused by the chunk cap.
  JSON 15 MB, pilot             a large valid frame: decoded in a worker thread.
  16 MB frames x4, no token     back-to-back frames that starved the auth deadline.
And, outside the server: ``png_decode`` of 100 000 one-byte IDAT chunks, the old joining
decoder (kept here for the comparison) against the linear one, with their ratio.

Usage: ``python bench/attacks.py [--quick]``. Figures depend on the machine's load: compare rows
of one run, not runs.
"""

from __future__ import annotations

import argparse
import asyncio
import base64
import contextlib
import json
import socket
import statistics
import struct
import sys
import threading
import time
import zlib
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import uvicorn  # noqa: E402
from fastapi import FastAPI  # noqa: E402
from websockets.asyncio.client import connect  # noqa: E402

from server.graph import Graph  # noqa: E402
from server.rosbridge.context import BridgeContext  # noqa: E402
from server.rosbridge.encode import PNG_SIGNATURE, png_decode, png_encode  # noqa: E402
from server.rosbridge.endpoint import make_router  # noqa: E402
from server.security import Security, TokenStore  # noqa: E402
from server.settings import Settings  # noqa: E402

HOST = "127.0.14.20"
TICK_S = 0.005


def old_png_decode(png: bytes) -> bytes:
    """The decoder before issue 14 (IDAT bodies joined one by one: quadratic)."""
    pos, idat = len(PNG_SIGNATURE), b""
    while pos < len(png):
        (length,) = struct.unpack(">I", png[pos : pos + 4])
        kind, body = png[pos + 4 : pos + 8], png[pos + 8 : pos + 8 + length]
        pos += 12 + length
        if kind == b"IDAT":
            idat += body
    return zlib.decompressobj().decompress(idat)


def chunked_png(text: str, chunks: int) -> bytes:
    png = png_encode(text)
    head = len(PNG_SIGNATURE) + 12 + 13
    (length,) = struct.unpack(">I", png[head : head + 4])
    stream = png[head + 8 : head + 8 + length]
    stream += b"\0" * max(0, chunks - len(stream))
    body = b"".join(
        struct.pack(">I", 1) + b"IDAT" + stream[i : i + 1] + b"\0\0\0\0" for i in range(chunks)
    )
    return png[:head] + body + png[-12:]


@contextlib.contextmanager
def server(tmp: Path) -> Iterator[tuple[int, str, list[float]]]:
    with socket.socket() as s:
        s.bind((HOST, 0))
        port = int(s.getsockname()[1])
    settings = Settings(host=HOST, port=port, data_dir=tmp)
    tokens = TokenStore(tmp)
    graph = Graph()
    ctx = BridgeContext(graph=graph, security=Security(settings, tokens), settings=settings)
    lateness: list[float] = []

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI):  # type: ignore[no-untyped-def]
        loop = asyncio.get_running_loop()
        graph.bind_loop(loop)

        async def ticker() -> None:
            due = loop.time()
            while True:
                due += TICK_S
                await asyncio.sleep(max(0.0, due - loop.time()))
                lateness.append(loop.time() - due)

        task = asyncio.create_task(ticker())
        yield
        task.cancel()

    app = FastAPI(lifespan=lifespan)
    app.include_router(make_router(ctx))
    config = uvicorn.Config(
        app, host=HOST, port=port, log_level="error", ws_max_size=64 << 20, ws_ping_interval=None
    )
    srv = uvicorn.Server(config)
    thread = threading.Thread(target=srv.run, daemon=True)
    thread.start()
    while not srv.started:
        time.sleep(0.01)
    try:
        yield port, tokens.pilot_token, lateness
    finally:
        srv.should_exit = True
        thread.join(10)


async def attack(url: str, frames: list[str], settle_s: float) -> None:
    with contextlib.suppress(Exception):
        async with connect(url, max_size=None, ping_interval=None) as ws:
            for f in frames:
                await ws.send(f)
            with contextlib.suppress(Exception):
                async with asyncio.timeout(settle_s):
                    while True:
                        await ws.recv()
    await asyncio.sleep(0.2)


def stall_ms(lateness: list[float], start: int) -> float:
    window = lateness[start:]
    return 1000 * max(window) if window else float("nan")


async def run_rows(
    port: int, token: str, lateness: list[float], rounds: int
) -> list[tuple[str, list[float]]]:
    base = f"ws://{HOST}:{port}/rosbridge"
    png = chunked_png('{"op":"subscribe","topic":"/a","type":"std_msgs/String"}', 900_000)
    png_frame = json.dumps({"op": "png", "data": base64.b64encode(png).decode()})
    big_json = json.dumps({"op": "publish", "topic": "/big", "msg": {"data": "x" * (15 << 20)}})
    big16 = "x" * (16 << 20)
    cases = [
        ("idle", None, []),
        ("PNG 900k chunks, no token", base, [png_frame]),
        ("PNG 900k chunks, pilot", f"{base}?token={token}", [png_frame]),
        ("JSON 15 MB, pilot", f"{base}?token={token}", [big_json]),
        ("16 MB frames x4, no token", base, [big16] * 4),
    ]
    out: list[tuple[str, list[float]]] = []
    for name, url, frames in cases:
        samples = []
        for _ in range(rounds):
            start = len(lateness)
            if url is None:
                await asyncio.sleep(1.0)
            else:
                await attack(url, frames, settle_s=3.0)
            samples.append(stall_ms(lateness, start))
        out.append((name, samples))
    return out


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    rounds = 1 if args.quick else 3
    import tempfile

    with tempfile.TemporaryDirectory() as tmp, server(Path(tmp)) as (port, token, lateness):
        time.sleep(0.5)
        rows = asyncio.run(run_rows(port, token, lateness, rounds))
    idle = statistics.median(rows[0][1])
    print(
        f"loop stall on the server (worst lateness of a {TICK_S * 1000:g} ms tick), "
        f"median of {rounds} round(s)"
    )
    print(f"{'attack':<28} {'stall ms':>10} {'× idle':>8}")
    for name, samples in rows:
        med = statistics.median(samples)
        print(f"{name:<28} {med:>10.1f} {med / idle if idle > 0 else float('nan'):>8.1f}")
    png = chunked_png('{"op":"auth","token":"x"}', 100_000)
    t0 = time.perf_counter()
    old_png_decode(png)
    t_old = time.perf_counter() - t0
    t0 = time.perf_counter()
    with contextlib.suppress(ValueError):
        png_decode(png)
    t_new = time.perf_counter() - t0
    print(
        f"\npng_decode, 100 000 one-byte IDAT chunks: old {t_old * 1000:.0f} ms, "
        f"new {t_new * 1000:.2f} ms (refused at the chunk cap), ratio {t_old / t_new:.0f}×"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
