"""How long the vehicles on a console's bus are cut off when the console restarts its router for
new vehicle keys (``drone.bus.console.ConsoleBus.rekey``: a key made or revoked while ``serve``
runs).

A console's embedded router and its own session (``ConsoleBus``) in this process, as ``serve``
has them, with its 10 Hz heartbeat; ``--vehicles`` light vehicles in processes of their own
(spawned: no fork after Zenoh opens), each a Zenoh client as ``uav-console vehicle`` is one
(``drone.bus.config.client_config``, its own key), with its liveliness token and telemetry at
``--rate-hz``. The router is restarted ``--restarts`` times, a spare vehicle key added and
removed in turn; each restart's 2 s window alternates with a window as long without one, the
baseline under the same load (on a shared machine the load, not the bus, makes most gaps).
Figures, medians over the restarts (and the worst):

- ``rekey``: the call, from the old router's close to the console's session on the new one;
- ``cut off``: from the close to the last vehicle's liveliness back at the console;
- ``telemetry gap``: the longest silence of a vehicle's telemetry at the console in the window
  (baseline: in a window without a restart);
- ``heartbeat gap``: the longest silence of the console's heartbeat at a vehicle in the window
  (a vehicle hovers after 1 s of it: ``heartbeat_timeout_s``).

Usage: ``python bench/bus_rekey.py [--vehicles 5] [--restarts 7] [--rate-hz 50]``.
"""

from __future__ import annotations

import argparse
import itertools
import multiprocessing as mp
import os
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

FLEET = "bench"
POSE = {"x": 1.0, "y": 2.0, "z": 1.0, "yaw_deg": 0.0, "battery_pct": 80.0, "state": "HOVERING"}


def vehicle_worker(
    connect: list[str], name: str, key: str, rate_hz: float, stop: Any, out: Any
) -> None:
    """One light vehicle: liveliness, telemetry at ``rate_hz``; reports when the console's
    heartbeats came (``time.monotonic``: one clock for every process of the machine)."""
    import zenoh

    from drone.bus import keys
    from drone.bus.config import client_config
    from drone.bus.payloads import Telemetry, encode
    from drone.bus.session import open_session

    session = open_session(client_config(connect=connect, user=f"vehicle-{name}", password=key))
    token = session.liveliness().declare_token(keys.alive(FLEET, name))
    pub = session.declare_publisher(
        keys.telemetry(FLEET, name), congestion_control=zenoh.CongestionControl.DROP
    )
    beats: list[float] = []
    sub = session.declare_subscriber(
        keys.all_console_heartbeats(FLEET), lambda _s: beats.append(time.monotonic())
    )
    period = 1.0 / rate_hz
    while not stop.is_set():
        pub.put(encode(Telemetry(drone=name, stamp=time.time(), **POSE)))
        time.sleep(period)
    out.put((name, beats))
    sub.undeclare()
    token.undeclare()
    session.close()


