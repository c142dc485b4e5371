"""EMERGENCY STOP from the real page: Chromium presses the button on the console of a real
``serve`` (vehicles in their own processes), and the time is taken from the press to the first
``AT*REF`` with the emergency bit on the simulator's AT socket (``drone/sim/probe.py``, which
timestamps what ``drone/sim/server.py`` decodes).

The simulated AR.Drone runs in this benchmark's process (``SimThread``) and ``serve --drone
ADDR`` flies it over the real wire protocol; the page is loaded under its own CSP and holds its
safety-door connection open, as an operator's does. Each stop goes down both roads (REST and the
door); whichever reaches the vehicle first runs it.

Rows (the idle row is the baseline of the ratios):
  idle                    nothing else happening
  web server SIGSTOPped   ``kill -STOP`` on ``serve`` just before the press (resumed after)
  door flood (no token)   attacker processes holding 16 connections each without a token on
                          the vehicle's door, refreshed every 1.5 s, from the page's address
  attack mix              the door flood, plus observers sending the 1-pixel-wide 16 MB png
                          frame (``bench/attacks.py``) to ``/rosbridge``, each the next as
                          soon as the last is answered, plus
                          no-token WebSocket connections to ``/rosbridge`` refreshed every 1.5 s

Every row also polls ``GET /api/v1/health`` every 100 ms during its presses: its p95 is the
web server's own answer time under that row's load.

The press is ``page.mouse.down()`` on the button (the stop fires on pointerdown), so the time
includes the DevTools round trip that delivers the press. Between presses the drone is reset
(REST ``reset``) out of the emergency state.

Usage: ``python bench/stop.py [--trials N] [--quick]``. The machine is shared: the load average
is printed next to the figures.
"""

from __future__ import annotations

import argparse
import contextlib
import multiprocessing as mp
import os
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import httpx  # noqa: E402

from bench.loopback import free_port  # noqa: E402
from bench.polling import wait_for  # noqa: E402
from drone.sim.probe import SimThread  # noqa: E402

HOST = "127.0.26.1"
SIM_ADDR = "127.0.26.31"
TOKEN = "bench-stop-token"
OBSERVER = "bench-stop-observer-token"
PNG_ATTACKERS = 2
NO_TOKEN_WS = 16
CHROMIUM = os.environ.get("UAVC_CHROMIUM", "/usr/bin/chromium")
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--no-first-run"]
FLOOD_PROCS = 4
FLOOD_CONNS = 16
FLOOD_REFRESH_S = 1.5


@contextlib.contextmanager
def serve(tmp: Path) -> Iterator[tuple[subprocess.Popen[bytes], int, httpx.Client]]:
    port = free_port(HOST)
    env = {**os.environ, "UAVC_DATA_DIR": str(tmp / "data"), "PYTHONPATH": str(ROOT)}
    argv = [sys.executable, "-m", "server", "serve", "--host", HOST, "--port", str(port)]
    argv += ["--drone", SIM_ADDR, "--token", TOKEN, "--vehicles", "process"]
    argv += ["--observer-token", OBSERVER]
    log = open(tmp / "serve.log", "wb")  # noqa: SIM115
    proc = subprocess.Popen(argv, cwd=ROOT, env=env, stdout=log, stderr=log)
    http = httpx.Client(
        base_url=f"http://{HOST}:{port}", headers={"Authorization": f"Bearer {TOKEN}"}, timeout=60
    )
    try:
        wait_for(
            lambda: (
                (d := http.get("/api/v1/drones/uav1").json())["link_ok"]
                and d["vehicle"]["connected"]
            ),
            "serve and its vehicle",
            90,
        )
        yield proc, port, http
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.kill(proc.pid, signal.SIGCONT)
        proc.terminate()
        try:
            proc.wait(20)
        except subprocess.TimeoutExpired:
            proc.kill()
        http.close()
        log.close()


def _flood(host: str, port: int) -> None:
    """One attacker: FLOOD_CONNS connections without a token, refreshed every 1.5 s."""
    while True:
        held = []
        for _ in range(FLOOD_CONNS):
            with contextlib.suppress(OSError):
                held.append(socket.create_connection((host, port), timeout=1))
        time.sleep(FLOOD_REFRESH_S)
        for s in held:
            with contextlib.suppress(OSError):
                s.close()


