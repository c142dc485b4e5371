"""Decode attacks against the rosbridge door, sent by each role, measured as the stall they
cause on the event loop the drones' safety shares and as ``/health``'s latency meanwhile.

The server runs in its own process (the attacking client's work is in none of its figures): the
rosbridge router, a 5 ms ticker on its loop (the stall is the worst lateness of a tick), a sync
``GET /health`` as the real one is (answered from the thread pool, through the loop), and
``GET /bench/stall`` / ``/bench/decoder`` to read the figures. Each attack runs for at least
``--window`` seconds (its frames sent again and again, one connection, each frame's answer
awaited; reconnecting when the server closes it) while another thread polls ``/health``; then
the worst tick lateness and the p95 of ``/health`` in that window are taken. Each figure is the
median of ``--rounds`` windows; the idle loop (the same window, no attack) is the baseline of
the same run.

Decode attacks (the frames that are expensive to decode), sent uncompressed
unless named "deflate" (permessage-deflate, RFC 7692, as browsers and Node's ``ws`` send):
  PNG 1 px × 4 M rows     a 21 857-byte frame: 16 MB of 1-pixel rows.
  PNG 1000 px, 4 MB       the largest PNG within the budget: decoded by a worker.
  PNG zlib bomb           a 10×10 header over 64 MB of zeros: inflation stops at 310 bytes.
  PNG 900k chunks         ~900 000 one-byte IDAT chunks: refused at the chunk cap.
  JSON 15 MB string       one large valid frame: decoded by a worker.
  JSON 4 MB of numbers    ~2 M values: over the value budget (a worker parses, then refuses).
  CBOR 1 MB of small ints ~1 M values in a binary frame: the same.
  fragments, 8 MB         140 fragments of 60 KB reassembling one 8 MB message.
  deflate: 100 × 60 KB    ~8 KB on the wire inflating to 6 MB (one socket read held thousands
                          of such messages: an observer's stalled the loop 1.1 s).
  deflate: 15 MB message  one compressed message over the 4 MiB it may inflate to.
Roles: no token (the transport caps frames before auth at 4 KB), observer (no png at all;
frames and messages of at most 64 KB), pilot without the lease.

Then: the attacks that reach a worker, with the pool's processes against threads (the GIL:
``json.loads`` holds it for a whole call); the permessage-deflate attacks with the transport's
inflation metered and not (``server.http.ws_guard.InflateLimits``); the 16 MB pre-auth floods
against the capped and the plain transport; and, outside the server, a per-row PNG decoder
(rows sliced one by one in Python, the baseline) against the linear one, at width 1 and
1000.

Usage: ``python bench/attacks.py [--quick] [--rounds N] [--window S]``. Figures depend on the
machine's load: compare rows of one run, not runs.
"""

from __future__ import annotations

import argparse
import asyncio
import base64
import contextlib
import json
import math
import multiprocessing
import os
import socket
import statistics
import struct
import sys
import threading
import time
import urllib.request
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import cbor2  # noqa: E402
import numpy as np  # noqa: E402
import uvicorn  # noqa: E402
from fastapi import FastAPI  # noqa: E402
from websockets.asyncio.client import connect  # noqa: E402

from server.graph import Graph  # noqa: E402
from server.http.security import Security, TokenStore  # noqa: E402
from server.http.ws_guard import InflateLimits, preauth_capped_ws  # noqa: E402
from server.rosbridge.budget import DecodeBudget, png_text  # noqa: E402
from server.rosbridge.context import BridgeContext  # noqa: E402
from server.rosbridge.encode import PNG_SIGNATURE, fragments, png_encode  # noqa: E402
from server.rosbridge.endpoint import make_router  # noqa: E402
from server.settings import Settings  # noqa: E402

HOST = "127.0.14.20"
TICK_S = 0.005
HEALTH_PERIOD_S = 0.01
# permessage-deflate as websockets does it alone: no cap but the transport's, no pacing
UNMETERED = InflateLimits(
    max_message_bytes=1 << 40, per_turn_bytes=1 << 40, rate_bytes_per_s=1e15, burst_bytes=1e15
)