def run(vehicles: int, restarts: int, rate_hz: float) -> dict[str, Any]:
    from drone.bus import keys
    from drone.bus.commander import BusCommander
    from drone.bus.console import ConsoleBus
    from drone.bus.session import free_listen_endpoint

    names = [f"uav{i + 1}" for i in range(vehicles)]
    passwords = {n: f"uavk_{n}_" + "k" * 40 for n in names}
    spare = {"spare": "uavk_spare_" + "s" * 40}
    tmp = Path(tempfile.mkdtemp(prefix="bus-rekey-"))
    endpoint = free_listen_endpoint("tcp/127.0.0.1:17447")
    ctx = mp.get_context("spawn")
    stop = ctx.Event()
    out = ctx.Queue()
    # spawned (a fresh interpreter each), never forked: Zenoh is open in this process
    procs = [
        ctx.Process(
            target=vehicle_worker,
            args=([endpoint], n, passwords[n], rate_hz, stop, out),
            daemon=True,
        )
        for n in names
    ]
    bus = ConsoleBus(
        tmp / "bus", FLEET, [], name="bench", listen=[endpoint], vehicle_passwords=passwords
    )
    bus.start()
    assert bus.session is not None
    commander = BusCommander(bus.session, FLEET, "bench")
    alive_at: dict[str, list[tuple[float, bool]]] = {n: [] for n in names}
    tel_at: dict[str, list[float]] = {n: [] for n in names}
    lock = threading.Lock()

    def on_alive(sample: Any) -> None:
        import zenoh

        drone = keys.drone_of(str(sample.key_expr))
        if drone in alive_at:
            with lock:
                alive_at[drone].append((time.monotonic(), sample.kind == zenoh.SampleKind.PUT))

    def on_tel(sample: Any) -> None:
        drone = keys.drone_of(str(sample.key_expr))
        if drone in tel_at:
            with lock:
                tel_at[drone].append(time.monotonic())

    lv = bus.session.liveliness().declare_subscriber(keys.all_alive(FLEET), on_alive, history=True)
    ts = bus.session.declare_subscriber(keys.all_telemetry(FLEET), on_tel)
    beating = threading.Event()

    def beat() -> None:
        while not beating.wait(0.1):
            commander.beat(time.time())

    threading.Thread(target=beat, daemon=True).start()
    for p in procs:
        p.start()
    deadline = time.monotonic() + 120
    while set(bus.alive()) != set(names):
        if time.monotonic() > deadline:
            raise SystemExit(f"the vehicles did not join: {bus.alive()}")
        time.sleep(0.05)
    time.sleep(1.0)
    rows: list[dict[str, float]] = []
    base: list[float] = []  # the baseline windows' starts
    for r in range(restarts):
        base.append(time.monotonic())
        time.sleep(2.0)
        now_keys = passwords | (spare if r % 2 == 0 else {})
        t0 = time.monotonic()
        done = bus.rekey(now_keys)
        assert done is not None
        end = time.monotonic() + 10
        while time.monotonic() < end:
            with lock:
                back = [next((t for t, up in alive_at[n] if t > t0 and up), None) for n in names]
            if all(b is not None for b in back):
                break
            time.sleep(0.005)
        time.sleep(max(0.0, t0 + 2.0 - time.monotonic()))  # telemetry after it, for the gap
        cut = max((b - t0) for b in back if b is not None) if all(back) else float("inf")
        rows.append({"t0": t0, "rekey": done.down_s, "cut": cut})
    beating.set()
    stop.set()
    heart = dict(out.get(timeout=30) for _ in procs)

    def window_gap(times: list[float], start: float) -> float:
        """The longest silence in [start, start + 2 s)."""
        inside = [start, *(t for t in times if start < t < start + 2.0), start + 2.0]
        return max(b - a for a, b in itertools.pairwise(inside))

    with lock:
        for row, b0 in zip(rows, base, strict=True):
            row["gap"] = max(window_gap(tel_at[n], row["t0"]) for n in names)
            row["base_gap"] = max(window_gap(tel_at[n], b0) for n in names)
            row["beat"] = max(window_gap(heart[n], row["t0"]) for n in names)
            row["base_beat"] = max(window_gap(heart[n], b0) for n in names)
    for r, row in enumerate(rows):
        print(
            f"restart {r + 1}: rekey {row['rekey'] * 1000:.0f} ms, cut off "
            f"{row['cut'] * 1000:.0f} ms, telemetry gap {row['gap'] * 1000:.0f} ms "
            f"(baseline {row['base_gap'] * 1000:.0f}), heartbeat gap {row['beat'] * 1000:.0f} "
            f"ms (baseline {row['base_beat'] * 1000:.0f})",
            flush=True,
        )
    for p in procs:
        p.join(10)
    lv.undeclare()
    ts.undeclare()
    commander.close()
    bus.close()

    def med(key: str) -> float:
        return statistics.median(row[key] for row in rows) * 1000

    def worst(key: str) -> float:
        return max(row[key] for row in rows) * 1000

    result = {
        "vehicles": vehicles,
        "restarts": restarts,
        "rekey_ms": (med("rekey"), worst("rekey")),
        "cut_off_ms": (med("cut"), worst("cut")),
        "telemetry_gap_ms": (med("gap"), worst("gap")),
        "telemetry_gap_baseline_ms": (med("base_gap"), worst("base_gap")),
        "heartbeat_gap_ms": (med("beat"), worst("beat")),
        "heartbeat_gap_baseline_ms": (med("base_beat"), worst("base_beat")),
        "telemetry_period_ms": 1000 / rate_hz,
    }
    return result


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--vehicles", type=int, default=5)
    ap.add_argument("--restarts", type=int, default=7)
    ap.add_argument("--rate-hz", type=float, default=50.0)
    args = ap.parse_args()
    res = run(args.vehicles, args.restarts, args.rate_hz)
    load = os.getloadavg()[0]

    def line(what: str, key: str) -> str:
        med, worst = res[key]
        return f"| {what} | {med:.0f} ms | {worst:.0f} ms |"

    print(
        f"\nload {load:.1f} on {os.cpu_count()} cores; {res['vehicles']} vehicles, "
        f"{res['restarts']} router restarts, telemetry every {res['telemetry_period_ms']:.0f} ms\n"
        "| | median | worst |\n|---|---|---|\n"
        + "\n".join(
            [
                line("rekey call (close → console back on the router)", "rekey_ms"),
                line("cut off (close → the last vehicle back)", "cut_off_ms"),
                line("telemetry gap at the console, a restart's 2 s", "telemetry_gap_ms"),
                line("telemetry gap, 2 s without a restart", "telemetry_gap_baseline_ms"),
                line("heartbeat gap at a vehicle, a restart's 2 s", "heartbeat_gap_ms"),
                line("heartbeat gap, 2 s without a restart", "heartbeat_gap_baseline_ms"),
            ]
        )
    )


if __name__ == "__main__":
    main()
