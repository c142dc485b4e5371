"""Flight recorder benchmarks: what recording costs, how big recordings get, how fast it writes.

Rows (each measured with the recorder on and off in the same run, alternating):
  bridge fan-out            rosbridge, 10 subscribers, a client publishing at 1 kHz (as
                            bench/bridge.py): publish -> receive p50/p99, with the recorder
                            tapping the server's graph vs without.
  control loop              the 100 Hz ControlLoop thread's period error p99 while a drone's
                            topics (navdata 15 Hz + pose, camera JPEG 15 fps) are published
                            on a graph, with the recorder writing them vs without.
  bytes per flight-minute   a lockstep flight (simulator, EKF, PID, tasks, the vehicle node's
                            topics) around the room, recorded: MCAP bytes per simulated minute,
                            with the camera and without.
  write throughput          FlightFile.write of navdata and of 15 KiB camera JPEGs (ROS 1
                            serialisation + zstd chunks + file): messages/s and MB/s.
  encode cost               one message out of rosbridge: cbor-raw (ROS 1 bytes in CBOR) vs
                            JSON text (the default) vs cbor, for navdata and a camera image.

Usage: ``python bench/recorder.py [--quick]``. The machine may be shared: read the ratios.
"""

from __future__ import annotations

import argparse
import base64
import multiprocessing as mp
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench import bridge  # noqa: E402
from drone.control.loop import ControlLoop, LoopStats  # noqa: E402
from drone.control.pid import PaperPID, Setpoint  # noqa: E402
from drone.lockstep import LockstepRig  # noqa: E402
from drone.sim.camera import Renderer  # noqa: E402
from drone.sim.world import load_world  # noqa: E402
from server import msgs  # noqa: E402
from server.graph import Graph  # noqa: E402
from server.nodes.vehicle_node import VehicleNode  # noqa: E402
from server.recorder.mcapfile import FlightFile  # noqa: E402
from server.recorder.recorder import Recorder, RecorderConfig  # noqa: E402
from server.rosbridge import cborraw  # noqa: E402
from server.rosbridge.values import to_cbor_value, to_json_text  # noqa: E402
from server.tasks.manager import TaskManager  # noqa: E402

NAVDATA = "ardrone_autonomy/Navdata"
IMAGE = "sensor_msgs/CompressedImage"


def pct(values: list[float], q: int) -> float:
    if len(values) < 2:
        return float("nan")
    return statistics.quantiles(values, n=100)[q - 1]


# -- 1. bridge fan-out --------------------------------------------------------------------
def serve(mode: str, port: int, data_dir: str) -> None:
    """bench/bridge.py's rosbridge server, with (``on``) or without the recorder."""
    import uvicorn
    from fastapi import FastAPI

    from server.http.security import Security, TokenStore
    from server.rosbridge.context import BridgeContext
    from server.rosbridge.endpoint import make_router
    from server.settings import Settings

    settings = Settings(port=port, data_dir=Path(data_dir), rate_limit_per_s=1e6, rate_burst=10**6)
    graph = Graph()
    tokens = TokenStore(Path(data_dir), pilot_token=bridge.TOKEN)
    ctx = BridgeContext(graph=graph, security=Security(settings, tokens), settings=settings)
    ctx.out_queue_frames = 100_000
    if mode == "on":
        rec = Recorder(graph, RecorderConfig(Path(data_dir) / "flights", idle_s=3600.0))
        rec.start()
        rec.touch()  # a flight session for the whole run
    app = FastAPI()
    app.include_router(make_router(ctx))
    uvicorn.run(app, host="127.0.0.1", port=port, log_level="error", ws_ping_interval=None)


def start_server(mode: str, port: int, data_dir: str) -> subprocess.Popen[bytes]:
    proc = subprocess.Popen([sys.executable, __file__, "--serve", mode, str(port), data_dir])
    import socket

    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        try:
            socket.create_connection(("127.0.0.1", port), 0.2).close()
            return proc
        except OSError:
            time.sleep(0.05)
    proc.kill()
    raise RuntimeError("server did not start")


