"""MAVLink benchmarks; prints tables of medians and ratios.

Table 1, command round trip: ``COMMAND_LONG`` (MAV_CMD_DO_CHANGE_SPEED, which the simulated
autopilot only acknowledges) → ``COMMAND_ACK`` over TCP loopback to the MAVLink simulator in a
separate process, p50/p99: through the console's driver (``MavlinkDriver`` + ``GcsProtocol``:
queue, retry bookkeeping, event dispatch) vs a bare pymavlink loop (``mavutil`` send, blocking
``recv_match``) on a second connection to the same simulator (``--insecure``: unsigned), and
the driver again on a signed simulator (the default), measured in the same run.

Table 2, telemetry ingest per drone: one minute of the simulated autopilot's telemetry at the
rates the driver requests (≈ 45 messages/s) decoded by ``GcsProtocol.receive`` with a
``MavlinkVehicle`` snapshot per batch: messages per CPU second, and the CPU share one drone's
stream costs; baseline: pymavlink's bare ``parse_buffer`` on the same bytes.

Table 3, lockstep patrol real-time factor: the persistent patrol (2 drones, the same route,
battery and tick) with simulated PX4 quadrotors over MAVLink in memory vs AR.Drones over their
wire protocol with the console's EKF and PID, simulated seconds per wall second and per CPU
second.

Usage: ``python bench/mavlink.py [--quick]``. The figures are from a shared machine (other jobs
running); the ratios are the stable part.
"""

from __future__ import annotations

import argparse
import asyncio
import math
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from drone.mavlink.codec import Codec, mav
from drone.mavlink.driver import MavlinkDriver
from drone.mavlink.gcs.events import CommandResult
from drone.mavlink.gcs.heartbeat import STREAMS_HZ
from drone.mavlink.gcs.protocol import GcsProtocol
from drone.mavlink.sim.autopilot import SimAutopilot
from drone.mavlink.vehicle import MavlinkVehicle
from drone.sim.world import load_world
from experiments.patrol import PatrolConfig, PatrolExperiment

ROOT = Path(__file__).resolve().parents[1]
ADDR = "127.0.16.40"


def _pct(values: list[float], q: float) -> float:
    s = sorted(values)
    return s[min(len(s) - 1, max(0, math.ceil(q * len(s)) - 1))]


async def _driver_rtt(n: int, key: bytes | None = None) -> list[float]:
    results: dict[int, float] = {}
    sent: dict[int, float] = {}
    acked = asyncio.Event()

    def on_event(ev: object) -> None:
        if isinstance(ev, CommandResult) and ev.token in sent:
            results[ev.token] = time.perf_counter() - sent[ev.token]
            acked.set()

    d = MavlinkDriver(f"tcp:{ADDR}:5760", GcsProtocol(signing_key=key), on_event=on_event)
    await d.start()
    try:
        while d.protocol.pending_commands() or not d.protocol.connected:
            await asyncio.sleep(0.05)
        for _ in range(n):
            acked.clear()
            t0 = time.perf_counter()
            tok = d.protocol.command(mav.MAV_CMD_DO_CHANGE_SPEED, 1.0, 5.0, -1.0)
            sent[tok] = t0
            d.flush()
            await acked.wait()  # no busy wait: the simulator shares the CPUs
    finally:
        await d.stop()
    return list(results.values())


def _bare_rtt(n: int) -> list[float]:
    from pymavlink import mavutil

    m = mavutil.mavlink_connection(f"tcp:{ADDR}:5760", source_system=250)
    m.wait_heartbeat(timeout=10)
    out = []
    for _ in range(n):
        t0 = time.perf_counter()
        m.mav.command_long_send(1, 1, mav.MAV_CMD_DO_CHANGE_SPEED, 0, 1, 5, -1, 0, 0, 0, 0)
        m.recv_match(type="COMMAND_ACK", blocking=True, timeout=5)
        out.append(time.perf_counter() - t0)
    m.close()
    return out


def _sim(*flags: str) -> subprocess.Popen[bytes]:
    return subprocess.Popen(
        [sys.executable, "-m", "server", "sim", "--protocol", "mavlink", "--addr", ADDR, *flags],
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )


