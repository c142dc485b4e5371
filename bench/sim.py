"""Simulator and AR.Drone codec benchmarks; prints a table of medians and ratios.

Rows:
  lockstep RTF (no camera)   simulated seconds per wall second: DriverProtocol ↔ InMemoryLink ↔
                             SimDrone at 100 Hz with navdata at 15 Hz; baseline: physics alone
                             (SimDrone.step without the wire) in the same run. Target ≥ 100×.
  lockstep RTF (camera)      the same plus a 640×360 render every 1/15 s. Target ≥ 10×.
  camera                     ms per rendered frame (drone.sim.camera) over a moving pose;
                             budget 5 ms.
  navdata decode / encode    µs per demo packet; baseline: pyardrone's ctypes parser.
  AT encode / parse          µs per AT*PCMD; baseline: pyardrone's ATCommand._pack.
  H.264 encode+decode        ms per 640×360 frame (drone.ardrone.video); budget 66.7 ms (15 fps).

``--before REV`` adds the camera table: the same camera rows, a ``LockstepRig`` flight with the
vehicle's perception (render + ArUco + PnP + EKF: a camera test's workload) and 10 s of that
drone standing on its station, run for this tree and for git revision REV's tree (``git
archive``) alternately in subprocesses, ``--repeats`` times each; medians, and after/before
ratios from the same run. CPU rows are the steadier ones on a loaded machine.

Usage: ``python bench/sim.py [--repeats N] [--seconds S] [--before REV] [--camera-only]``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

# ``--before``: the tree under test comes first on the path (a subprocess per tree)
sys.path.insert(0, os.environ.get("UAVC_BENCH_TREE") or str(Path(__file__).resolve().parents[1]))

from drone.ardrone import at
from drone.ardrone.navdata import (
    CtrlState,
    Demo,
    DroneState,
    Navdata,
    decode_navdata,
    encode_navdata,
)
from drone.ardrone.protocol import DriverProtocol
from drone.sim.drone import SimDrone
from drone.sim.link import InMemoryLink

ROOT = Path(__file__).resolve().parents[1]
DT = 0.01
CAMERA_PERIOD_S = 1.0 / 15.0


def _world() -> object | None:
    try:
        from drone.sim.world import load_world

        return load_world("indoor")
    except Exception as exc:  # the world module is another engineer's; report, do not crash
        print(f"(no indoor world: {exc}; camera rows skipped)", file=sys.stderr)
        return None


def _flight(link: InMemoryLink, proto: DriverProtocol, seconds: float, camera: bool) -> float:
    """Scripted flight; returns simulated seconds per wall second."""
    sim = link.sim
    script = [(0.0, "takeoff"), (5.0, "fwd"), (8.0, "yaw"), (11.0, "hover"), (13.0, "back")]
    next_frame = 0.0
    t0 = time.perf_counter()
    start = sim.time
    i = 0
    while sim.time - start < seconds:
        rel = (sim.time - start) % 20.0
        while i < len(script) and rel >= script[i][0]:
            cmd = script[i][1]
            if cmd == "takeoff":
                proto.takeoff()
            elif cmd == "fwd":
                proto.move(0.0, -0.4, 0.0, 0.0)
            elif cmd == "yaw":
                proto.move(0.1, 0.0, 0.1, 0.5)
            elif cmd == "hover":
                proto.hover()
            else:
                proto.move(0.0, 0.4, -0.1, 0.0)
            i += 1
        if rel < DT:
            i = 0
        link.step(sim.time, DT)
        if camera and sim.time >= next_frame:
            sim.render_frame()
            next_frame += CAMERA_PERIOD_S
    return (sim.time - start) / (time.perf_counter() - t0)


def rtf(seconds: float, camera: bool, world: object | None) -> float:
    sim = SimDrone(world, seed=1)
    proto = DriverProtocol()
    link = InMemoryLink(proto, sim)
    link.start()
    link.run(1.0)
    return _flight(link, proto, seconds, camera)


def physics_only_rtf(seconds: float) -> float:
    sim = SimDrone(seed=1)
    sim.physics.takeoff()
    n = round(seconds / DT)
    t0 = time.perf_counter()
    for _ in range(n):
        sim.step(DT)
    return seconds / (time.perf_counter() - t0)


def _path_pose(k: int) -> tuple[float, float, float, float, float, float]:
    """Pose ``k`` of a lap of the indoor room at 1-1.6 m, turning: a new view every frame."""
    a = 2.0 * math.pi * k / 120.0
    return (
        4.0 + 2.5 * math.cos(a),
        3.0 + 1.8 * math.sin(a),
        1.3 + 0.3 * math.sin(3 * a),
        0.05 * math.sin(5 * a),
        0.05 * math.cos(4 * a),
        a + 1.2 * math.sin(2 * a),
    )


def render_ms(world: object, frames: int = 120) -> tuple[float, float]:
    """(ms per rendered frame along the lap, CPU ms per frame) with ``SimDrone``'s renderer."""
    from drone.sim.camera import Renderer

    r = Renderer(world, seed=1)  # type: ignore[arg-type]
    r.render(_path_pose(0))  # build the noise patterns
    t0, c0 = time.perf_counter(), time.process_time()
    for k in range(frames):
        r.render(_path_pose(k), frame=k)
    n = frames / 1e3
    return (time.perf_counter() - t0) / n, (time.process_time() - c0) / n


