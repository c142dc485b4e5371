"""Flight-critical isolation: emergency latency to the wire and control-loop timing,
the flight stack in the web process (``--vehicles inline``, the baseline) vs in its own process
(``--vehicles process``), measured in the same run.

The simulated AR.Drone runs in this benchmark's own process (``drone.sim.probe.SimThread``), and
``uav-console serve --drone 127.0.13.x`` flies it over the real wire protocol, so latency is
taken where it matters: from the moment a client sends the stop to the moment the first
``AT*REF`` with the emergency bit reaches the simulator's AT socket.

Rows:
  emergency idle          REST ``POST /drones/uav1/emergency`` (and, in process mode, a stop
                          on the vehicle's safety door, held open) -> AT*REF emergency bit.
  emergency under attack  the same while the web process decodes a ``png`` rosbridge frame sent
                          *before authenticating* whose PNG has N one-byte IDAT chunks (the
                          quadratic PNG decoder; N = 900 000 froze its loop 12 s);
                          or while 4 unauthenticated connections send back-to-back 16 MB frames.
  control loop            the 100 Hz controller's period error p99 (its own TimingRecorder) with
                          10 WebSocket clients streaming the camera and navdata, the captioner
                          describing in a loop and 3 clients posting spoken commands to
                          ``/speech`` back to back (decoded by the server's Whisper pool), and
                          whether the control thread got real-time scheduling. Targets: p99
                          <= 0.5 ms; emergency p99 <= 20 ms idle, <= 50 ms under attack.

Usage: ``python bench/isolation.py [--quick] [--png-chunks N] [--load-s S]``. The machine is
shared: say how loaded it was next to any figure (``uptime`` is printed).
"""

from __future__ import annotations

import argparse
import base64
import contextlib
import itertools
import json
import multiprocessing as mp
import os
import signal
import statistics
import struct
import subprocess
import sys
import tempfile
import threading
import time
import zlib
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import httpx  # noqa: E402
from websockets.sync.client import connect  # noqa: E402

from bench.loopback import free_port  # noqa: E402
from bench.polling import wait_for  # noqa: E402
from drone.sim.probe import SimThread  # noqa: E402
from tests.speech.conftest import synthesise  # noqa: E402

HOST = "127.0.13.1"
SPEECH_CLIPS = 12  # > the 8 results server/speech/memo.py keeps: every post is decoded
TOKEN = "bench-isolation-token"
SIM_ADDRS = {"inline": "127.0.13.30", "process": "127.0.13.31"}


@contextlib.contextmanager
def serve(mode: str, sim_addr: str, tmp: Path) -> Iterator[tuple[int, httpx.Client]]:
    port = free_port(HOST)
    env = {**os.environ, "UAVC_DATA_DIR": str(tmp / mode)}
    argv = [sys.executable, "-m", "server", "serve", "--host", HOST, "--port", str(port)]
    argv += ["--drone", sim_addr, "--token", TOKEN, "--vehicles", mode]
    log = open(tmp / f"{mode}.log", "wb")  # noqa: SIM115
    proc = subprocess.Popen(argv, cwd=ROOT, env=env, stdout=log, stderr=log)
    http = httpx.Client(
        base_url=f"http://{HOST}:{port}", headers={"Authorization": f"Bearer {TOKEN}"}, timeout=120
    )
    try:
        wait_for(lambda: http.get("/api/v1/drones/uav1").json()["link_ok"], f"{mode} server", 60)
        yield port, http
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


# ---------------------------------------------------------------------------------- attacks
def png_bomb(chunks: int) -> str:
    """A ``png`` op whose PNG has ``chunks`` one-byte IDAT chunks."""
    data = zlib.compress(b"\x00" * 4)
    head = b"\x89PNG\r\n\x1a\n"
    ihdr = struct.pack(">IIBBBBB", 1, 1, 8, 2, 0, 0, 0)
    parts = [head, struct.pack(">I", len(ihdr)), b"IHDR", ihdr, b"\0\0\0\0"]
    pad = data + b"\0" * max(0, chunks - len(data))
    one = [struct.pack(">I", 1) + b"IDAT" + pad[i : i + 1] + b"\0\0\0\0" for i in range(chunks)]
    png = b"".join(parts) + b"".join(one)
    return json.dumps({"op": "png", "data": base64.b64encode(png).decode("ascii")})


def _png_attacker(url: str, frame: str, out: Any) -> None:
    with contextlib.suppress(Exception), connect(url, max_size=None) as ws:
        t0 = time.monotonic()
        ws.send(frame)
        with contextlib.suppress(Exception):
            ws.recv(timeout=120)
        out.put(time.monotonic() - t0)


def _big_attacker(url: str) -> None:
    blob = json.dumps({"op": "publish", "topic": "/x", "msg": {"data": "a" * (16 << 20)}})
    while True:
        with contextlib.suppress(Exception), connect(url, max_size=None) as ws:
            while True:
                ws.send(blob)


