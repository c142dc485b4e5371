"""Issue 14's attacks against the rosbridge door, measured as the stall they cause on the loop
the drones' safety shares. Prints a table of medians; the baseline is the same loop idle.

Rows (the server's event loop runs a 5 ms ticker; the stall is the worst lateness of a tick):
  idle                          nothing but the ticker (baseline).
  PNG 900k chunks, no token     the frame that froze the loop for 12 s: now refused at its header.
  PNG 900k chunks, pilot        the same after auth: refused by the chunk cap.
  JSON 15 MB, pilot             a large valid frame: decoded in a worker thread.
  16 MB frames x4, no token     back-to-back frames that starved the auth deadline: now refused
                                at the first frame's header by the transport (server.ws_guard).
  16 MB frames, 4 connections   one such frame on each of four connections at once.
  ... (app check only)          the two floods against uvicorn's plain transport, which reads each
                                frame whole before the endpoint refuses it (before the cap).
Each row also gives the server's peak RSS during the attack above its RSS before. The server
runs in its own process, so the attacking client's work is in neither figure.
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
import multiprocessing
import socket
import statistics
import struct
import sys
import time
import urllib.request
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
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
from server.ws_guard import preauth_capped_ws  # noqa: E402

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


def _serve(host: str, port: int, tmp: str, capped: bool) -> None:
    """The server under attack, in its own process (so the attacking client's work shares
    neither its GIL nor its memory figures): the rosbridge router, a ticker on its loop, and
    ``GET /bench/stall?since=N`` (the worst lateness of tick N onwards, and the tick count)."""
    settings = Settings(host=host, port=port, data_dir=Path(tmp))
    graph = Graph()
    ctx = BridgeContext(graph, Security(settings, TokenStore(Path(tmp))), settings)
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

    @app.get("/bench/stall")
    def stall(since: int = 0) -> dict[str, float]:
        window = lateness[since:]
        return {"ticks": len(lateness), "stall_ms": 1000 * max(window) if window else 0.0}

    config = uvicorn.Config(
        app,
        host=host,
        port=port,
        log_level="error",
        ws_max_size=64 << 20,  # as serve: 4 × the 16 MB frame limit
        ws=preauth_capped_ws() if capped else "websockets-sansio",
        ws_ping_interval=None,
    )
    uvicorn.Server(config).run()


@dataclass
class Target:
    """A running :func:`_serve` process."""

    port: int
    token: str
    pid: int

    def get(self, path: str) -> dict[str, float]:
        with urllib.request.urlopen(f"http://{HOST}:{self.port}{path}", timeout=30) as r:
            return dict(json.loads(r.read()))

    def proc_kb(self, field: str) -> int:
        for line in Path(f"/proc/{self.pid}/status").read_text().splitlines():
            if line.startswith(field + ":"):
                return int(line.split()[1])
        return -1

    def reset_peak(self) -> None:
        # "5" resets the peak RSS (VmHWM) to the current RSS: proc(5), /proc/pid/clear_refs
        Path(f"/proc/{self.pid}/clear_refs").write_text("5")


@contextlib.contextmanager
def server(tmp: Path, *, capped: bool) -> Iterator[Target]:
    with socket.socket() as s:
        s.bind((HOST, 0))
        port = int(s.getsockname()[1])
    token = TokenStore(tmp).pilot_token  # the child loads the same token file
    proc = multiprocessing.get_context("spawn").Process(
        target=_serve, args=(HOST, port, str(tmp), capped), daemon=True
    )
    proc.start()
    assert proc.pid is not None
    target = Target(port, token, proc.pid)
    deadline = time.monotonic() + 30
    while True:
        try:
            target.get("/bench/stall")
            break
        except OSError:
            if time.monotonic() > deadline or not proc.is_alive():
                raise RuntimeError("the bench server did not start") from None
            time.sleep(0.05)
    try:
        yield target
    finally:
        proc.terminate()
        proc.join(10)


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


@dataclass
class Row:
    name: str
    stall_ms: list[float]
    peak_mb: list[float]  # the server's peak RSS during the attack, above its RSS before


Case = tuple[str, bool, list[str], int]  # name, with the pilot token, frames, connections


async def run_rows(target: Target, cases: list[Case], rounds: int) -> list[Row]:
    """Each case ``rounds`` times, its connections at once; an empty frame list is the idle
    baseline (1 s of nothing)."""
    base = f"ws://{HOST}:{target.port}/rosbridge"
    out: list[Row] = []
    for name, with_token, frames, connections in cases:
        row = Row(name, [], [])
        for _ in range(rounds):
            since = int(target.get("/bench/stall")["ticks"])
            target.reset_peak()
            before = target.proc_kb("VmRSS")
            if not frames:
                await asyncio.sleep(1.0)
            else:
                url = f"{base}?token={target.token}" if with_token else base
                await asyncio.gather(*(attack(url, frames, 3.0) for _ in range(connections)))
            row.peak_mb.append((target.proc_kb("VmHWM") - before) / 1024)
            row.stall_ms.append(target.get(f"/bench/stall?since={since}")["stall_ms"])
        out.append(row)
    return out


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    rounds = 1 if args.quick else 3
    import tempfile

    png = chunked_png('{"op":"subscribe","topic":"/a","type":"std_msgs/String"}', 900_000)
    png_frame = json.dumps({"op": "png", "data": base64.b64encode(png).decode()})
    big_json = json.dumps({"op": "publish", "topic": "/big", "msg": {"data": "x" * (15 << 20)}})
    big16 = "x" * (16 << 20)
    floods: list[Case] = [
        ("16 MB frames x4, no token", False, [big16] * 4, 1),
        ("16 MB frames, 4 connections, no token", False, [big16], 4),
    ]
    cases: list[Case] = [
        ("idle", False, [], 1),
        ("PNG 900k chunks, no token", False, [png_frame], 1),
        ("PNG 900k chunks, pilot", True, [png_frame], 1),
        ("JSON 15 MB, pilot", True, [big_json], 1),
        *floods,
    ]
    with tempfile.TemporaryDirectory() as tmp:
        with server(Path(tmp), capped=True) as target:
            rows = asyncio.run(run_rows(target, cases, rounds))
        # the same floods against uvicorn's plain transport: the app's own check only
        with server(Path(tmp), capped=False) as target:
            before = asyncio.run(run_rows(target, floods, rounds))
    idle = statistics.median(rows[0].stall_ms)
    print(
        f"the server process under attack: loop stall (worst lateness of a {TICK_S * 1000:g} ms "
        f"tick) and peak RSS above its RSS before; median of {rounds} round(s)"
    )
    print(f"{'attack':<52} {'stall ms':>9} {'× idle':>7} {'peak MB':>8}")
    shown = [*rows, *(Row(f"{r.name} (app check only)", r.stall_ms, r.peak_mb) for r in before)]
    for row in shown:
        med = statistics.median(row.stall_ms)
        ratio = med / idle if idle > 0 else float("nan")
        print(f"{row.name:<52} {med:>9.1f} {ratio:>7.1f} {statistics.median(row.peak_mb):>8.1f}")
    print(
        "(app check only: uvicorn's plain websockets-sansio transport, which reads each frame "
        "whole before the app refuses it; the other rows run serve's, which refuses a frame "
        "over 4 KB before auth at its header: server/ws_guard.py)"
    )
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