def bench_fan_out(seconds: float, rounds: int) -> None:
    print("\n## rosbridge fan-out, 10 subscribers, 1 kHz std_msgs/String")
    print("| recorder | p50 ms | p99 ms | delivered/s | recordings written |")
    print("|---|---|---|---|---|")
    results: dict[str, list[dict[str, float]]] = {"off": [], "on": []}
    recorded = 0
    for _ in range(rounds):
        for mode in ("off", "on"):
            with tempfile.TemporaryDirectory() as tmp:
                port = bridge.free_port()
                proc = start_server(mode, port, tmp)
                try:
                    r = bridge.fan_out(
                        "rosbridge",
                        port,
                        10,
                        1000.0,
                        seconds,
                        "/bench/chatter",
                        "std_msgs/String",
                        lambda: {"data": repr(time.monotonic())},
                    )
                finally:
                    proc.terminate()
                    proc.wait(20)
                results[mode].append(r)
                if mode == "on":
                    recorded += sum(
                        f.stat().st_size > 0 for f in (Path(tmp) / "flights").glob("*.mcap")
                    )
    for mode in ("off", "on"):
        rows = results[mode]
        p50 = statistics.median(r["p50_ms"] for r in rows)
        p99 = statistics.median(r["p99_ms"] for r in rows)
        rate = statistics.median(r["delivered_per_s"] for r in rows)
        print(
            f"| {mode} | {p50:.2f} | {p99:.2f} | {rate:.0f} | {recorded if mode == 'on' else '–'} |"
        )
    on = statistics.median(r["p50_ms"] for r in results["on"])
    off = statistics.median(r["p50_ms"] for r in results["off"])
    on99 = statistics.median(r["p99_ms"] for r in results["on"])
    off99 = statistics.median(r["p99_ms"] for r in results["off"])
    print(f"\nratio on/off: p50 {on / off:.2f}, p99 {on99 / off99:.2f}")


# -- 2. control loop ----------------------------------------------------------------------
class _State:
    x = y = 0.0
    z = 1.0
    yaw_rad = vx = vy = vz = 0.0


def _traffic(graph: Graph, stop: threading.Event) -> None:
    """A drone's topics at their live rates: navdata + pose 15 Hz, camera 15 fps (real JPEG)."""
    import cv2

    frame = Renderer(load_world("indoor"), seed=0).render((4.0, 3.0, 1.2, 0.0, 0.0, 0.5))
    _, buf = cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, 80])
    jpeg = base64.b64encode(buf.tobytes()).decode("ascii")
    period = 1 / 15
    k = 0
    t0 = time.monotonic()
    while not stop.is_set():
        nav = msgs.default_message(NAVDATA)
        nav.update(header=msgs.header("ardrone_base_link"), state=3, altd=1000 + k)
        graph.publish("/ardrone/navdata", nav, type=NAVDATA)
        pose = {"header": msgs.header(), "pose": {"position": {"x": 1.0, "y": 2.0, "z": 1.0}}}
        graph.publish("/uav/pose", pose, type="geometry_msgs/PoseStamped")
        img = {"header": msgs.header("cam"), "format": "jpeg", "data": jpeg}
        graph.publish("/ardrone/image_raw/compressed", img, type=IMAGE)
        k += 1
        stop.wait(max(0.0, t0 + k * period - time.monotonic()))


