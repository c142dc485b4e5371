"""The fleet's bus at scale: N light simulated vehicles on Zenoh.

Each light vehicle is the simulator's physics and battery flying a circle (50 Hz physics, no
camera) with its own credential, publishing telemetry at 10 Hz and a status (the LTM's
``LtmStatus``) at 1 Hz under its own name, as a vehicle process does; many run in one process
(``--procs`` worker processes share them out). Each vehicle its own Zenoh session
(``drone.bus.vehicle.VehicleBus``, its bus credential) to the central, a separate process running
the console's embedded router with its access control (``drone.bus.console.ConsoleBus``, which
subscribes to every drone's telemetry); an observer (a Zenoh session with the console's
``client.json5``) stamps each telemetry on arrival. The baseline, the same N over the rosbridge
vehicle link that the bus replaced, needs a checkout that has that link; its figures are in
docs/bus.md ("Scale"). Figures:

- telemetry end to end (vehicle's stamp → the observer, one machine, one clock): p50 / p99;
- the central's CPU (``/proc/<pid>/stat`` of the central process / of ``serve``: CPU seconds per
  wall second, 1.0 is one core) and its work per message (CPU µs per telemetry received);
- telemetry messages per second at the observer (expected N × 10), how many vehicles it heard
  and how many the central knows (alive by liveliness);
- memory per vehicle (RSS of the vehicle processes after joining over before, /N).

Usage: ``python bench/bus.py [--quick] [--n 10 50 200] [--seconds S] [--procs P]``.
On 2 cores the vehicles, the observer and the central contend: read the central's CPU and the
load average beside the latency.
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
from collections.abc import Callable
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

FLEET = "bench"
PHYSICS_HZ = 50
TELEMETRY_HZ = 10
STATUS_HZ = 1
HOST = "127.0.0.1"
WARM_S = 3.0  # after the start: every vehicle joined and publishing before the window opens


def rss_mb(pid: int | None = None) -> float:
    """Resident memory of a process (this one by default), from /proc."""
    with open(f"/proc/{pid or os.getpid()}/statm") as f:
        pages = int(f.read().split()[1])
    return pages * os.sysconf("SC_PAGE_SIZE") / 1e6


def cpu_s(pid: int) -> float:
    """CPU seconds (user + system, all threads) of process ``pid`` so far, from /proc."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


# ---------------------------------------------------------------------- the light vehicle
class LightVehicle:
    """Physics + battery flying a circle; the telemetry and status payloads it publishes."""

    def __init__(self, name: str, index: int) -> None:
        from drone.sim.physics import Physics

        self.name = name
        self.index = index
        self.seq = 0
        self.phys = Physics(bounds=(-60.0, 60.0, -60.0, 60.0, 0.0, 30.0))
        self.phys.body.x, self.phys.body.y = math.cos(index), math.sin(index)
        self.phys.takeoff()

    def step(self, elapsed: float, dt: float) -> None:
        phase = 2 * math.pi * elapsed / 30.0 + self.index
        self.phys.command(0.2 * math.cos(phase), -0.2 * math.sin(phase), 0.0, 0.0, True)
        self.phys.step(dt)

    def telemetry(self) -> bytes:
        """The bus's telemetry payload (schema 1), stamped now."""
        from drone.bus.payloads import Telemetry, encode

        b = self.phys.body
        return encode(
            Telemetry(
                drone=self.name,
                stamp=time.time(),
                x=b.x,
                y=b.y,
                z=b.z,
                yaw_deg=math.degrees(b.yaw_rad),
                battery_pct=self.phys.battery.pct,
                state=self.phys.ctrl.name,
                flying=self.phys.flying,
            )
        )

    def status(self) -> str:
        """An ``LtmStatus`` as the vehicle's LTM reports it (server/fleet/messages.py)."""
        b = self.phys.body
        self.seq += 1
        return json.dumps(
            {
                "name": self.name,
                "t": time.monotonic(),
                "seq": self.seq,
                "x": b.x,
                "y": b.y,
                "z": b.z,
                "yaw_deg": math.degrees(b.yaw_rad),
                "battery_pct": self.phys.battery.pct,
                "flying": self.phys.flying,
                "state": self.phys.ctrl.name,
                "link_ok": True,
                "emergency": False,
                "station": {"x": 0.0, "y": 0.0, "z": 0.0},
            }
        )


