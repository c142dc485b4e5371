"""Each drone's flight stack in its own process (issue 14 "Flight-critical isolation").

One ``serve --vehicles process`` for the module, flying a simulated AR.Drone run by the test
process itself (so the test reads the drone's wire and ground truth directly, never through the
server under test). Clients are real: httpx over TCP and ``websockets`` on the rosbridge port.
"""

from __future__ import annotations

import json
import os
import re
import signal
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

from drone.sim.probe import SimThread
from tests.isolation.conftest import Served, door_stop, reply_texts, serve, wait_for
from tests.support.loopback import fresh_address

pytestmark = pytest.mark.timeout(180)
SIM_ADDR = fresh_address()
LAND_AFTER_S = 6.0  # the long-loss landing, shortened for the test (20 s by default)


class Listener:
    """A rosbridge client (``websockets``) collecting every frame on some topics."""

    def __init__(self, url: str, topics: dict[str, str]) -> None:
        self._cm = connect(url, max_size=None)
        self.ws = self._cm.__enter__()
        self.frames: list[str] = []
        for topic, typ in topics.items():
            sub = {"op": "subscribe", "topic": topic, "type": typ}
            if "image" in topic:
                sub["throttle_rate"] = 500
            self.ws.send(json.dumps(sub))
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        try:
            for frame in self.ws:
                if isinstance(frame, str):
                    self.frames.append(frame)
        except Exception:
            return

    def send(self, obj: dict[str, Any]) -> None:
        self.ws.send(json.dumps(obj))

    def topics(self) -> set[str]:
        return {json.loads(f).get("topic", "") for f in list(self.frames)}

    def close(self) -> None:
        self._cm.__exit__(None, None, None)


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[SimThread, Served]]:
    tmp: Path = tmp_path_factory.mktemp("isolation")
    env = {"UAVC_CENTRAL_LOSS_LAND_S": str(LAND_AFTER_S)}
    with (
        SimThread(SIM_ADDR) as sim,
        serve(tmp, SIM_ADDR, extra=("--vehicles", "process"), env=env) as srv,
    ):
        srv.wait_vehicle()
        assert "flight stacks: uav1 in its own process" in srv.log_path.read_text()
        yield sim, srv


def take_off(sim: SimThread, srv: Served, *, localise: bool = True) -> None:
    assert srv.command_again_if_late("take off")["accepted"], srv.log()
    wait_for(lambda: sim.truth.flying and sim.truth.z > 0.6, "take-off", 30)
    if localise:
        wait_for(lambda: srv.drone()["localised"], "the EKF to localise on the markers", 30)


def land(sim: SimThread, srv: Served) -> None:
    srv.command("land")
    wait_for(lambda: not sim.truth.flying, "landing", 30)


def leave_emergency(sim: SimThread, srv: Served) -> None:
    """``reset`` until the simulator leaves EMERGENCY (the bit toggles on a rising edge, and the
    driver may still hold it from the stop: a reset then is no edge, so wait and retry)."""

    def reset() -> bool:
        time.sleep(1.0)  # the driver lets go of the bit: the next reset is an edge
        r = srv.http.post("/api/v1/drones/uav1/reset")
        assert r.status_code == 200, r.text
        time.sleep(1.0)  # the edge reaches the simulator (no state to poll for "not yet")
        return not sim.truth.emergency

    wait_for(reset, "the drone to leave EMERGENCY", 40)


def assert_control_thread_scheduling(pid: int, controller: dict[str, Any]) -> None:
    """The vehicle's control thread asked for SCHED_FIFO 10 (``control_rt_priority``) and its
    other threads for SCHED_RR 5 (``vehicle_rt_priority``), unless the environment asks for none
    (``UAVC_CONTROL_RT_PRIORITY=0``): what the loop reports is what the OS says of the process's
    threads (granted where privileged, e.g. root; else refused and said, and then no thread of
    the vehicle runs real-time). The numeric libraries' worker threads (OpenBLAS, OpenCV),
    started at import before the vehicle asks, stay normal."""
    threads = {
        int(tid): (os.sched_getscheduler(int(tid)), os.sched_getparam(int(tid)).sched_priority)
        for tid in os.listdir(f"/proc/{pid}/task")
    }
    control = [tid for tid, policy in threads.items() if policy == (os.SCHED_FIFO, 10)]
    if os.environ.get("UAVC_CONTROL_RT_PRIORITY", "").strip() == "0":  # none asked (a shared
        # machine's runs): the control thread keeps normal scheduling, no thread is real-time
        assert controller["scheduling"] == "normal", controller
        assert all(policy != os.SCHED_FIFO for policy, _ in threads.values()), threads
    elif controller["scheduling"] == "SCHED_FIFO 10":
        assert len(control) == 1, threads
        assert threads[pid] == (os.SCHED_RR, 5), threads  # the asyncio (main) thread
        others = {policy for tid, policy in threads.items() if tid != control[0]}
        assert others <= {(os.SCHED_RR, 5), (os.SCHED_OTHER, 0)}, threads
    else:  # refused: the control thread kept what it inherited from the vehicle's main thread
        policy, priority = threads[pid]
        kept = "normal" if policy == os.SCHED_OTHER else f"SCHED_RR {priority}"
        assert controller["scheduling"].startswith(f"{kept} (SCHED_FIFO 10 refused"), controller
        assert all(policy != os.SCHED_FIFO for policy, _ in threads.values()), threads