def _loop_with(recording: bool, seconds: float, directory: Path) -> LoopStats:
    graph = Graph()
    rec = None
    if recording:
        rec = Recorder(graph, RecorderConfig(directory, idle_s=3600.0, chunk_s=1.0))
        rec.start()
        rec.touch()
    stop = threading.Event()
    producer = threading.Thread(target=_traffic, args=(graph, stop), daemon=True)
    producer.start()
    pid, sp, st = PaperPID(), Setpoint(1.0, 0.5, 1.2, 0.3), _State()
    loop = ControlLoop(lambda now, dt: pid.step(st, sp, 0.01), period_s=0.01, spin_s=0.002)
    loop.start()
    time.sleep(seconds)
    loop.stop()
    stop.set()
    producer.join()
    if rec is not None:
        rec.stop()
    return loop.stats()


def bench_loop(seconds: float, rounds: int) -> None:
    print(f"\n## 100 Hz control loop, a drone's topics published, {seconds:g} s x {rounds}")
    print("| recorder | period err p50 µs | p99 µs | max µs | overruns |")
    print("|---|---|---|---|---|")
    stats: dict[str, list[LoopStats]] = {"off": [], "on": []}
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(rounds):
            for mode in ("off", "on"):
                stats[mode].append(_loop_with(mode == "on", seconds, Path(tmp) / str(i)))
    for mode in ("off", "on"):
        s = stats[mode]
        p50 = statistics.median(x.period_error_p50_s for x in s) * 1e6
        p99 = statistics.median(x.period_error_p99_s for x in s) * 1e6
        mx = max(x.period_error_max_s for x in s) * 1e6
        over = sum(x.overruns for x in s)
        print(f"| {mode} | {p50:.0f} | {p99:.0f} | {mx:.0f} | {over} |")
    on = statistics.median(x.period_error_p99_s for x in stats["on"])
    off = statistics.median(x.period_error_p99_s for x in stats["off"])
    print(f"\nratio on/off, p99: {on / off:.2f}")


# -- 3. bytes per flight-minute ------------------------------------------------------------
def flight_minute(camera: bool, sim_seconds: float) -> tuple[int, int, float]:
    """(bytes, messages, wall s) of recording a lockstep flight of ``sim_seconds``."""
    world = load_world("indoor")
    rig = LockstepRig(world, seed=3, camera=camera)
    tm = TaskManager(rig.vehicle, world, rig.clock)
    rig.add_stepper(lambda now, dt: tm.step(now))
    graph = Graph()
    clock = rig.clock.now
    t0 = time.time()
    node = VehicleNode(graph, rig.vehicle, tm, "uav1", clock=clock, stamp=lambda: t0 + clock())
    rig.add_stepper(lambda now, dt: node.step(now, images=camera))
    with tempfile.TemporaryDirectory() as tmp:
        rec = Recorder(
            graph,
            RecorderConfig(Path(tmp), idle_s=3600.0),
            clock=lambda: t0 + clock(),
            stamp_ns=lambda: int((t0 + clock()) * 1e9),
        )
        rec.start(background=False)
        rec.touch()
        rig.add_stepper(lambda now, dt: rec.step() if int(now * 100) % 10 == 0 else None)
        assert rig.wait_link()
        wall = time.perf_counter()
        tm.submit([{"action": "takeoff"}])
        markers = [m.id for m in world.markers][:4]
        tm.submit([{"action": "patrol", "markers": markers}])
        rig.run(sim_seconds)
        wall = time.perf_counter() - wall
        rec.stop()
        (row,) = rec.flights()
        return row.bytes, row.messages, wall


def bench_size(sim_seconds: float) -> None:
    print(f"\n## Recording size, lockstep patrol flight of {sim_seconds:g} simulated s")
    print("| camera | bytes per flight-minute | messages per minute | bytes per message |")
    print("|---|---|---|---|")
    for camera in (False, True):
        size, n, _wall = flight_minute(camera, sim_seconds)
        per_min = size * 60 / sim_seconds
        print(
            f"| {'15 fps JPEG' if camera else 'off'} | {per_min / 1e6:.2f} MB | "
            f"{n * 60 / sim_seconds:.0f} | {size / max(1, n):.0f} |"
        )


