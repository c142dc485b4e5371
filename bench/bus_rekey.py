"""How long the vehicles on a console's bus are cut off when the console restarts its router for
new vehicle keys (``drone.bus.console.ConsoleBus.rekey``: a key made or revoked while ``serve``
runs).

A console's embedded router and its own session (``ConsoleBus``) in this process, as ``serve``
has them, with its 10 Hz heartbeat; ``--vehicles`` light vehicles in processes of their own
(spawned: no fork after Zenoh opens), each a Zenoh client as ``uav-console vehicle`` is one
(``drone.bus.config.client_config``, its own key), with its liveliness token and telemetry at
``--rate-hz``. The router is restarted ``--restarts`` times, a spare vehicle key added and
removed in turn. Figures, medians over the restarts (and the worst):

- ``rekey``: the call, from the old router's close to the console's session on the new one;
- ``cut off``: from the close to the last vehicle's liveliness back at the console;
- ``telemetry gap``: the longest silence of a vehicle's telemetry at the console across it;
- ``heartbeat gap``: the longest silence of the console's heartbeat at a vehicle (a vehicle
  hovers after 1 s of it: ``heartbeat_timeout_s``).

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
    """One light vehicle: liveliness, telemetry at ``rate_hz``; reports its heartbeat gaps."""
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
    gaps = [b - a for a, b in itertools.pairwise(beats)]
    out.put((name, max(gaps) if gaps else None))
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
    rows = []
    for r in range(restarts):
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
        time.sleep(1.0)  # telemetry after it, for the gap
        with lock:
            gaps = []
            for n in names:
                arrivals = [t for t in tel_at[n] if t0 - 1.0 < t < t0 + 1.0]
                gaps.append(max((b - a for a, b in itertools.pairwise(arrivals)), default=0))
        cut = max((b - t0) for b in back if b is not None) if all(back) else float("inf")
        rows.append({"rekey": done.down_s, "cut": cut, "gap": max(gaps)})
        print(
            f"restart {r + 1}: rekey {done.down_s * 1000:.0f} ms, cut off {cut * 1000:.0f} ms, "
            f"telemetry gap {max(gaps) * 1000:.0f} ms",
            flush=True,
        )
    beating.set()
    stop.set()
    heart = [out.get(timeout=30) for _ in procs]
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
        "heartbeat_gap_max_ms": max(g for _n, g in heart if g is not None) * 1000,
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
    print(
        f"\nload {load:.1f} on {os.cpu_count()} cores; "
        f"{res['vehicles']} vehicles, {res['restarts']} router restarts (median / worst):\n"
        f"  rekey call     {res['rekey_ms'][0]:6.0f} / {res['rekey_ms'][1]:.0f} ms\n"
        f"  cut off        {res['cut_off_ms'][0]:6.0f} / {res['cut_off_ms'][1]:.0f} ms\n"
        f"  telemetry gap  {res['telemetry_gap_ms'][0]:6.0f} / {res['telemetry_gap_ms'][1]:.0f} ms"
        f" (period {res['telemetry_period_ms']:.0f} ms)\n"
        f"  heartbeat gap at a vehicle, worst over the run: {res['heartbeat_gap_max_ms']:.0f} ms"
        " (a vehicle hovers after 1000)"
    )


if __name__ == "__main__":
    main()