# -- frames --------------------------------------------------------------------------------------
def _chunk(kind: bytes, body: bytes) -> bytes:
    crc = zlib.crc32(kind + body) & 0xFFFFFFFF
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", crc)


def png_of_rows(width: int, text: bytes, raw_bytes: int) -> bytes:
    """``text`` as an RGB PNG ``width`` pixels wide padded with newlines to ``raw_bytes`` of
    pixel rows (filter byte 0 on each)."""
    stride = 3 * width
    rows = raw_bytes // (stride + 1)
    text = text + b"\n" * (rows * stride - len(text))
    raw = np.zeros((rows, stride + 1), np.uint8)
    raw[:, 1:] = np.frombuffer(text, np.uint8).reshape(rows, stride)
    ihdr = struct.pack(">IIBBBBB", width, rows, 8, 2, 0, 0, 0)
    return (
        PNG_SIGNATURE
        + _chunk(b"IHDR", ihdr)
        + _chunk(b"IDAT", zlib.compress(raw.tobytes(), 9))
        + _chunk(b"IEND", b"")
    )


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


def png_op(png: bytes, id: str) -> str:
    return json.dumps({"op": "png", "id": id, "data": base64.b64encode(png).decode()})


@dataclass
class Attack:
    """Frames sent in order, then ``answers`` answers (status or service response) awaited."""

    name: str
    frames: list[str | bytes]
    answers: int = 1
    reaches_worker: bool = False  # from a pilot, its decoding runs in the pool
    compression: str | None = None  # "deflate": permessage-deflate (as browsers send)


def attacks(quick: bool) -> list[Attack]:
    call = json.dumps({"op": "call_service", "id": "inner", "service": "/rosapi/topics"}).encode()
    numbers = {"op": "publish", "id": "n", "topic": "/big", "msg": {"data": [0] * (2 << 20)}}
    ints = {"op": "publish", "id": "c", "topic": "/big", "msg": {"data": [0] * (1 << 20)}}
    whole = json.dumps(
        {"op": "call_service", "id": "f", "service": "/rosapi/topics", "pad": "x" * (8 << 20)}
    )
    return [
        Attack("PNG 1 px × 4 M rows (16 MB)", [png_op(png_of_rows(1, call, 16 << 20), "p1")]),
        Attack(
            "PNG 1000 px, 4 MB (at the budget)",
            [png_op(png_of_rows(1000, call, (4 << 20) - 3001), "p2")],
            reaches_worker=True,
        ),
        Attack("PNG zlib bomb (10×10 header)", [png_op(bomb_png(), "p3")], reaches_worker=True),
        Attack(
            "PNG 900k chunks",
            [png_op(chunked_png(call.decode(), 100_000 if quick else 900_000), "p4")],
            reaches_worker=True,
        ),
        Attack(
            "JSON 15 MB string",
            [
                json.dumps(
                    {"op": "publish", "id": "j", "topic": "/big", "msg": {"d": "x" * (15 << 20)}}
                )
            ],
            reaches_worker=True,
        ),
        Attack("JSON 4 MB of numbers", [json.dumps(numbers)], reaches_worker=True),
        Attack("CBOR 1 MB of small ints", [cbor2.dumps(ints)], reaches_worker=True),
        Attack(
            "fragments, 8 MB message",
            list(fragments(whole, 60_000, "frag")),
            reaches_worker=True,
        ),
        Attack(
            "deflate: 100 × 60 KB messages",
            [json.dumps({"op": "nope", "id": f"d{n}", "pad": "x" * 60_000}) for n in range(100)],
            answers=100,
            compression="deflate",
        ),
        Attack(
            "deflate: 15 MB message",
            [
                json.dumps(
                    {"op": "publish", "id": "z", "topic": "/big", "msg": {"d": "x" * (15 << 20)}}
                )
            ],
            compression="deflate",
        ),
    ]