# -- 4. write throughput and 5. encode cost ------------------------------------------------
def _camera_msg() -> dict[str, Any]:
    import cv2

    frame = Renderer(load_world("indoor"), seed=0).render((4.0, 3.0, 1.2, 0.0, 0.0, 0.5))
    _, buf = cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, 80])
    return {"header": msgs.header("cam"), "format": "jpeg", "data": buf.tobytes()}


def _navdata_msg() -> dict[str, Any]:
    nav = msgs.default_message(NAVDATA)
    nav.update(header=msgs.header("ardrone_base_link"), state=3, altd=1234, rotZ=12.5)
    return nav


def bench_write(n: int) -> None:
    print(f"\n## Write throughput (FlightFile.write, zstd chunks, {n} messages)")
    print("| message | bytes in | msgs/s | MB/s in |")
    print("|---|---|---|---|")
    for name, type_name, msg in (
        ("navdata", NAVDATA, _navdata_msg()),
        ("camera JPEG", IMAGE, _camera_msg()),
    ):
        from server.ros1 import codec_for

        size = len(codec_for(type_name).encode(msg))
        count = n if name == "navdata" else max(50, n // 20)
        with tempfile.TemporaryDirectory() as tmp:
            f = FlightFile(Path(tmp) / "x.mcap", "x", 0)
            t = time.perf_counter()
            for i in range(count):
                f.write("/t", type_name, i, msg)
            f.finish(count, [])
            dt = time.perf_counter() - t
        print(f"| {name} | {size} | {count / dt:.0f} | {count * size / dt / 1e6:.1f} |")


def _time_per_call(fn: Callable[[], Any], n: int) -> float:
    runs = []
    for _ in range(5):
        t = time.perf_counter()
        for _ in range(n):
            fn()
        runs.append((time.perf_counter() - t) / n)
    return statistics.median(runs)


def bench_encode(n: int) -> None:
    print("\n## Encode cost per outgoing message (median of 5 runs)")
    print("| message | JSON text µs | cbor µs | cbor-raw µs | cbor-raw / JSON |")
    print("|---|---|---|---|---|")
    for name, type_name, msg in (
        ("navdata", NAVDATA, _navdata_msg()),
        ("camera JPEG", IMAGE, _camera_msg()),
    ):
        import cbor2

        k = n if name == "navdata" else max(50, n // 20)

        def as_json(msg: dict[str, Any] = msg) -> str:
            return '{"op":"publish","topic":"/t","msg":' + to_json_text(msg) + "}"

        def as_cbor(msg: dict[str, Any] = msg, type_name: str = type_name) -> bytes:
            body = {"op": "publish", "topic": "/t", "msg": to_cbor_value(type_name, msg)}
            return cbor2.dumps(body)

        def as_raw(msg: dict[str, Any] = msg, type_name: str = type_name) -> bytes:
            return cborraw.publish_frame("/t", type_name, msg)

        tj, tc, tr = (_time_per_call(f, k) for f in (as_json, as_cbor, as_raw))
        print(f"| {name} | {tj * 1e6:.1f} | {tc * 1e6:.1f} | {tr * 1e6:.1f} | {tr / tj:.2f} |")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--quick", action="store_true")
    p.add_argument("--serve", nargs=3, metavar=("MODE", "PORT", "DIR"), help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.serve:
        serve(args.serve[0], int(args.serve[1]), args.serve[2])
        return 0
    quick = args.quick
    print("Flight recorder (bench/recorder.py); machine possibly shared: read the ratios.")
    bench_encode(2000 if quick else 20000)
    bench_write(5000 if quick else 50000)
    bench_size(20.0 if quick else 60.0)
    bench_loop(3.0 if quick else 10.0, 1 if quick else 3)
    bench_fan_out(3.0 if quick else 8.0, 1 if quick else 3)
    return 0


if __name__ == "__main__":
    mp.set_start_method("spawn", force=True)
    raise SystemExit(main())
