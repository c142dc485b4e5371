"""The fleet's bus at scale: N light simulated vehicles publishing on Zenoh to a central.

Each light vehicle is the simulator's physics and battery flying a circle (50 Hz physics, no
camera) with its own bus credential and session, publishing telemetry at 10 Hz and a status at
1 Hz under its own name, as a vehicle process does; many run in one process (``--procs`` worker
processes share them out). The central is a separate process: the console's embedded router
(``drone.bus.console.ConsoleBus``, with its access control) plus a subscriber to every drone's
telemetry. Figures, per N:

- telemetry end to end (vehicle's stamp → the central's callback, one machine, one clock):
  p50 / p99;
- the central's CPU (its process's CPU seconds per wall second: 1.0 is one core) and its work
  per message (CPU µs per message received);
- messages per second received by the central;
- memory per vehicle (RSS of the vehicle processes over the same processes with no vehicle, /N).

Baseline in the same run: the same N over today's ``/vehicle-link`` (``--link``, a real
``serve --fleet 0`` with vehicle keys), when given.

Usage: ``python bench/bus.py [--quick] [--n 10 50 200] [--seconds S] [--procs P]``.
On 2 cores the vehicles and the central contend: read the central's CPU and the growth with N
beside the latency.
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing as mp
import os
import resource
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

FLEET = "bench"
PHYSICS_HZ = 50
TELEMETRY_HZ = 10
STATUS_HZ = 1


def rss_mb(pid: int | None = None) -> float:
    """Resident memory of a process (this one by default), from /proc."""
    with open(f"/proc/{pid or os.getpid()}/statm") as f:
        pages = int(f.read().split()[1])
    return pages * os.sysconf("SC_PAGE_SIZE") / 1e6


def vehicle_worker(
    names: list[str],
    creds: dict[str, tuple[list[str], str, str]],
    seconds: float,
    ready: Any,
    start: Any,
    out: Any,
) -> None:
    """Fly ``names`` (physics + battery, a circle each) and publish their telemetry/status."""
    import zenoh

    from drone.bus import keys
    from drone.bus.payloads import Telemetry, encode
    from drone.bus.vehicle import VehicleBus
    from drone.sim.physics import Physics

    base = rss_mb()
    fleet = []
    for i, name in enumerate(names):
        connect, user, password = creds[name]
        bus = VehicleBus(connect, user, password, FLEET, name)
        bus.start()
        assert bus.session is not None
        status = bus.session.declare_publisher(
            f"{keys.ROOT}/{FLEET}/{name}/status", congestion_control=zenoh.CongestionControl.DROP
        )
        phys = Physics(bounds=(-60.0, 60.0, -60.0, 60.0, 0.0, 30.0))
        phys.body.x, phys.body.y = math.cos(i), math.sin(i)
        phys.takeoff()
        fleet.append((name, bus, status, phys))
    ready.put(("ready", os.getpid(), rss_mb() - base))
    start.wait()
    dt = 1.0 / PHYSICS_HZ
    t0 = time.monotonic()
    tick = 0
    sent = 0
    while (now := time.monotonic()) - t0 < seconds:
        for k, (name, bus, status, phys) in enumerate(fleet):
            phase = 2 * math.pi * (now - t0) / 30.0 + k
            phys.command(0.2 * math.cos(phase), -0.2 * math.sin(phase), 0.0, 0.0, True)
            phys.step(dt)
            # stagger the vehicles over the telemetry period, as independent processes would be
            if (tick + k) % (PHYSICS_HZ // TELEMETRY_HZ) == 0:
                b = phys.body
                message = Telemetry(
                    drone=name,
                    stamp=time.time(),
                    x=b.x,
                    y=b.y,
                    z=b.z,
                    yaw_deg=math.degrees(b.yaw_rad),
                    battery_pct=phys.battery.pct,
                    state=phys.ctrl.name,
                    flying=phys.flying,
                )
                assert bus._publisher is not None
                bus._publisher.put(encode(message))
                sent += 1
            if (tick + k) % (PHYSICS_HZ // STATUS_HZ) == 0:
                status.put(json.dumps({"drone": name, "battery_pct": phys.battery.pct}))
        tick += 1
        time.sleep(max(0.0, t0 + tick * dt - time.monotonic()))
    out.put(("done", os.getpid(), sent, rss_mb()))
    for _, bus, _, _ in fleet:
        bus.close()


def central_worker(
    directory: str, names: list[str], seconds: float, ready: Any, start: Any, out: Any
) -> None:
    """The console's router with its ACL, and a subscriber that stamps every telemetry."""
    from drone.bus import keys
    from drone.bus.console import ConsoleBus
    from drone.bus.payloads import decode_telemetry
    from drone.bus.session import free_listen_endpoint

    bus = ConsoleBus(
        Path(directory), FLEET, names, listen=[free_listen_endpoint("tcp/127.0.0.1:17447")]
    )
    bus.start()
    latencies: list[float] = []
    counted = {"on": False, "n": 0}

    def on_sample(sample: Any) -> None:
        t = time.time()
        message = decode_telemetry(sample.payload.to_bytes())
        if counted["on"]:
            latencies.append(t - message.stamp)
            counted["n"] += 1

    assert bus.session is not None
    sub = bus.session.declare_subscriber(keys.all_telemetry(FLEET), on_sample)
    creds = {n: bus.vehicle_credential(n) for n in names}
    ready.put(("creds", {n: (list(c.connect), c.user, c.password) for n, c in creds.items()}))
    start.wait()
    time.sleep(min(2.0, seconds / 4))  # every vehicle joined and publishing
    counted["on"] = True
    cpu0, wall0 = time.process_time(), time.monotonic()
    time.sleep(seconds - min(2.0, seconds / 4) - 1.0)
    cpu, wall = time.process_time() - cpu0, time.monotonic() - wall0
    counted["on"] = False
    out.put(
        (
            "central",
            {
                "latencies": latencies,
                "received": counted["n"],
                "cpu_s": cpu,
                "wall_s": wall,
                "alive": len(bus.alive()),
            },
        )
    )
    sub.undeclare()  # type: ignore[no-untyped-call]
    bus.close()