def bomb_png() -> bytes:
    ihdr = struct.pack(">IIBBBBB", 10, 10, 8, 2, 0, 0, 0)
    idat = zlib.compress(b"\0" * (64 << 20), 9)
    return PNG_SIGNATURE + _chunk(b"IHDR", ihdr) + _chunk(b"IDAT", idat) + _chunk(b"IEND", b"")


# -- the server under attack ----------------------------------------------------------------------
def _serve(host: str, port: int, tmp: str, capped: bool, backend: str, metered: bool) -> None:
    """The server under attack, in its own process; see the module docstring."""
    settings = Settings(host=host, port=port, data_dir=Path(tmp))
    graph = Graph()
    ctx = BridgeContext(graph, Security(settings, TokenStore(Path(tmp))), settings)
    ctx.decode_backend = backend  # type: ignore[assignment]
    lateness: list[float] = []
    busy: list[float] = []  # CPU time of the loop's thread between two ticks

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI):  # type: ignore[no-untyped-def]
        loop = asyncio.get_running_loop()
        graph.bind_loop(loop)

        async def ticker() -> None:
            due = loop.time()
            cpu = time.thread_time()
            while True:
                due += TICK_S
                await asyncio.sleep(max(0.0, due - loop.time()))
                lateness.append(loop.time() - due)
                now = time.thread_time()
                busy.append(now - cpu)
                cpu = now

        task = asyncio.create_task(ticker())
        yield
        task.cancel()
        ctx.close()

    app = FastAPI(lifespan=lifespan)
    app.include_router(make_router(ctx))

    @app.get("/health")
    def health() -> dict[str, str]:  # sync, as server/api/system.py's: thread pool, then loop
        return {"status": "ok"}

    @app.get("/bench/stall")
    def stall(since: int = 0) -> dict[str, float]:
        window, cpu = lateness[since:], busy[since:]
        return {
            "ticks": len(lateness),
            "stall_ms": 1000 * max(window) if window else 0.0,
            "cpu_ms": 1000 * max(cpu) if cpu else 0.0,
        }

    @app.get("/bench/decoder")
    def decoder() -> dict[str, int]:
        s = ctx.decoder.stats
        return {"submitted": s.submitted, "inflated": s.png_inflated, "busy": s.refused_busy}

    config = uvicorn.Config(
        app,
        host=host,
        port=port,
        log_level="error",
        ws_max_size=64 << 20,  # as serve: 4 × the 16 MB frame limit
        ws=preauth_capped_ws(inflate=None if metered else UNMETERED)
        if capped
        else "websockets-sansio",
        ws_ping_interval=None,
    )
    uvicorn.Server(config).run()


@dataclass
class Target:
    """A running :func:`_serve` process."""

    port: int
    pilot: str
    observer: str
    pid: int

    def get(self, path: str) -> dict[str, float]:
        with urllib.request.urlopen(f"http://{HOST}:{self.port}{path}", timeout=60) as r:
            return dict(json.loads(r.read()))

    def url(self, role: str) -> str:
        token = {"pilot": self.pilot, "observer": self.observer}.get(role)
        base = f"ws://{HOST}:{self.port}/rosbridge"
        return f"{base}?token={token}" if token else base


@contextlib.contextmanager
def server(
    tmp: Path, *, capped: bool = True, backend: str = "process", metered: bool = True
) -> Iterator[Target]:
    with socket.socket() as s:
        s.bind((HOST, 0))
        port = int(s.getsockname()[1])
    tokens = TokenStore(tmp)  # the child loads the same token file
    proc = multiprocessing.get_context("spawn").Process(
        target=_serve, args=(HOST, port, str(tmp), capped, backend, metered), daemon=False
    )
    proc.start()
    assert proc.pid is not None
    target = Target(port, tokens.pilot_token, tokens.observer_token, proc.pid)
    deadline = time.monotonic() + 60
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