def rig_flight(world: object, seconds: float) -> tuple[float, float]:
    """A ``LockstepRig`` flight with the camera and the vehicle's perception: 2 s landed on the
    station, take off, fly a box with turns, land, 2 s landed; (simulated s per wall s, CPU ms
    per simulated s)."""
    from drone.lockstep import LockstepRig

    rig = LockstepRig(world, seed=1, camera=True)
    rig.wait_link()
    v = rig.vehicle
    # /cmd_vel fractions (x forward, y left, z up, yaw left): forward, turn, left and up, back
    legs = [
        (0.25, 0.0, 0.0, 0.0),
        (0.0, 0.0, 0.0, 0.6),
        (0.0, 0.25, 0.1, 0.0),
        (-0.2, 0.0, -0.1, -0.4),
    ]
    t0, c0, s0 = time.perf_counter(), time.process_time(), rig.clock.now()
    rig.run(2.0)
    v.takeoff()
    rig.run(5.0)
    leg_s = max(1.0, (seconds - 13.0) / len(legs))
    for leg in legs:
        v.jog(*leg)
        rig.run(leg_s)
        v.hover()
    v.land()
    rig.run(4.0)
    rig.run(2.0)
    sim_s = rig.clock.now() - s0
    return sim_s / (time.perf_counter() - t0), (time.process_time() - c0) / sim_s * 1e3


def rig_landed(world: object, seconds: float = 10.0) -> float:
    """CPU ms per simulated second of a ``LockstepRig`` drone standing on its station with the
    camera and perception on (a test's wait before take-off or after landing)."""
    from drone.lockstep import LockstepRig

    rig = LockstepRig(world, seed=1, camera=True)
    rig.wait_link()
    c0 = time.process_time()
    rig.run(seconds)
    return (time.process_time() - c0) / seconds * 1e3


def camera_rows(seconds: float, world: object) -> dict[str, float]:
    """One run of every camera row (``--camera-only`` prints these as JSON)."""
    rtf_cam = rtf(seconds / 4, True, world)
    wall_ms, cpu_ms = render_ms(world)
    rig_rtf, rig_cpu = rig_flight(world, seconds)
    return {
        "rtf_camera": rtf_cam,
        "render_ms": wall_ms,
        "render_cpu_ms": cpu_ms,
        "rig_rtf": rig_rtf,
        "rig_cpu_ms_per_s": rig_cpu,
        "landed_cpu_ms_per_s": rig_landed(world),
    }


def before_table(rev: str, repeats: int, seconds: float) -> None:
    """Camera rows for this tree and for ``rev``'s, alternately in subprocesses; medians, ratios."""
    with tempfile.TemporaryDirectory(prefix="bench-sim-before-") as tmp:
        archive = subprocess.run(
            ["git", "-C", str(ROOT), "archive", rev], capture_output=True, check=True
        )
        subprocess.run(["tar", "-x", "-C", tmp], input=archive.stdout, check=True)
        trees = {"before": tmp, "after": str(ROOT)}
        got: dict[str, list[dict[str, float]]] = {"before": [], "after": []}
        for _ in range(repeats):
            for name, tree in trees.items():
                env = {**os.environ, "UAVC_BENCH_TREE": tree, "PYTHONPATH": tree}
                out = subprocess.run(
                    [sys.executable, __file__, "--camera-only", "--seconds", str(seconds)],
                    env=env,
                    capture_output=True,
                    text=True,
                    check=True,
                )
                got[name].append(json.loads(out.stdout.strip().splitlines()[-1]))
    med = {
        n: {k: statistics.median(d[k] for d in runs) for k in runs[0]} for n, runs in got.items()
    }
    labels = [
        ("rtf_camera", "lockstep RTF, camera 15 fps", "x"),
        ("render_ms", "camera render (moving)", "ms/frame"),
        ("render_cpu_ms", "  CPU", "ms/frame"),
        ("rig_rtf", "LockstepRig + perception RTF", "x"),
        ("rig_cpu_ms_per_s", "  CPU per simulated s", "ms"),
        ("landed_cpu_ms_per_s", "  landed: CPU per simulated s", "ms"),
    ]
    print(
        f"\ncamera rows, medians of {repeats} alternating runs: this tree vs {rev} (load "
        f"{os.getloadavg()[0]:.1f})"
    )
    print(f"{'metric':32} {'after':>10} {'before':>10} {'unit':9} {'after/before':>12}")
    print("-" * 80)
    for key, name, unit in labels:
        a, b = med["after"][key], med["before"][key]
        print(f"{name:32} {a:10.2f} {b:10.2f} {unit:9} {a / b:12.2f}")


def per_call(fn: Callable[[], object], n: int) -> float:
    """Seconds per call of ``fn`` over ``n`` calls."""
    t0 = time.perf_counter()
    for _ in range(n):
        fn()
    return (time.perf_counter() - t0) / n