def table_rtt(n: int) -> None:
    from drone.mavlink import signing

    proc = _sim("--insecure")  # unsigned (loopback only): the bare pymavlink loop's baseline
    try:
        time.sleep(3.0)
        driver = asyncio.run(_driver_rtt(n))
        bare = _bare_rtt(n)
    finally:
        proc.terminate()
        proc.wait(timeout=10)
    with tempfile.TemporaryDirectory() as data_dir:  # signed, as the simulator runs by default
        key, _ = signing.load_or_create(Path(data_dir))
        proc = _sim("--data-dir", data_dir)
        try:
            time.sleep(3.0)
            signed = asyncio.run(_driver_rtt(n, key))
        finally:
            proc.terminate()
            proc.wait(timeout=10)
    print(f"\nCommand round trip COMMAND_LONG → COMMAND_ACK, TCP loopback, {n} commands (ms)")
    print(f"{'path':<34}{'p50':>8}{'p99':>8}")
    rows = (
        ("console driver (MavlinkDriver)", driver),
        ("bare pymavlink mavutil", bare),
        ("console driver, signed link", signed),
    )
    for name, v in rows:
        print(f"{name:<34}{1e3 * _pct(v, 0.5):>8.2f}{1e3 * _pct(v, 0.99):>8.2f}")
    print(f"ratio driver / bare (p50)         {_pct(driver, 0.5) / _pct(bare, 0.5):>8.2f}")
    print(f"ratio signed / unsigned (p50)     {_pct(signed, 0.5) / _pct(driver, 0.5):>8.2f}")


def _telemetry_bytes(seconds: float) -> tuple[bytes, int]:
    ap = SimAutopilot(load_world("outdoor"))
    ap.connect("bench")
    link = ap.links["bench"]
    for msg_id, hz in STREAMS_HZ.items():
        name = mav.mavlink_map[msg_id].msgname
        if name in link.rates_hz:
            link.rates_hz[name] = hz
    chunks = []
    for _ in range(round(seconds / 0.02)):
        ap.step(0.02)
        chunks.append(ap.drain("bench"))
    data = b"".join(chunks)
    count = len(Codec(255, 190).feed(data))
    return data, count


def table_ingest(seconds: float, repeats: int) -> None:
    data, count = _telemetry_bytes(seconds)
    chunks = [data[i : i + 512] for i in range(0, len(data), 512)]
    ours, bare = [], []
    for _ in range(repeats):
        p = GcsProtocol(request_streams=False)
        v = MavlinkVehicle("uav1", load_world("outdoor"), p)
        t0 = time.process_time()
        for i, c in enumerate(chunks):
            p.receive(c, i * 0.01)
            for ev in p.events():
                v.on_event(ev)
            v.snapshot()
        ours.append(time.process_time() - t0)
        c0 = Codec(255, 190)
        t0 = time.process_time()
        for c in chunks:
            c0.feed(c)
        bare.append(time.process_time() - t0)
    rate = count / seconds
    print(f"\nTelemetry ingest, one drone: {count} messages = {seconds:.0f} s at {rate:.0f} msg/s")
    print(f"{'path':<40}{'msgs/CPU s':>12}{'CPU per drone':>15}")
    for name, v in (
        ("GcsProtocol + MavlinkVehicle snapshot", ours),
        ("bare pymavlink parse_buffer", bare),
    ):
        med = statistics.median(v)
        print(f"{name:<40}{count / med:>12.0f}{100 * med / seconds:>14.2f}%")
    ratio = statistics.median(ours) / statistics.median(bare)
    print(f"ratio console / bare (CPU)              {ratio:>12.2f}")


def table_patrol(seconds: float) -> None:
    print(f"\nLockstep patrol, 2 drones, {seconds:.0f} simulated s, dt 0.1 s")
    print(f"{'drones':<44}{'× real time':>12}{'× per CPU s':>13}{'coverage':>10}")
    rows = {}
    for proto, label in (
        ("mavlink", "PX4 over MAVLink (autopilot flies)"),
        ("ardrone", "AR.Drone (console EKF + PID)"),
    ):
        cfg = PatrolConfig(
            drones=2, duration_s=seconds, flight_time_s=150.0, swap_s=20.0, protocol=proto
        )
        rep = PatrolExperiment(cfg).run()
        rows[proto] = rep
        print(
            f"{label:<44}{rep.realtime_factor:>12.1f}{rep.realtime_factor_cpu:>13.1f}"
            f"{100 * rep.coverage:>9.1f}%"
        )
    ratio = rows["mavlink"].realtime_factor_cpu / rows["ardrone"].realtime_factor_cpu
    print(f"ratio MAVLink / AR.Drone (per CPU s)        {ratio:>12.2f}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true")
    a = ap.parse_args()
    table_rtt(100 if a.quick else 500)
    table_ingest(20.0 if a.quick else 60.0, 3 if a.quick else 5)
    table_patrol(120.0 if a.quick else 300.0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