# -- measuring ----------------------------------------------------------------------------------
class HealthPoller:
    """``GET /health`` back to back (``HEALTH_PERIOD_S`` apart) in a thread; latencies kept."""

    def __init__(self, target: Target) -> None:
        self.url = f"http://{HOST}:{target.port}/health"
        self.latencies: list[float] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.is_set():
            t0 = time.perf_counter()
            try:
                with urllib.request.urlopen(self.url, timeout=120) as r:
                    r.read()
            except OSError:
                pass
            self.latencies.append(time.perf_counter() - t0)
            self._stop.wait(HEALTH_PERIOD_S)

    def __enter__(self) -> HealthPoller:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(150)


def p95(values: list[float]) -> float:
    if not values:
        return math.nan
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, math.ceil(0.95 * len(ordered)) - 1)]


async def run_attack(url: str, attack: Attack, window_s: float) -> int:
    """Send ``attack`` again and again for ``window_s`` (at least once); the times sent."""
    loop = asyncio.get_running_loop()
    end = loop.time() + window_s
    sent = 0
    while sent == 0 or loop.time() < end:
        with contextlib.suppress(Exception):
            async with connect(
                url,
                max_size=None,
                ping_interval=None,
                open_timeout=60,
                compression=attack.compression,
            ) as ws:
                while sent == 0 or loop.time() < end:
                    for f in attack.frames:
                        await ws.send(f)
                    sent += 1
                    got = 0
                    async with asyncio.timeout(120):
                        while got < attack.answers:
                            msg = await ws.recv()
                            if isinstance(msg, str) and '"op": "fragment"' not in msg:
                                got += 1
        if sent == 0:
            sent = 1  # could not even connect: counted as sent, the window still applies
    return sent


@dataclass
class Row:
    name: str
    stall_ms: list[float] = field(default_factory=list)
    cpu_ms: list[float] = field(default_factory=list)
    health_p95_ms: list[float] = field(default_factory=list)
    health_n: list[int] = field(default_factory=list)
    worker: list[int] = field(default_factory=list)  # frames the pool took
    inflated: list[int] = field(default_factory=list)

    def med(self, values: list[float] | list[int]) -> float:
        return statistics.median(values) if values else math.nan


async def measure(
    target: Target, name: str, role: str | None, attack: Attack | None, window_s: float
) -> Row:
    row = Row(name)
    since = int(target.get("/bench/stall")["ticks"])
    before = target.get("/bench/decoder")
    with HealthPoller(target) as health:
        if attack is None:
            await asyncio.sleep(window_s)
        else:
            await run_attack(target.url(role or ""), attack, window_s)
    after = target.get("/bench/decoder")
    stall = target.get(f"/bench/stall?since={since}")
    row.stall_ms.append(stall["stall_ms"])
    row.cpu_ms.append(stall["cpu_ms"])
    row.health_p95_ms.append(1000 * p95(health.latencies))
    row.health_n.append(len(health.latencies))
    row.worker.append(int(after["submitted"] - before["submitted"]))
    row.inflated.append(int(after["inflated"] - before["inflated"]))
    return row


def merge(rows: list[Row]) -> Row:
    out = Row(rows[0].name)
    for r in rows:
        out.stall_ms += r.stall_ms
        out.cpu_ms += r.cpu_ms
        out.health_p95_ms += r.health_p95_ms
        out.health_n += r.health_n
        out.worker += r.worker
        out.inflated += r.inflated
    return out


ROLES = [("no token", None), ("observer", "observer"), ("pilot, no lease", "pilot")]


async def role_matrix(
    target: Target, cases: list[Attack], rounds: int, window_s: float
) -> tuple[Row, list[tuple[Attack, str, Row]]]:
    idle: list[Row] = []
    results: dict[tuple[str, str], list[Row]] = {}
    for _ in range(rounds):
        idle.append(await measure(target, "idle", None, None, window_s))
        for attack in cases:
            for label, role in ROLES:
                url_role = role if role is not None else "anonymous"
                row = await measure(target, attack.name, url_role, attack, window_s)
                results.setdefault((attack.name, label), []).append(row)
    out = [(a, label, merge(results[(a.name, label)])) for a in cases for label, _ in ROLES]
    return merge(idle), out