def run_bus(n: int, seconds: float, procs: int) -> dict[str, float]:
    ctx = mp.get_context("spawn")  # Zenoh is opened in the children only, after the spawn
    names = [f"v{i:03d}" for i in range(n)]
    ready, out = ctx.Queue(), ctx.Queue()
    start = ctx.Event()
    with tempfile.TemporaryDirectory() as tmp:
        central = ctx.Process(target=central_worker, args=(tmp, names, seconds, ready, start, out))
        central.start()
        tag, creds = ready.get(timeout=60)
        assert tag == "creds"
        groups = [names[i::procs] for i in range(procs)]
        workers = [
            ctx.Process(target=vehicle_worker, args=(g, creds, seconds, ready, start, out))
            for g in groups
            if g
        ]
        for w in workers:
            w.start()
        joined_mb = [ready.get(timeout=120)[2] for _ in workers]
        start.set()
        results: dict[str, Any] = {}
        sent = 0
        for _ in range(len(workers) + 1):
            item = out.get(timeout=seconds + 120)
            if item[0] == "central":
                results = item[1]
            else:
                sent += item[2]
        for p in [central, *workers]:
            p.join(30)
    lat_ms = sorted(x * 1000 for x in results["latencies"])
    p99 = lat_ms[min(len(lat_ms) - 1, int(0.99 * len(lat_ms)))] if lat_ms else math.nan
    return {
        "n": n,
        "p50_ms": statistics.median(lat_ms) if lat_ms else math.nan,
        "p99_ms": p99,
        "central_cores": results["cpu_s"] / results["wall_s"],
        "cpu_us_per_msg": 1e6 * results["cpu_s"] / max(1, results["received"]),
        "msgs_per_s": results["received"] / results["wall_s"],
        "expected_per_s": n * TELEMETRY_HZ,
        "mb_per_vehicle": sum(joined_mb) / n,
        "alive": results["alive"],
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="N = 10 and 50, 8 s each")
    ap.add_argument("--n", type=int, nargs="+", default=None)
    ap.add_argument("--seconds", type=float, default=None)
    ap.add_argument("--procs", type=int, default=4, help="vehicle processes")
    args = ap.parse_args(argv)
    ns = args.n or ([10, 50] if args.quick else [10, 50, 200])
    seconds = args.seconds or (8.0 if args.quick else 20.0)
    print(f"load average at start: {os.getloadavg()[0]:.1f}; {os.cpu_count()} cores")
    print(
        "| N | telemetry p50 | p99 | central CPU (cores) | CPU µs/msg | msgs/s (expected) "
        "| MB per vehicle | alive |"
    )
    print("|---|---|---|---|---|---|---|---|")
    rows = []
    for n in ns:
        r = run_bus(n, seconds, min(args.procs, n))
        rows.append(r)
        print(
            f"| {n} | {r['p50_ms']:.1f} ms | {r['p99_ms']:.1f} ms | {r['central_cores']:.2f} | "
            f"{r['cpu_us_per_msg']:.0f} | {r['msgs_per_s']:.0f} ({r['expected_per_s']}) | "
            f"{r['mb_per_vehicle']:.2f} | {r['alive']} |",
            flush=True,
        )
    if len(rows) > 1:
        first, last = rows[0], rows[-1]
        growth = last["central_cores"] / max(first["central_cores"], 1e-9)
        peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3
        print(
            f"\ncentral CPU grows {growth:.1f}x from N={first['n']} to N={last['n']} "
            f"({last['n'] / first['n']:.0f}x the vehicles); p99 ratio "
            f"{last['p99_ms'] / max(first['p99_ms'], 1e-9):.2f}; "
            f"peak RSS of this process {peak_mb:.0f} MB"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
