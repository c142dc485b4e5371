"""Flight autonomy benchmark: 100 Hz loop jitter, perception cost, closed-loop accuracy.

1. Control loop at 100 Hz (absolute deadlines) for ``--seconds`` (60; ``--quick`` 5 s), idle and
   under load (an asyncio loop in the main thread serving telemetry at 50 Hz and 640×360 JPEG
   video at 15 fps to 10 WebSocket clients over loopback): plain ``sleep`` to the deadline (the
   baseline) vs sleep-then-spin (2 ms), and spin with ``sys.setswitchinterval(0.0005)``.
   Period error = |period − 10 ms|; overruns = missed deadlines. Target: p99 ≤ 0.2 ms, 0 overruns.
2. Perception per 640×360 frame: ArUco detection alone (baseline) vs detect + IPPE PnP + EKF
   update, on rendered frames of the default room. Target ≤ 2 ms/frame.
3. Closed loop in lockstep: go to every marker of the default room (camera + EKF) vs the same
   flights dead-reckoning from navdata alone (no camera, the baseline); true final error and
   time to arrive. Target median error < 0.1 m.

    .venv/bin/python bench/autonomy.py [--quick] [--seconds 60] [--skip-load]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import statistics
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from drone.camera import CameraModel  # noqa: E402
from drone.control.loop import ControlLoop, LoopStats  # noqa: E402
from drone.control.pid import PaperPID, Setpoint  # noqa: E402
from drone.perception.ekf import ExtendedKalmanFilter, NavdataInput  # noqa: E402
from drone.perception.markers import MarkerLocaliser  # noqa: E402
from drone.sim.camera import Renderer  # noqa: E402
from drone.sim.world import load_world  # noqa: E402


# ---------------------------------------------------------------------------------------------
# 1. control loop
class _State:
    x = y = 0.0
    z = 1.0
    yaw_rad = vx = vy = vz = 0.0


def _run_loop(
    seconds: float, spin_s: float, switch: float | None, yield_spin: bool = True
) -> LoopStats:
    pid, sp, st = PaperPID(), Setpoint(1.0, 0.5, 1.2, 0.3), _State()
    old = sys.getswitchinterval()
    if switch is not None:
        sys.setswitchinterval(switch)
    loop = ControlLoop(
        lambda now, dt: pid.step(st, sp, 0.01),
        period_s=0.01,
        spin_s=spin_s,
        yield_while_spinning=yield_spin,
    )
    loop.start()
    done = threading.Event()
    done.wait(seconds)
    loop.stop()
    sys.setswitchinterval(old)
    return loop.stats()


async def _load(stop: asyncio.Event, clients: int = 10) -> dict[str, int]:
    """Telemetry (50 Hz JSON) and JPEG video (15 fps) to ``clients`` WebSocket clients."""
    import cv2
    import websockets

    world = load_world("indoor")
    frame = Renderer(world, seed=0).render((4.0, 3.0, 1.2, 0.0, 0.0, 0.5))
    counts = {"sent": 0, "received": 0}
    conns: set = set()

    async def handler(ws) -> None:  # type: ignore[no-untyped-def]
        conns.add(ws)
        try:
            await ws.wait_closed()
        finally:
            conns.discard(ws)

    async def producer() -> None:
        k = 0
        while not stop.is_set():
            tel = json.dumps(
                {
                    "op": "publish",
                    "topic": "/ardrone/navdata",
                    "msg": {"altd": 1000 + k, "rotZ": k * 0.1, "vx": 1.0, "k": k},
                }
            )
            payloads = [tel]
            if k % 3 == 0:  # 50 Hz / 3 ≈ 16.7 fps of video
                _, buf = await asyncio.to_thread(cv2.imencode, ".jpg", frame)
                payloads.append(buf.tobytes())
            for ws in list(conns):
                for p in payloads:
                    await ws.send(p)
                    counts["sent"] += 1
            k += 1
            await asyncio.sleep(0.02)

    async def consumer() -> None:
        async with websockets.connect("ws://127.0.0.71:8766", max_size=None) as ws:
            async for _ in ws:
                counts["received"] += 1

    async with websockets.serve(handler, "127.0.0.71", 8766, max_size=None):
        cons = [asyncio.create_task(consumer()) for _ in range(clients)]
        prod = asyncio.create_task(producer())
        await stop.wait()
        prod.cancel()
        for c in cons:
            c.cancel()
        await asyncio.gather(prod, *cons, return_exceptions=True)
    return counts


def _under_load(fn: Callable[[], LoopStats]) -> tuple[LoopStats, dict[str, int]]:
    async def main() -> tuple[LoopStats, dict[str, int]]:
        stop = asyncio.Event()
        load = asyncio.create_task(_load(stop))
        await asyncio.sleep(0.5)
        stats = await asyncio.to_thread(fn)
        stop.set()
        return stats, await load

    return asyncio.run(main())


def bench_loop(seconds: float, load: bool) -> None:
    variants = [
        ("sleep (baseline)", 0.0, None, True),
        ("sleep+spin 2 ms (yielding)", 0.002, None, True),
        ("sleep+busy-spin 1 ms", 0.001, None, False),
        ("spin + switch 0.5 ms", 0.002, 0.0005, True),
    ]
    print(f"\n## Control loop, 100 Hz, {seconds:g} s per row")
    print(
        "| variant | load | rate Hz | period err p50 µs | p99 µs | max µs | overruns | p99 ratio |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for loaded in [False, True] if load else [False]:
        base = None
        for name, spin, switch, ys in variants:
            if loaded:
                s, counts = _under_load(
                    lambda spin=spin, switch=switch, ys=ys: _run_loop(seconds, spin, switch, ys)  # type: ignore[misc]
                )
                tag = f"10 ws clients ({counts['received']} msgs)"
            else:
                s, tag = _run_loop(seconds, spin, switch, ys), "idle"
            base = base or s.period_error_p99_s
            print(
                f"| {name} | {tag} | {s.rate_hz:.2f} | {s.period_error_p50_s * 1e6:.0f} | "
                f"{s.period_error_p99_s * 1e6:.0f} | {s.period_error_max_s * 1e6:.0f} | "
                f"{s.overruns} | {s.period_error_p99_s / base:.2f} |"
            )


# ---------------------------------------------------------------------------------------------
# 2. perception
def bench_perception(n: int) -> None:
    world = load_world("indoor")
    cam = CameraModel()
    renderer = Renderer(world, seed=0)
    loc = MarkerLocaliser(world, cam)
    rng = np.random.default_rng(0)
    frames = []
    while len(frames) < n:
        m = world.markers[len(frames) % len(world.markers)]
        d, off = rng.uniform(0.8, 3.0), rng.uniform(-0.6, 0.6)
        ang = m.yaw_rad + off
        x, y = m.position[0] + d * math.cos(ang), m.position[1] + d * math.sin(ang)
        if not world.bounds.contains(x, y, 1.2, margin=0.3):
            continue
        yaw = math.atan2(m.position[1] - y, m.position[0] - x) + rng.uniform(-0.3, 0.3)
        frames.append((renderer.render((x, y, 1.2, 0.0, 0.0, yaw), frame=len(frames)), yaw))
    import cv2

    grey = [cv2.cvtColor(f, cv2.COLOR_BGR2GRAY) for f, _ in frames]
    det_t = []
    for g in grey:
        t0 = time.perf_counter()
        loc.detector.detectMarkers(g)
        det_t.append(time.perf_counter() - t0)
    ekf = ExtendedKalmanFilter()
    full_t, ekf_t, found = [], [], 0
    for k, (f, yaw) in enumerate(frames):
        t = 0.1 * (k + 1)
        ekf.update_navdata(NavdataInput(t, 0.0, 0.0, 0.0, 1.2, 0.0))
        t0 = time.perf_counter()
        res = loc.process(f, t, 0.0, 0.0, yaw)
        t1 = time.perf_counter()
        for det in res.detections:
            ekf.reset(t, det.fix.x, det.fix.y, det.fix.z, det.fix.yaw_rad, localised=True)
            ekf.update_marker(det.fix)
            found += 1
        t2 = time.perf_counter()
        full_t.append(t2 - t0)
        ekf_t.append((t2 - t1) / max(1, len(res.detections)))
    med = statistics.median
    print(f"\n## Perception, 640×360, {n} rendered frames ({found} marker fixes)")
    print("| stage | median ms | p99 ms | ratio vs detect |")
    print("|---|---|---|---|")
    d50 = med(det_t)
    for name, ts in (("ArUco detect (baseline)", det_t), ("detect + IPPE + EKF update", full_t)):
        print(
            f"| {name} | {med(ts) * 1e3:.2f} | {np.percentile(ts, 99) * 1e3:.2f} | "
            f"{med(ts) / d50:.2f} |"
        )
    print(
        f"| EKF marker update alone (reset+update) | {med(ekf_t) * 1e3:.3f} | "
        f"{np.percentile(ekf_t, 99) * 1e3:.3f} | {med(ekf_t) / d50:.3f} |"
    )


# ---------------------------------------------------------------------------------------------
# 3. closed loop
def _accuracy(camera: bool, plans: list[tuple[int, tuple[float, float, float], list[int]]]):  # type: ignore[no-untyped-def]
    from tests.autonomy.flight import Flight

    world = load_world("indoor")
    rows = []
    for seed, start, markers in plans:
        f = Flight.make(world, seed=seed, camera=camera, starts=[start])
        f.submit({"action": "takeoff"})
        f.run_until_idle(12.0)
        for mid in markers:
            t0 = f.rig.clock.now()
            f.tm.submit([{"action": "goto", "marker": mid}])
            ok = f.run_until_idle(40.0) and f.events[-1].kind == "done"
            sp = world.marker(mid).standoff(1.0)
            d, dyaw = f.truth_error(sp.x, sp.y, sp.z, sp.yaw_rad)
            rows.append((mid, ok, d, dyaw, f.rig.clock.now() - t0))
            if not ok:  # the task failed: start over from a fresh takeoff for the next marker
                f.tm.cancel()
    return rows


def bench_closed_loop(quick: bool) -> None:
    plans = [
        (0, (1.0, 3.0, 0.0), [11, 0, 1, 2]),
        (1, (1.0, 2.2, -0.6), [3, 4, 5, 6]),
        (2, (1.0, 3.8, 0.6), [7, 8, 9, 10]),
    ]
    if quick:
        plans = plans[:1]
    t0 = time.perf_counter()
    cam = _accuracy(True, plans)
    wall = time.perf_counter() - t0
    dr = _accuracy(False, plans)
    print(f"\n## Closed loop (lockstep), goto each marker; camera run took {wall:.1f} s wall")
    print("| marker | arrived | error m | yaw err ° | time s | dead-reckoning error m |")
    print("|---|---|---|---|---|---|")
    for (mid, ok, d, dy, t), (_, _, d2, _, _) in zip(cam, dr, strict=True):
        print(f"| {mid} | {'yes' if ok else 'NO'} | {d:.3f} | {dy:.1f} | {t:.1f} | {d2:.3f} |")
    med_cam = statistics.median(r[2] for r in cam)
    med_dr = statistics.median(r[2] for r in dr)
    sim_s = sum(r[4] for r in cam)
    print(
        f"| **median** | {sum(r[1] for r in cam)}/{len(cam)} | **{med_cam:.3f}** | "
        f"{statistics.median(r[3] for r in cam):.1f} | {statistics.median(r[4] for r in cam):.1f}"
        f" | {med_dr:.3f} (ratio {med_dr / max(med_cam, 1e-9):.1f}×) |"
    )
    print(f"lockstep speed with camera: {sim_s / wall:.1f}× real time")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="5 s loop runs, fewer frames and flights")
    ap.add_argument("--seconds", type=float, default=None, help="seconds per loop variant (60)")
    ap.add_argument("--skip-load", action="store_true", help="no WebSocket load runs")
    ap.add_argument("--only", choices=("loop", "perception", "closed"), default=None)
    a = ap.parse_args(argv)
    seconds = a.seconds or (5.0 if a.quick else 60.0)
    if a.only in (None, "loop"):
        bench_loop(seconds, load=not a.skip_load)
    if a.only in (None, "perception"):
        bench_perception(60 if a.quick else 300)
    if a.only in (None, "closed"):
        bench_closed_loop(a.quick)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