class Attack:
    """Attackers in their own processes (so they never share this process's GIL with the
    measuring simulator); ``stall_s``: how long the server took to answer the PNG bomb."""

    def __init__(self, port: int, kind: str, frame: str | None) -> None:
        url = f"ws://{HOST}:{port}/rosbridge"
        self.stall_s: list[float] = []
        self._out: Any = mp.Queue()
        if kind == "png":
            assert frame is not None
            self.procs = [mp.Process(target=_png_attacker, args=(url, frame, self._out))]
        else:
            self.procs = [mp.Process(target=_big_attacker, args=(url,)) for _ in range(4)]
        self.kind = kind

    def __enter__(self) -> Attack:
        for p in self.procs:
            p.start()
        return self

    def __exit__(self, *exc: object) -> None:
        if self.kind == "png":
            self.procs[0].join(120)
            with contextlib.suppress(Exception):
                self.stall_s.append(float(self._out.get(timeout=1)))
        for p in self.procs:
            if p.is_alive():
                p.terminate()
            p.join(10)


# ---------------------------------------------------------------------------------- emergency
def trial(sim: SimThread, http: httpx.Client, click: Callable[[], Any]) -> float:
    """One stop: ``click`` (in a thread: a REST call may block) -> first emergency REF (s)."""
    t0 = time.monotonic()
    th = threading.Thread(target=_quiet(click), daemon=True)
    th.start()
    arrived = wait_for(
        lambda: sim.sim.first_emergency_after(t0), "emergency on the wire", 120, 0.0005
    )
    return float(arrived - t0)


def _quiet(fn: Callable[[], Any]) -> Callable[[], None]:
    def run() -> None:
        with contextlib.suppress(Exception):
            fn()

    return run


def reset(sim: SimThread, http: httpx.Client) -> None:
    wait_for(lambda: sim.truth.emergency, "the emergency state", 30)
    # The bit toggles on a rising edge and the driver holds it a while after the state changed:
    # a reset sent while it is still held would be no edge at all.
    time.sleep(1.0)
    for _ in range(5):
        wait_for(lambda: http.post("/api/v1/drones/uav1/reset").status_code == 200, "reset", 60)
        with contextlib.suppress(RuntimeError):
            wait_for(lambda: not sim.truth.emergency, "leaving the emergency state", 5)
            break
    time.sleep(1.0)


def clicks(http: httpx.Client, mode: str) -> dict[str, Callable[[], Any]]:
    out: dict[str, Callable[[], Any]] = {
        "REST": lambda: http.post("/api/v1/drones/uav1/emergency"),
    }
    if mode == "process":
        url = http.get("/api/v1/drones/uav1").json()["vehicle"]["door_url"]
        door = connect(url)  # held open, as the console page holds it
        door.send(json.dumps({"op": "auth", "token": TOKEN}))
        assert json.loads(door.recv(timeout=10))["op"] == "hello"
        # read its heartbeats and acks (a client that does not read is closed by the door)
        threading.Thread(target=_quiet(lambda: [None for _ in door]), daemon=True).start()
        count = itertools.count()

        def stop() -> None:
            door.send(json.dumps({"op": "stop", "action": "emergency", "id": f"b{next(count)}"}))

        out["safety door"] = stop
    return out


def pct(xs: list[float], q: float) -> float:
    s = sorted(xs)
    return s[min(len(s) - 1, round(q / 100 * (len(s) - 1)))]


def row(label: str, xs: list[float], extra: str = "") -> str:
    ms = [x * 1000 for x in xs]
    return (
        f"| {label:<46} | {len(ms):>3} | {statistics.median(ms):9.1f} | {pct(ms, 99):9.1f} | "
        f"{max(ms):9.1f} | {extra}"
    )