@contextlib.contextmanager
def flood(door_url: str) -> Iterator[None]:
    rest = door_url.split("://", 1)[1]
    host, port = rest.rsplit(":", 1)
    procs = [
        mp.Process(target=_flood, args=(host.strip("[]"), int(port)), daemon=True)
        for _ in range(FLOOD_PROCS)
    ]
    for p in procs:
        p.start()
    time.sleep(2 * FLOOD_REFRESH_S)  # the caps are full before the first press
    try:
        yield
    finally:
        for p in procs:
            p.terminate()
            p.join(5)


def _png_observer(host: str, port: int) -> None:
    """One observer sending the 1 px × 4 M rows PNG frame (bench/attacks.py) again and again,
    reading answers."""
    import asyncio

    import websockets

    from bench.attacks import png_of_rows, png_op

    frame = png_op(
        png_of_rows(1, b'{"op": "call_service", "service": "/rosapi/topics"}', 16 << 20), "x"
    )

    async def attack() -> None:
        url = f"ws://{host}:{port}/rosbridge?token={OBSERVER}"
        while True:
            try:
                async with websockets.connect(url, max_size=None) as ws:
                    while True:  # the next frame as soon as the last is answered
                        await ws.send(frame)
                        await ws.recv()
            except Exception:  # refused or closed: connect again
                await asyncio.sleep(0.1)

    asyncio.run(attack())


def _no_token_ws(host: str, port: int) -> None:
    """WebSocket upgrades to /rosbridge without a token, held and refreshed every 1.5 s."""
    request = (
        f"GET /rosbridge HTTP/1.1\r\nHost: {host}:{port}\r\nUpgrade: websocket\r\n"
        "Connection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
        "Sec-WebSocket-Version: 13\r\n\r\n"
    ).encode()
    while True:
        held = []
        for _ in range(NO_TOKEN_WS):
            with contextlib.suppress(OSError):
                s = socket.create_connection((host, port), timeout=1)
                s.sendall(request)
                held.append(s)
        time.sleep(FLOOD_REFRESH_S)
        for s in held:
            with contextlib.suppress(OSError):
                s.close()


@contextlib.contextmanager
def attack_mix(door_url: str, port: int) -> Iterator[None]:
    procs = [
        *(
            mp.Process(target=_png_observer, args=(HOST, port), daemon=True)
            for _ in range(PNG_ATTACKERS)
        ),
        mp.Process(target=_no_token_ws, args=(HOST, port), daemon=True),
    ]
    for p in procs:
        p.start()
    try:
        with flood(door_url):
            yield
    finally:
        for p in procs:
            p.terminate()
            p.join(5)


class HealthPoller:
    """``GET /api/v1/health`` every 100 ms on its own connection; answer times in seconds."""

    def __init__(self, port: int) -> None:
        import threading

        self.port = port
        self.times: list[float] = []
        self.failed = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        with httpx.Client(base_url=f"http://{HOST}:{self.port}", timeout=30) as client:
            while not self._stop.is_set():
                t0 = time.monotonic()
                try:
                    client.get("/api/v1/health").raise_for_status()
                    self.times.append(time.monotonic() - t0)
                except httpx.HTTPError:
                    self.failed += 1
                self._stop.wait(max(0.0, 0.1 - (time.monotonic() - t0)))

    def __enter__(self) -> HealthPoller:
        self._thread.start()
        return self

    def __exit__(self, *_: object) -> None:
        self._stop.set()
        self._thread.join(35)


def reset(sim: SimThread, http: httpx.Client, lease: str) -> None:
    """Out of the emergency state (``reset`` needs the pilot lease: the page's, named)."""
    wait_for(lambda: sim.truth.emergency, "the emergency state", 30)
    # The bit toggles on a rising edge and the driver holds it a while after the state changed.
    time.sleep(1.0)
    headers = {"X-Pilot-Lease": lease}
    for _ in range(5):
        wait_for(
            lambda: http.post("/api/v1/drones/uav1/reset", headers=headers).status_code == 200,
            "reset",
            60,
        )
        with contextlib.suppress(RuntimeError):
            wait_for(lambda: not sim.truth.emergency, "leaving the emergency state", 5)
            break
    time.sleep(0.5)