def test_a_remote_vehicle_is_a_whole_vehicle(rig: tuple[SimThread, Served]) -> None:
    """Camera, navdata, pose, task, replies, typed commands and the jog all cross the link."""
    sim, srv = rig
    topics = {
        "/ardrone/navdata": "ardrone_autonomy/Navdata",
        "/uav/pose": "geometry_msgs/PoseStamped",
        "/uav/task": "uav_console/TaskStatus",
        "/console/reply": "uav_console/Reply",
        "/console/state": "uav_console/DialogState",
        "/ardrone/image_raw/compressed": "sensor_msgs/CompressedImage",
    }
    lis = Listener(srv.ws, topics)
    try:
        take_off(sim, srv)
        # typed in the console: an utterance over rosbridge, answered on /console/reply
        utterance = {"text": "go up 0.4 meters", "confidence": 1.0, "source": "text"}
        lis.send({"op": "publish", "topic": "/console/utterance", "msg": {**utterance}})
        wait_for(lambda: any("Climbing" in t for t in reply_texts(lis.frames)), "reply")
        wait_for(lambda: sim.truth.z > 1.0, "the climb", 30)
        # the jog: /cmd_vel forward at 30 % for a second moves the drone forward
        x0 = sim.truth.x
        twist = {"linear": {"x": 0.3, "y": 0.0, "z": 0.0}, "angular": {"x": 0, "y": 0, "z": 0}}
        for _ in range(10):
            lis.send({"op": "publish", "topic": "/cmd_vel", "msg": twist})
            time.sleep(0.1)  # a key held for a second at the page's 10 Hz
        zero = {"linear": {"x": 0, "y": 0, "z": 0}, "angular": {"x": 0, "y": 0, "z": 0}}
        lis.send({"op": "publish", "topic": "/cmd_vel", "msg": zero})
        wait_for(lambda: sim.truth.x - x0 > 0.15, "the jog to move the drone forward", 10)
        land(sim, srv)
        wait_for(lambda: set(topics) <= lis.topics(), f"all topics (got {lis.topics()})", 10)
        drone = srv.drone()
        assert drone["vehicle"]["mode"] == "process"
        assert drone["controller"]["rate_hz"] > 50  # the 100 Hz loop runs in the vehicle
        assert_control_thread_scheduling(int(srv.vehicle()["pid"]), drone["controller"])
        # a full garbage collection walks only what the flight made, not the startup objects
        assert re.search(r"uav1: \d{4,} startup objects frozen out of", srv.log_path.read_text())
        with srv.http.stream("GET", "/api/v1/drones/uav1/video.mjpg") as stream:
            assert stream.status_code == 200
            first = b""
            for chunk in stream.iter_bytes():
                first += chunk
                if b"\xff\xd9" in first:
                    break
            assert b"\xff\xd8" in first  # a whole JPEG from the vehicle's camera
    finally:
        lis.close()


def test_stalled_web_process_vehicle_hovers_then_lands_then_reconnects(
    rig: tuple[SimThread, Served],
) -> None:
    sim, srv = rig
    take_off(sim, srv)
    pid = srv.vehicle()["pid"]
    assert srv.command("go forward 4 meters")["accepted"]
    start_x = sim.truth.x
    wait_for(lambda: sim.truth.x > start_x + 0.3, "the drone to fly forward", 20)
    srv.pause()  # the whole web process stops: no heartbeat, no REST, no rosbridge
    try:
        t0 = time.monotonic()
        # it hovers after 1 s of silence, lands after LAND_AFTER_S: still up 2 s before that
        time.sleep(max(0.0, t0 + LAND_AFTER_S - 2.0 - time.monotonic()))
        t = sim.truth
        assert t.flying, "landed before the long-loss time"
        assert t.x < start_x + 3.5, "finished the move despite the silent server"
        wait_for(lambda: not sim.truth.flying, "the landing after a long loss", LAND_AFTER_S + 15)
    finally:
        srv.resume()
    srv.assert_rejoined_after_long_loss(pid)