# ---------------------------------------------------------------------------------- loop
def loop_under_load(
    port: int, http: httpx.Client, seconds: float, speech: list[bytes], speakers: int = 3
) -> dict[str, Any]:
    """10 streaming clients + the captioner + ``speakers`` clients posting the WAVs of
    ``speech`` in turn to ``/speech?execute=false`` back to back (the server decodes them in its
    worker pool) for ``seconds``; the controller's stats after. ``speech`` holds more clips than
    the server's result memo keeps (8), each with its own noise, so every post is decoded."""
    stop = threading.Event()
    received = [0]
    decoded = [0]

    def client() -> None:
        with connect(f"ws://{HOST}:{port}/rosbridge?token={TOKEN}", max_size=None) as ws:
            for topic, typ in (
                ("/ardrone/image_raw/compressed", "sensor_msgs/CompressedImage"),
                ("/ardrone/navdata", "ardrone_autonomy/Navdata"),
                ("/uav/pose", "geometry_msgs/PoseStamped"),
            ):
                ws.send(json.dumps({"op": "subscribe", "topic": topic, "type": typ}))
            while not stop.is_set():
                with contextlib.suppress(TimeoutError):
                    ws.recv(timeout=0.5)
                    received[0] += 1

    def captioner() -> None:
        while not stop.is_set():
            with contextlib.suppress(httpx.HTTPError):
                http.post("/api/v1/drones/uav1/describe")

    clips = itertools.cycle(speech)

    def speaker() -> None:
        while not stop.is_set():
            with contextlib.suppress(httpx.HTTPError):
                r = http.post(
                    "/api/v1/speech",
                    params={"execute": "false"},
                    content=next(clips),
                    headers={"Content-Type": "audio/wav"},
                )
                if r.status_code == 200 and r.json()["text"]:
                    decoded[0] += 1
                else:
                    time.sleep(0.1)  # the pool said busy: ask again shortly

    threads = [threading.Thread(target=client, daemon=True) for _ in range(10)]
    threads.append(threading.Thread(target=captioner, daemon=True))
    threads += [threading.Thread(target=speaker, daemon=True) for _ in range(speakers)]
    for t in threads:
        t.start()
    time.sleep(seconds)
    stats = dict(http.get("/api/v1/drones/uav1").json()["controller"])
    stop.set()
    for t in threads:
        t.join(10)
    stats["frames_received"] = received[0]
    stats["speech_decoded"] = decoded[0]
    return stats


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--trials", type=int, default=None)
    ap.add_argument("--png-chunks", type=int, default=None)
    ap.add_argument("--load-s", type=float, default=None)
    ap.add_argument("--modes", default="inline,process")
    args = ap.parse_args(argv)
    trials = args.trials or (5 if args.quick else 20)
    attack_trials = 2 if args.quick else 5
    chunks = args.png_chunks or (200_000 if args.quick else 400_000)
    load_s = args.load_s or (20.0 if args.quick else 65.0)
    print(f"load before: {os.getloadavg()} on {os.cpu_count()} cores (shared machine)")
    bomb = png_bomb(chunks)
    with tempfile.TemporaryDirectory() as td:
        speech = [
            synthesise(
                Path(td) / f"{i}.wav", "take off and climb one meter", snr_db=30, seed=i
            ).read_bytes()
            for i in range(SPEECH_CLIPS)
        ]
    print(f"png bomb: {chunks} one-byte IDAT chunks, frame {len(bomb) / 1e6:.1f} MB")
    lines = [
        f"| {'emergency: click -> AT*REF bit on the wire':<46} |   n |   p50 ms |   p99 ms |"
        "   max ms | note",
        f"|{'-' * 48}|-----|----------|----------|----------|------",
    ]
    loops: dict[str, dict[str, Any]] = {}
    with tempfile.TemporaryDirectory() as td:
        for mode in args.modes.split(","):
            with (
                SimThread(SIM_ADDRS[mode]) as sim,
                serve(mode, SIM_ADDRS[mode], Path(td)) as (
                    port,
                    http,
                ),
            ):
                paths = clicks(http, mode)
                for path, click in paths.items():
                    xs = []
                    for _ in range(trials):
                        xs.append(trial(sim, http, click))
                        reset(sim, http)
                    lines.append(row(f"{mode}, {path}, idle", xs))
                for kind in ("png", "16MB"):
                    for path, click in paths.items():
                        xs, stalls = [], []
                        for _ in range(attack_trials):
                            with Attack(port, kind, bomb if kind == "png" else None) as attack:
                                time.sleep(0.5 if kind == "png" else 1.0)
                                xs.append(trial(sim, http, click))
                            stalls += attack.stall_s
                            reset(sim, http)
                        note = (
                            f"server answered the bomb after {statistics.median(stalls):.1f} s"
                            if stalls
                            else ""
                        )
                        lines.append(row(f"{mode}, {path}, under {kind} attack", xs, note))
                loops[mode] = loop_under_load(port, http, load_s, speech)
    print("\n".join(lines))
    print()
    print(
        f"| control loop, 10 streaming clients + captioner + 3 speech decodes, {load_s:.0f} s"
        " | p99 period error ms | max ms | overruns | rate Hz | frames to clients"
        " | utterances decoded | control thread"
    )
    print("|---|---|---|---|---|---|---|---|")
    for mode, st in loops.items():
        print(
            f"| {mode} | {st['period_error_p99_s'] * 1000:.3f}"
            f" | {st['period_error_max_s'] * 1000:.2f} | {st['overruns']} | {st['rate_hz']:.1f}"
            f" | {st['frames_received']} | {st['speech_decoded']}"
            f" | {st.get('scheduling', '?')} |"
        )
    if "inline" in loops and "process" in loops:
        ratio = loops["inline"]["period_error_p99_s"] / max(
            loops["process"]["period_error_p99_s"], 1e-9
        )
        print(f"\np99 period error, inline / process: {ratio:.1f}x")
    print(f"load after: {os.getloadavg()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