def press(page: Any, at: tuple[float, float], sim: SimThread) -> float:
    """Press EMERGENCY STOP; seconds until the emergency bit reached the simulator's wire."""
    t0 = time.monotonic()
    page.mouse.move(*at)
    page.mouse.down()
    page.mouse.up()
    arrived = wait_for(lambda: sim.sim.first_emergency_after(t0), "AT*REF emergency", 60, 0.0005)
    return float(arrived - t0)


def pct(xs: list[float], q: float) -> float:
    s = sorted(xs)
    return s[min(len(s) - 1, round(q / 100 * (len(s) - 1)))]


def main(argv: list[str] | None = None) -> int:
    from playwright.sync_api import sync_playwright

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=None)
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args(argv)
    trials = args.trials or (5 if args.quick else 20)
    print(f"load before: {os.getloadavg()} on {os.cpu_count()} cores (shared machine)")
    results: dict[str, list[float]] = {}
    roads: dict[str, dict[str, int]] = {}
    health: dict[str, tuple[float, int]] = {}
    with (
        tempfile.TemporaryDirectory() as td,
        SimThread(SIM_ADDR) as sim,
        serve(Path(td)) as (proc, port, http),
        sync_playwright() as pw,
    ):
        browser = pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
        page = browser.new_context(viewport={"width": 1440, "height": 900}).new_page()
        page.goto(f"http://{HOST}:{port}/?token={TOKEN}")
        wait_for(lambda: page.evaluate("document.body.dataset.doorRoad === 'ok'"), "the door", 30)
        wait_for(lambda: page.evaluate("uavConsole.haveLease === true"), "the lease", 30)
        lease = str(page.evaluate("uavConsole.api.leaseHolder"))
        box = page.locator("#btn-emergency").bounding_box()
        assert box is not None
        at = (box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
        door_url = http.get("/api/v1/drones/uav1").json()["vehicle"]["door_url"]

        def run(label: str, before: Callable[[], None], after: Callable[[], None]) -> None:
            xs: list[float] = []
            by: dict[str, int] = {}
            poller = HealthPoller(port).__enter__()
            for _ in range(trials):
                page.evaluate("document.body.dataset.stop = ''")
                before()
                try:
                    xs.append(press(page, at, sim))
                    wait_for(
                        lambda: page.evaluate("document.body.dataset.stop === 'delivered'"),
                        "the page's acknowledgement",
                        30,
                    )
                    text = str(page.evaluate("document.body.dataset.stopText"))
                    road = "door" if "safety door" in text else "server"
                    by[road] = by.get(road, 0) + 1
                finally:
                    after()
                reset(sim, http, lease)
            poller.__exit__()
            results[label], roads[label] = xs, by
            health[label] = (pct(poller.times, 95) if poller.times else float("nan"), poller.failed)

        nothing = lambda: None  # noqa: E731
        run("idle", nothing, nothing)
        run(
            "web server SIGSTOPped",
            lambda: os.kill(proc.pid, signal.SIGSTOP),
            lambda: os.kill(proc.pid, signal.SIGCONT),
        )
        with flood(door_url):
            run(f"door flood ({FLOOD_PROCS}x{FLOOD_CONNS} no-token conns)", nothing, nothing)
        with attack_mix(door_url, port):
            run("attack mix (png + door + no-token floods)", nothing, nothing)
        browser.close()
    print(f"load after: {os.getloadavg()}")
    base = results["idle"]
    print(
        "| press -> AT*REF emergency bit            |   n |  p50 ms |  p99 ms |  max ms "
        "| p50 / idle | p99 / idle | acked by | /health p95 ms (failed)"
    )
    print(
        "|-----------------------------------------|-----|---------|---------|---------|"
        "------------|------------|----------|------------------------"
    )
    for label, xs in results.items():
        ms = [x * 1000 for x in xs]
        p50, p99 = statistics.median(ms), pct(ms, 99)
        r50 = p50 / (statistics.median(base) * 1000)
        r99 = p99 / (pct(base, 99) * 1000)
        acked = ", ".join(f"{k} {v}" for k, v in sorted(roads[label].items()))
        print(
            f"| {label:<39} | {len(ms):>3} | {p50:7.1f} | {p99:7.1f} | {max(ms):7.1f} "
            f"| {r50:10.2f} | {r99:10.2f} | {acked} "
            f"| {health[label][0] * 1000:.0f} ({health[label][1]})"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