def median_of(repeats: int, fn: Callable[[], float]) -> float:
    return statistics.median(fn() for _ in range(repeats))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--seconds", type=float, default=60.0, help="simulated seconds per run")
    ap.add_argument("--quick", action="store_true", help="3 runs of 15 simulated seconds")
    ap.add_argument("--before", metavar="REV", help="also time the camera rows at git REV")
    ap.add_argument("--camera-only", action="store_true", help="one run of the camera rows, JSON")
    args = ap.parse_args(argv)
    if args.quick:
        args.repeats, args.seconds = min(args.repeats, 3), min(args.seconds, 15.0)
    r = args.repeats
    world = _world()
    if args.camera_only:
        if world is None:
            return 1
        print(json.dumps(camera_rows(args.seconds, world)))
        return 0
    rows: list[tuple[str, float, str, str, float | None, str]] = []

    base = median_of(r, lambda: physics_only_rtf(args.seconds))
    lock = median_of(r, lambda: rtf(args.seconds, False, world))
    rows.append(("lockstep RTF, no camera", lock, "x", "target 100x", lock / 100.0, "x target"))
    rows.append(("  physics only (baseline)", base, "x", "", lock / base, "lockstep/physics"))
    if world is not None:
        cam = median_of(r, lambda: rtf(args.seconds / 4, True, world))
        rows.append(("lockstep RTF, camera 15 fps", cam, "x", "target 10x", cam / 10.0, "x target"))
        ms = median_of(r, lambda: render_ms(world)[0])
        rows.append(("camera render", ms, "ms/frame", "budget 5 ms", ms / 5.0, "x budget"))

    demo = Demo(CtrlState.FLYING << 16, 80, 1234.5, -321.0, 45000.0, 812, 250.0, -30.0, 12.0, 7)
    packet = encode_navdata(Navdata(DroneState.FLY | DroneState.NAVDATA_DEMO, 42, 0, demo))
    dec = median_of(r, lambda: per_call(lambda: decode_navdata(packet), 20000)) * 1e6
    nav = decode_navdata(packet)
    enc = median_of(r, lambda: per_call(lambda: encode_navdata(nav), 20000)) * 1e6
    try:
        from pyardrone.navdata import NavData

        theirs = median_of(r, lambda: per_call(lambda: NavData(packet), 20000)) * 1e6
        rows.append(
            (
                "navdata decode (demo)",
                dec,
                "us/msg",
                f"pyardrone {theirs:.1f} us",
                dec / theirs,
                "ours/theirs",
            )
        )
    except ImportError:
        rows.append(("navdata decode (demo)", dec, "us/msg", "", None, ""))
    rows.append(("navdata encode (demo)", enc, "us/msg", "", None, ""))

    enc_at = at.ATEncoder()
    pcmd = at.Pcmd(1, -0.25, 0.5, 0.1, -0.75)
    at_us = median_of(r, lambda: per_call(lambda: enc_at.encode(pcmd), 20000)) * 1e6
    wire = at.encode_command(pcmd, 5)
    parse_us = median_of(r, lambda: per_call(lambda: at.parse_at(wire), 20000)) * 1e6
    try:
        from pyardrone import at as pat

        their = pat.PCMD(1, -0.25, 0.5, 0.1, -0.75)
        theirs_at = median_of(r, lambda: per_call(lambda: their._pack(5), 20000)) * 1e6
        rows.append(
            (
                "AT encode (PCMD)",
                at_us,
                "us/msg",
                f"pyardrone {theirs_at:.1f} us",
                at_us / theirs_at,
                "ours/theirs",
            )
        )
    except ImportError:
        rows.append(("AT encode (PCMD)", at_us, "us/msg", "", None, ""))
    rows.append(("AT parse (PCMD)", parse_us, "us/msg", "", None, ""))

    try:
        from drone.ardrone import video

        if world is not None:
            sim = SimDrone(world, seed=1)
            frames = [sim.render_frame() for _ in range(30)]

            def codec() -> float:
                e, d = video.H264Encoder(), video.H264Decoder()
                t0 = time.perf_counter()
                for f in frames:
                    for p in e.encode(f):  # type: ignore[arg-type]
                        d.decode_packet(video.VideoPacket(p.header, p.payload))
                return (time.perf_counter() - t0) / len(frames)

            h264 = median_of(r, codec) * 1e3
            rows.append(
                ("H.264 encode+decode", h264, "ms/frame", "budget 66.7 ms", h264 / 66.7, "x budget")
            )
    except ImportError:
        print("(no drone.ardrone.video: H.264 row skipped)", file=sys.stderr)

    print(f"bench/sim.py — medians of {r} runs, {args.seconds:.0f} s simulated per lockstep run")
    print(f"{'metric':32} {'median':>10} {'unit':9} {'baseline':22} {'ratio':>8}  ")
    print("-" * 100)
    for name, value, unit, baseline, ratio, how in rows:
        rs = f"{ratio:8.2f}  {how}" if ratio is not None else ""
        print(f"{name:32} {value:10.2f} {unit:9} {baseline:22} {rs}")
    if args.before:
        before_table(args.before, r, args.seconds)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
