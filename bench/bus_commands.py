"""Commands on the bus: round trip, and a stop against a queue of motion commands.

A console's embedded router with its access control (``drone.bus.console.ConsoleBus``) and its
commander (``drone.bus.commander.BusCommander``) in this process; one vehicle in another
(spawned: no fork after Zenoh opens) answering its ``cmd`` queryable
(``drone.bus.commanded.CommandedVehicle``) with a handler that takes ``--work-ms`` per motion
command (a stand-in for the vehicle's checks) and none for a stop. Figures:

- round trip of a command (query → the vehicle's reply), one at a time: a motion command
  (queued path) and a stop (hover: the stop path), p50 / p99;
- a stop sent behind ``--queue`` motion commands sent at once: when its reply comes, against
  when the queue's last reply comes (the stop runs first and the queue behind it is answered
  "superseded").

Usage: ``python bench/bus_commands.py [--quick] [--n 300] [--queue 50] [--work-ms 20]``.
"""

from __future__ import annotations

import argparse
import asyncio
import multiprocessing as mp
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

FLEET = "bench"
NAME = "uav1"


def vehicle_worker(cred: tuple[list[str], str, str], work_ms: float, stop: Any) -> None:
    """One vehicle answering its commands until ``stop`` is set."""
    import logging

    from drone.bus.commanded import CommandedVehicle
    from drone.bus.commands import Command
    from drone.bus.config import client_config
    from drone.bus.lease import VehicleLease
    from drone.bus.session import open_session

    logging.getLogger("drone.bus.commanded").setLevel(logging.ERROR)  # refusals are expected

    async def handle(command: Command) -> dict[str, Any]:
        if not command.is_stop:
            await asyncio.sleep(work_ms / 1000)
        return {"detail": f"{command.action or command.op} done"}

    async def main() -> None:
        connect, user, password = cred
        session = open_session(client_config(connect=connect, user=user, password=password))
        lease = VehicleLease()
        cv = CommandedVehicle(session, FLEET, NAME, handle, lease, asyncio.get_running_loop())
        cv.start()
        while not stop.is_set():
            await asyncio.sleep(0.05)
        cv.close()
        session.close()  # type: ignore[no-untyped-call]

    asyncio.run(main())


def pct(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


async def measure(n: int, queue: int) -> dict[str, Any]:
    from drone.bus.commander import BusCommander
    from drone.bus.console import ConsoleBus
    from drone.bus.errors import NoReply
    from drone.bus.session import free_listen_endpoint

    out: dict[str, Any] = {}
    with tempfile.TemporaryDirectory() as tmp:
        bus = ConsoleBus(
            Path(tmp) / "bus",
            FLEET,
            [NAME],
            name="bench",
            listen=[free_listen_endpoint("tcp/127.0.0.1:17547")],
        )
        bus.start()
        assert bus.session is not None
        cred = bus.vehicle_credential(NAME)
        ctx = mp.get_context("spawn")
        stop = ctx.Event()
        work_ms = ARGS.work_ms
        proc = ctx.Process(
            target=vehicle_worker,
            args=((list(cred.connect), cred.user, cred.password), work_ms, stop),
        )
        proc.start()
        c = BusCommander(bus.session, FLEET, "bench")
        try:
            for _ in range(400):
                try:
                    await c.command(NAME, c.new_command(NAME, "lease"), 1.0)
                    break
                except NoReply:
                    await asyncio.sleep(0.05)
            for op, args, key in (
                ("direct", {"action": "takeoff"}, "motion"),
                ("direct", {"action": "hover"}, "stop"),
            ):
                rtt = []
                for _ in range(n):
                    t0 = time.perf_counter()
                    cmd = c.new_command(NAME, op, args, issued=time.time())
                    reply = await c.command(NAME, cmd)
                    rtt.append(
                        (time.perf_counter() - t0) * 1000 - (0 if key == "stop" else work_ms)
                    )
                    assert reply.accepted, reply.reason
                out[key] = (statistics.median(rtt), pct(rtt, 0.99))
            t0 = time.perf_counter()
            motions = [
                asyncio.ensure_future(
                    c.command(
                        NAME,
                        c.new_command(NAME, "direct", {"action": "takeoff"}, issued=time.time()),
                    )
                )
                for _ in range(queue)
            ]
            await asyncio.sleep(0.005)  # the queue is on its way first
            cmd = c.new_command(NAME, "direct", {"action": "land"}, issued=time.time())
            land = await c.command(NAME, cmd)
            t_land = (time.perf_counter() - t0) * 1000
            replies = await asyncio.gather(*motions)
            t_queue = (time.perf_counter() - t0) * 1000
            out["land_ms"], out["queue_ms"] = t_land, t_queue
            out["land_ok"] = land.accepted
            out["superseded"] = sum(1 for r in replies if r.reason.startswith("superseded"))
            out["ran_before"] = sum(1 for r in replies if r.accepted)
        finally:
            c.close()
            stop.set()
            proc.join(10)
            bus.close()
    return out


def main() -> int:
    if ARGS.quick:
        ARGS.n = min(ARGS.n, 100)
    r = asyncio.run(measure(ARGS.n, ARGS.queue))
    print(
        f"commands on the bus, one vehicle process, {ARGS.n} each (handler {ARGS.work_ms} ms "
        "per motion command, subtracted)"
    )
    print("| command | round trip p50 (ms) | p99 (ms) |")
    print("|---|---|---|")
    for key in ("motion", "stop"):
        p50, p99 = r[key]
        print(f"| {key} | {p50:.2f} | {p99:.2f} |")
    print()
    print(f"a land sent behind {ARGS.queue} motion commands:")
    print("| land answered (ms) | queue answered (ms) | ratio | ran before the land | superseded |")
    print("|---|---|---|---|---|")
    print(
        f"| {r['land_ms']:.1f} | {r['queue_ms']:.1f} | {r['land_ms'] / r['queue_ms']:.2f} "
        f"| {r['ran_before']} | {r['superseded']} |"
    )
    return 0


parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--n", type=int, default=300)
parser.add_argument("--queue", type=int, default=50)
parser.add_argument("--work-ms", type=float, default=20.0)
parser.add_argument("--quick", action="store_true", help="100 of each (make bench --quick)")
ARGS = parser.parse_args() if __name__ == "__main__" else parser.parse_args([])

if __name__ == "__main__":
    sys.exit(main())