def test_emergency_reaches_the_wire_while_the_web_process_is_stalled(
    rig: tuple[SimThread, Served],
) -> None:
    sim, srv = rig
    vehicle = srv.vehicle()
    door, ticket = vehicle["door_url"], vehicle["door_ticket"]
    take_off(sim, srv, localise=False)
    srv.pause()
    try:
        t0 = time.monotonic()
        # a fresh connection with the console's ticket: the vehicle checks it on its own
        ack = door_stop(door, ticket, "emergency", "stalled-1", time.time())
        assert ack.accepted and ack.road == "door" and ack.action == "emergency", ack
        arrived = wait_for(lambda: sim.sim.first_emergency_after(t0), "AT*REF emergency", 10)
        assert arrived >= t0
        wait_for(lambda: sim.truth.emergency, "the simulator's emergency state", 10)
        assert srv.proc.poll() is None  # still stopped, not gone: the path never touched it
        with pytest.raises(ConnectionClosed):  # no token, no stop
            door_stop(door, "not-the-token", "emergency", "stalled-2")
    finally:
        srv.resume()
    # the same stop id down the server road, late: answered with the door's delivery
    r = srv.http.post("/api/v1/drones/uav1/emergency", json={"id": "stalled-1"})
    assert r.status_code == 200 and r.json()["road"] == "door", r.text
    assert "already delivered by the door road" in r.json()["detail"]
    leave_emergency(sim, srv)


def test_killed_vehicle_process_is_reported_and_restarted(rig: tuple[SimThread, Served]) -> None:
    sim, srv = rig
    lis = Listener(srv.ws, {"/console/reply": "uav_console/Reply"})
    try:
        old = srv.vehicle()["pid"]
        os.kill(old, signal.SIGKILL)
        wait_for(
            lambda: any("flight process stopped" in t for t in reply_texts(lis.frames)),
            "the console's alert",
        )
        assert any("killed by signal 9" in t for t in reply_texts(lis.frames))
        again = wait_for(
            lambda: (v := srv.wait_vehicle())["pid"] != old and v, "a new vehicle process", 40
        )
        assert again["connected"]
        # and it flies
        take_off(sim, srv, localise=False)
        land(sim, srv)
    finally:
        lis.close()


def test_web_process_crash_vehicle_keeps_flying_and_is_adopted_by_the_next_serve(
    tmp_path: Path,
) -> None:
    """kill -9 of ``serve``: its vehicle hovers on (no heartbeat), and a new ``serve`` on the same
    port and data directory listens on the bus where the first did and adopts the same vehicle
    process instead of starting a second one; "land" lands it."""
    addr = fresh_address()
    # the bus where serve puts it by default: where it listened last, else 7447 or the next
    env = {"UAVC_CENTRAL_LOSS_LAND_S": "60", "UAVC_BUS_LISTEN": ""}
    with SimThread(addr) as sim:
        with serve(tmp_path, addr, extra=("--vehicles", "process"), env=env) as first:
            pid = first.wait_vehicle()["pid"]
            argv = Path(f"/proc/{pid}/cmdline").read_text().split("\0")
            assert "--bus-connect" in argv, argv  # it joins its console over the bus
            endpoints = first.http.get("/api/v1/health").json()["bus"]["endpoints"]
            take_off(sim, first, localise=False)
            first.proc.kill()  # SIGKILL: no clean shutdown, the vehicle is orphaned
            first.proc.wait()
            port = first.port
        time.sleep(2.0)  # deliberate: two seconds with no web process, and it stays up
        assert sim.truth.flying, "the orphaned vehicle must keep the drone in the air"
        with serve(tmp_path, addr, extra=("--vehicles", "process"), env=env, port=port) as second:
            again = second.wait_vehicle()
            assert again["pid"] == pid, "the new serve should adopt the running vehicle"
            assert second.http.get("/api/v1/health").json()["bus"]["endpoints"] == endpoints
            assert sim.truth.flying
            assert second.command("land")["accepted"], second.log()
            wait_for(lambda: not sim.truth.flying, "the adopted vehicle to land", 30)
        # the second serve stopped: it asked the adopted vehicle to stop too
        wait_for(lambda: not _alive(pid), "the adopted vehicle to exit", 30)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True