async def backend_rows(
    target: Target, cases: list[Attack], rounds: int, window_s: float
) -> tuple[Row, list[Row]]:
    idle: list[Row] = []
    per: dict[str, list[Row]] = {}
    for _ in range(rounds):
        idle.append(await measure(target, "idle", None, None, window_s))
        for attack in cases:
            per.setdefault(attack.name, []).append(
                await measure(target, attack.name, "pilot", attack, window_s)
            )
    return merge(idle), [merge(per[a.name]) for a in cases]


# -- the PNG decoders, outside the server --------------------------------------------------------
def per_row_png_text(png: bytes) -> str:
    """The decoder of before (rows sliced one by one in a Python list: per-row cost)."""
    pos, width = len(PNG_SIGNATURE), 0
    inflater = zlib.decompressobj()
    out = bytearray()
    while pos < len(png):
        (length,) = struct.unpack_from(">I", png, pos)
        kind = png[pos + 4 : pos + 8]
        if kind == b"IHDR":
            width = struct.unpack_from(">I", png, pos + 8)[0]
        elif kind == b"IDAT":
            out += inflater.decompress(png[pos + 8 : pos + 8 + length])
        pos += 12 + length
    stride = width * 3 + 1
    raw = bytes(out)
    rows = [raw[i + 1 : i + stride] for i in range(0, len(raw), stride)]
    return b"".join(rows).decode("utf-8")


def decoder_rows(size: int) -> list[tuple[int, float, float]]:
    unlimited = DecodeBudget(
        max_png_pixels=1 << 40, max_png_bytes=1 << 40, max_png_chunks=1 << 20, max_work_s=math.inf
    )
    out = []
    for width in (1, 1000):
        png = png_of_rows(width, b'{"op":"status"}', size)
        t0 = time.perf_counter()
        old = per_row_png_text(png)
        t_old = time.perf_counter() - t0
        t0 = time.perf_counter()
        new = png_text(png, unlimited)
        t_new = time.perf_counter() - t0
        assert old == new
        out.append((width, t_old, t_new))
    return out


# -- report -------------------------------------------------------------------------------------
def fmt(row: Row, idle: Row) -> str:
    stall = row.med(row.stall_ms)
    ratio = stall / idle.med(idle.stall_ms) if idle.med(idle.stall_ms) > 0 else math.nan
    hp = row.med(row.health_p95_ms)
    hratio = hp / idle.med(idle.health_p95_ms) if idle.med(idle.health_p95_ms) > 0 else math.nan
    return (
        f"{stall:>9.1f} {ratio:>7.1f} {row.med(row.cpu_ms):>7.1f} {hp:>11.1f} {hratio:>7.1f}"
        f" {row.med(row.health_n):>6.0f} {row.med(row.worker):>7.0f} {row.med(row.inflated):>8.0f}"
    )