def due(tick: int, k: int, hz: int) -> bool:
    """Whether vehicle ``k`` publishes at ``hz`` on this physics tick (staggered over the
    period, as independent processes would be)."""
    return (tick + k) % (PHYSICS_HZ // hz) == 0


# ---------------------------------------------------------------------- bus row
def bus_vehicle_worker(
    names: list[str],
    creds: dict[str, tuple[list[str], str, str]],
    seconds: float,
    ready: Any,
    start: Any,
    out: Any,
) -> None:
    """Fly ``names``, each with its own Zenoh session, publishing telemetry and status."""
    import zenoh

    from drone.bus import keys
    from drone.bus.vehicle import VehicleBus

    base = rss_mb()
    fleet = []
    for name in names:
        connect, user, password = creds[name]
        bus = VehicleBus(connect, user, password, FLEET, name)
        bus.start()
        assert bus.session is not None and bus._publisher is not None
        status = bus.session.declare_publisher(
            f"{keys.ROOT}/{FLEET}/{name}/status", congestion_control=zenoh.CongestionControl.DROP
        )
        fleet.append((LightVehicle(name, int(name[1:])), bus, bus._publisher, status))
    ready.put(("ready", os.getpid(), rss_mb() - base))
    start.wait()
    dt = 1.0 / PHYSICS_HZ
    t0 = time.monotonic()
    tick = sent = 0
    while (now := time.monotonic()) - t0 < seconds:
        for k, (v, _, telemetry, status) in enumerate(fleet):
            v.step(now - t0, dt)
            if due(tick, k, TELEMETRY_HZ):
                telemetry.put(v.telemetry())
                sent += 1
            if due(tick, k, STATUS_HZ):
                status.put(v.status())
        tick += 1
        time.sleep(max(0.0, t0 + tick * dt - time.monotonic()))
    out.put(("done", os.getpid(), sent))
    for _, bus, _, _ in fleet:
        bus.close()


def bus_central_worker(directory: str, names: list[str], ready: Any, ask: Any, stop: Any) -> None:
    """The console's router with its access control (and its telemetry subscriber)."""
    from drone.bus.console import ConsoleBus
    from drone.bus.session import free_listen_endpoint

    bus = ConsoleBus(
        Path(directory),
        FLEET,
        names,
        name="bench",
        listen=[free_listen_endpoint("tcp/127.0.0.1:17447")],
    )
    bus.start()
    creds = {n: bus.vehicle_credential(n) for n in names}
    ready.put(
        (
            "creds",
            {n: (list(c.connect), c.user, c.password) for n, c in creds.items()},
            str(bus.client_file),
        )
    )
    ask.wait()
    ready.put(("alive", len(bus.alive())))
    stop.wait()
    bus.close()


def bus_observer_worker(client_file: str, counting: Any, ready: Any, stop: Any, out: Any) -> None:
    """A third-party Zenoh client (the observer credential) stamping every telemetry."""
    import zenoh

    from drone.bus import keys

    latencies: list[float] = []
    heard: set[str] = set()

    def on_sample(sample: Any) -> None:
        t = time.time()
        if counting.is_set():
            msg = json.loads(sample.payload.to_bytes())
            latencies.append(t - msg["stamp"])
            heard.add(msg["drone"])

    with zenoh.open(zenoh.Config.from_file(client_file)) as session:
        sub = session.declare_subscriber(keys.all_telemetry(FLEET), on_sample)
        ready.put(("observer",))
        stop.wait()
        sub.undeclare()  # type: ignore[no-untyped-call]
    out.put(("observer", latencies, len(heard)))


def run_bus(n: int, seconds: float, procs: int) -> dict[str, Any]:
    ctx = mp.get_context("spawn")  # Zenoh is opened in the children only, after the spawn
    names = [f"v{i:03d}" for i in range(n)]
    ready, out = ctx.Queue(), ctx.Queue()
    start, counting, stop, ask = ctx.Event(), ctx.Event(), ctx.Event(), ctx.Event()
    with tempfile.TemporaryDirectory() as tmp:
        central = ctx.Process(target=bus_central_worker, args=(tmp, names, ready, ask, stop))
        central.start()
        tag, creds, client_file = ready.get(timeout=60)
        assert tag == "creds"
        observer = ctx.Process(
            target=bus_observer_worker, args=(client_file, counting, ready, stop, out)
        )
        observer.start()
        assert ready.get(timeout=60)[0] == "observer"
        workers = [
            ctx.Process(
                target=bus_vehicle_worker,
                args=(names[i::procs], creds, seconds, ready, start, out),
            )
            for i in range(procs)
            if names[i::procs]
        ]
        for w in workers:
            w.start()
        joined_mb = [ready.get(timeout=180)[2] for _ in workers]
        assert central.pid is not None
        assert observer.pid is not None
        r = measure(central.pid, observer.pid, seconds, start, counting)
        ask.set()
        alive = ready.get(timeout=60)[1]  # the central's liveliness view, vehicles still up
        sent = sum(out.get(timeout=120)[2] for _ in workers)
        stop.set()
        _, latencies, heard = out.get(timeout=60)
        for p in [central, observer, *workers]:
            p.join(30)
    return summarize("bus", n, r, latencies, heard, joined_mb, sent, alive, seconds)


def measure(pid: int, observer: int, seconds: float, start: Any, counting: Any) -> dict[str, float]:
    """Start the vehicles; over the window (after the warm-up, before the last second) count at
    the observer and read the central's CPU from /proc."""
    start.set()
    time.sleep(WARM_S)
    cpu0, obs0, wall0, load0 = cpu_s(pid), cpu_s(observer), time.monotonic(), os.getloadavg()[0]
    counting.set()
    time.sleep(max(1.0, seconds - WARM_S - 1.0))
    counting.clear()
    cpu, obs, wall = cpu_s(pid) - cpu0, cpu_s(observer) - obs0, time.monotonic() - wall0
    load = (load0 + os.getloadavg()[0]) / 2
    return {"cpu_s": cpu, "observer_s": obs, "wall_s": wall, "load": load}


def summarize(
    transport: str,
    n: int,
    r: dict[str, float],
    latencies: list[float],
    heard: int,
    joined_mb: list[float],
    sent: int,
    alive: int,
    seconds: float,
) -> dict[str, Any]:
    lat_ms = sorted(x * 1000 for x in latencies)
    p99 = lat_ms[min(len(lat_ms) - 1, int(0.99 * len(lat_ms)))] if lat_ms else math.nan
    return {
        "transport": transport,
        "n": n,
        "p50_ms": statistics.median(lat_ms) if lat_ms else math.nan,
        "p99_ms": p99,
        "central_cores": r["cpu_s"] / r["wall_s"],
        "observer_cores": r["observer_s"] / r["wall_s"],
        "cpu_us_per_msg": 1e6 * r["cpu_s"] / max(1, len(lat_ms)),
        "msgs_per_s": len(lat_ms) / r["wall_s"],
        "expected_per_s": n * TELEMETRY_HZ,
        "mb_per_vehicle": sum(joined_mb) / n,
        "heard": heard,
        "alive": alive,
        "sent_per_s": sent / seconds,
        "load": r["load"],
    }


def row(r: dict[str, Any]) -> str:
    return (
        f"| {r['n']} | {r['transport']} | {r['p50_ms']:.1f} ms | {r['p99_ms']:.1f} ms | "
        f"{r['central_cores']:.2f} | {r['cpu_us_per_msg']:.0f} | "
        f"{r['msgs_per_s']:.0f} ({r['sent_per_s']:.0f}; {r['expected_per_s']}) | "
        f"{r['mb_per_vehicle']:.2f} | "
        f"{r['heard']}/{r['n']} ({r['alive']}) | {r['observer_cores']:.2f} | {r['load']:.1f} |"
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="N = 10 and 50, 10 s each")
    ap.add_argument("--n", type=int, nargs="+", default=None)
    ap.add_argument("--seconds", type=float, default=None)
    ap.add_argument("--procs", type=int, default=4, help="vehicle processes")
    args = ap.parse_args(argv)
    ns = args.n or ([10, 50] if args.quick else [10, 50, 200])
    seconds = args.seconds or (10.0 if args.quick else 20.0)
    print(f"load average at start: {os.getloadavg()[0]:.1f}; {os.cpu_count()} cores", flush=True)
    print(
        "| N | transport | telemetry p50 | p99 | central CPU (cores) | CPU µs/msg "
        "| msgs/s received (sent; expected) | MB per vehicle "
        "| vehicles heard (at the central) | observer CPU | load avg |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|", flush=True)
    rows: list[dict[str, Any]] = []
    runs: list[tuple[str, Callable[[int, float, int], dict[str, Any]]]] = [("bus", run_bus)]
    for n in ns:
        got = {}
        for transport, run in runs:
            try:
                got[transport] = r = run(n, seconds, min(args.procs, n))
            except Exception as exc:  # one transport failing must not lose the other's row
                print(f"| {n} | {transport} | failed: {exc!r} |", flush=True)
                continue
            rows.append(r)
            print(row(r), flush=True)
    for transport, _ in runs:
        mine = [r for r in rows if r["transport"] == transport]
        if len(mine) > 1:
            first, last = mine[0], mine[-1]
            growth = last["central_cores"] / max(first["central_cores"], 1e-9)
            print(
                f"\n{transport}: central CPU grows {growth:.1f}x from N={first['n']} to "
                f"N={last['n']} ({last['n'] / first['n']:.0f}x the vehicles); p99 "
                f"{first['p99_ms']:.1f} → {last['p99_ms']:.1f} ms",
                end="",
            )
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3
    print(f"\npeak RSS of this process {peak_mb:.0f} MB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