HEAD = (
    f"{'stall ms':>9} {'× idle':>7} {'cpu ms':>7} {'/health p95':>11} {'× idle':>7} {'polls':>6}"
    f" {'worker':>7} {'inflated':>8}"
)


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="1 round, a shorter window")
    ap.add_argument("--rounds", type=int, default=None)
    ap.add_argument("--window", type=float, default=None, help="seconds per attack window")
    args = ap.parse_args()
    rounds = args.rounds or (1 if args.quick else 3)
    window_s = args.window or (1.0 if args.quick else 2.0)
    import tempfile

    cases = attacks(args.quick)
    big16 = "x" * (16 << 20)
    floods = [
        Attack("16 MB frames x4, no token", [big16] * 4, answers=0),
    ]
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        with server(Path(tmp)) as target:
            idle, matrix = asyncio.run(role_matrix(target, cases, rounds, window_s))
        worker_cases = [a for a in cases if a.reaches_worker]
        with server(Path(tmp), backend="thread") as target:
            t_idle, t_rows = asyncio.run(backend_rows(target, worker_cases, rounds, window_s))
        with server(Path(tmp)) as target:
            p_idle, p_rows = asyncio.run(backend_rows(target, worker_cases, rounds, window_s))
        deflate_cases = [a for a in cases if a.compression == "deflate"]
        metering = []
        for metered in (True, False):
            with server(Path(tmp), metered=metered) as target:
                m_idle, m = asyncio.run(role_matrix(target, deflate_cases, rounds, window_s))
                metering.append((metered, m_idle, m))
        flood_rows = []
        for capped in (True, False):
            with server(Path(tmp), capped=capped) as target:
                f_idle, f = asyncio.run(role_matrix(target, floods, rounds, window_s))
                flood_rows.append((capped, f_idle, f[0][2]))
    print(
        f"Decode attacks, each role, against the server in its own process (worker pool: "
        f"processes). Median of {rounds} window(s) of ≥ {window_s:g} s each; stall = worst "
        f"lateness of a {TICK_S * 1000:g} ms tick on its loop (wall: preemption by other "
        "processes and waits for the GIL included); cpu = the most CPU time the loop's thread "
        "spent between two ticks (its own work only); /health polled every "
        f"{HEALTH_PERIOD_S * 1000:g} ms; worker = frames the pool decoded; inflated = PNGs "
        "inflated (past the header's budget)."
    )
    print(
        f"Machine: {os.cpu_count()} CPUs, load average {load_before:.1f} before the run, "
        f"{os.getloadavg()[0]:.1f} after."
    )
    print(f"{'attack':<36} {'role':<16} {HEAD}")
    print(f"{'idle (baseline)':<36} {'':<16} {fmt(idle, idle)}")
    for attack, label, row in matrix:
        print(f"{attack.name:<36} {label:<16} {fmt(row, idle)}")
    print(
        "\nThe attacks a pilot's frames take to the worker pool: processes against threads "
        "(each against its own idle baseline, same run)."
    )
    print(f"{'attack, pilot':<36} {'pool':<8} {HEAD}")
    for label, base, rows in (("process", p_idle, p_rows), ("thread", t_idle, t_rows)):
        print(f"{'idle (baseline)':<36} {label:<8} {fmt(base, base)}")
        for row in rows:
            print(f"{row.name:<36} {label:<8} {fmt(row, base)}")
    print(
        "\npermessage-deflate: the transport's metered inflation (16 MiB a message, 1 MiB a turn "
        "of the loop, 16 MiB/s) against websockets' own (each against its idle baseline)."
    )
    print(f"{'attack':<36} {'role':<16} {'inflation':<10} {HEAD}")
    for metered, base, rows in metering:
        label = "metered" if metered else "unmetered"
        print(f"{'idle (baseline)':<36} {'':<16} {label:<10} {fmt(base, base)}")
        for attack, role, row in rows:
            print(f"{attack.name:<36} {role:<16} {label:<10} {fmt(row, base)}")
    print("\n16 MB frames before auth: the transport's cap against uvicorn's plain one.")
    print(f"{'flood':<36} {'transport':<10} {HEAD}")
    for capped, base, row in flood_rows:
        label = "capped" if capped else "plain"
        print(f"{'idle (baseline)':<36} {label:<10} {fmt(base, base)}")
        print(f"{row.name:<36} {label:<10} {fmt(row, base)}")
    size = (4 << 20) if args.quick else (16 << 20)
    print(f"\nPNG of {size >> 20} MB of pixel rows, decoded outside the server:")
    print(f"{'width':>6} {'per-row (before) ms':>20} {'linear ms':>10} {'ratio':>7}")
    for width, t_old, t_new in decoder_rows(size):
        print(f"{width:>6} {t_old * 1000:>20.0f} {t_new * 1000:>10.1f} {t_old / t_new:>7.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
