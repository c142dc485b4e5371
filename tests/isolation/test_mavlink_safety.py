"""A MAVLink drone in its own vehicle process stays safe (issue 14), as an AR.Drone does
(tests/isolation/test_processes.py): an emergency through the vehicle's safety door force-disarms
the simulated PX4 while the web process is stopped; a killed vehicle process is reported and
restarted, with its PX4; a stopped web process makes the vehicle hold the PX4 where it is (a
position setpoint streamed in OFFBOARD, as the hover task does for any localised drone), then
land it after the long-loss time.

One ``serve --vehicles process --drone sim-mavlink`` for the module. The vehicle owns the
simulated PX4 (on ``SIM_ADDR``, TCP ``PX4_PORT``); the test watches that PX4's own wire through a
second, passive TCP link of its own (:class:`Px4Wire`: it only reads, so it is no ground station
to the PX4), so what it checks while the web process is stopped comes from the autopilot, never
through the server under test.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

from drone.mavlink.codec import Codec, Message, mav
from drone.mavlink.modes import mode_name
from drone.mavlink.simserver import TCP_PORT
from tests.isolation.conftest import PILOT, Served, door_stop, reply_texts, serve, wait_for
from tests.isolation.test_mavlink_process import assert_own_process
from tests.isolation.test_processes import Listener
from tests.support.loopback import fresh_address

pytestmark = pytest.mark.timeout(180)
HOST = fresh_address()
SIM_ADDR = fresh_address()  # the vehicle's simulated PX4 (UAVC_SIM_BASE_ADDR)
PX4_PORT = TCP_PORT  # UAVC_MAVLINK_SIM_PORT's default: PX4 SITL's TCP port
LAND_AFTER_S = 6.0  # the long-loss landing, shortened for the test (20 s by default)


@dataclass(frozen=True)
class Px4State:
    """What the PX4 last said about itself on the wire."""

    t: float  # time.monotonic() of the latest HEARTBEAT
    armed: bool
    mode: str  # QGroundControl's name: AUTO.LOITER, AUTO.LAND, OFFBOARD…
    landed_state: int  # MAV_LANDED_STATE_*
    rel_alt_m: float
    speed_m_s: float  # horizontal ground speed
    north_m: float  # local position (LOCAL_POSITION_NED)
    east_m: float


class Px4Wire:
    """A passive TCP link to the simulated PX4: decodes its streams, sends nothing; reconnects
    when the PX4 goes away (its vehicle process was killed) and comes back."""

    def __init__(self, addr: str, port: int = PX4_PORT) -> None:
        self.addr, self.port = addr, port
        self.state: Px4State | None = None
        self.connects = 0
        self.history: list[tuple[float, bool, str]] = []  # (t, armed, mode) at each change
        self._alt = self._speed = self._north = self._east = 0.0
        self._landed = mav.MAV_LANDED_STATE_UNDEFINED
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self) -> Px4Wire:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(5)

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                with socket.create_connection((self.addr, self.port), timeout=1.0) as sock:
                    self.connects += 1
                    self._read(sock)
            except OSError:
                pass
            self._stop.wait(0.2)

    def _read(self, sock: socket.socket) -> None:
        codec = Codec(255, 191)
        while not self._stop.is_set():
            try:
                data = sock.recv(65536)
            except TimeoutError:
                continue
            if not data:
                return
            for msg in codec.feed(data):
                self._on(msg)

    def _on(self, m: Message) -> None:
        kind = m.get_type()
        if kind == "GLOBAL_POSITION_INT":
            self._alt = m.relative_alt / 1000.0
            self._speed = float(abs(complex(m.vx, m.vy))) / 100.0
        elif kind == "LOCAL_POSITION_NED":
            self._north, self._east = float(m.x), float(m.y)
        elif kind == "EXTENDED_SYS_STATE":
            self._landed = int(m.landed_state)
        elif kind == "HEARTBEAT":
            armed = bool(m.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED)
            mode = mode_name(m.autopilot, m.custom_mode)
            if not self.history or self.history[-1][1:] != (armed, mode):
                self.history.append((time.monotonic(), armed, mode))
            self.state = Px4State(
                time.monotonic(),
                armed,
                mode,
                self._landed,
                self._alt,
                self._speed,
                self._north,
                self._east,
            )

    def now(self, since: float) -> Px4State:
        """The PX4's state from a heartbeat sent after ``since`` (monotonic)."""
        return wait_for(
            lambda: (s := self.state) is not None and s.t > since and s, "a PX4 heartbeat", 10
        )


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Px4Wire, Served]]:
    tmp: Path = tmp_path_factory.mktemp("mavlink-safety")
    env = {
        "UAVC_SIM_BASE_ADDR": SIM_ADDR,
        "UAVC_SIM_SPEED": "2",
        "UAVC_CENTRAL_LOSS_LAND_S": str(LAND_AFTER_S),
    }
    extra = ("--vehicles", "process", "--world", "outdoor")
    with serve(tmp, "sim-mavlink", extra=extra, env=env, host=HOST) as srv:
        srv.wait_vehicle()
        with Px4Wire(SIM_ADDR) as wire:
            wait_for(lambda: wire.state, "the PX4's heartbeat on the test's own link")
            yield wire, srv


def settled(wire: Px4Wire, srv: Served) -> bool:
    """On the ground, disarmed, and the console's drone landed with no task under way (after a
    long-loss landing the vehicle's land task finishes a moment after the PX4 disarms)."""
    if not on_ground(wire):
        return False
    d = srv.drone()
    return d["ctrl_state"] == "LANDED" and d["task"]["state"] not in ("queued", "running")


def take_off(wire: Px4Wire, srv: Served) -> None:
    wait_for(lambda: settled(wire, srv), "the drone settled on the ground", 20)
    r = srv.http.post("/api/v1/drones/uav1/takeoff")
    assert r.status_code == 200 and r.json()["accepted"], r.text
    try:
        wait_for(
            lambda: (
                (s := wire.state) and s.armed and s.rel_alt_m > 2.0 and s.mode != "AUTO.TAKEOFF"
            ),
            "the PX4 to take off",
            30,
        )
    except AssertionError as exc:  # say what the PX4 and the console were doing
        d, log_tail = srv.drone(), srv.log_path.read_text()[-800:]
        raise AssertionError(
            f"{exc}; PX4 {wire.state}, modes {wire.history[-6:]}; console "
            f"{d.get('ctrl_state')} task {d.get('task')}; log tail {log_tail}"
        ) from exc
    wait_for(lambda: srv.drone()["flying"], "the console to see it flying", 10)


def on_ground(wire: Px4Wire) -> bool:
    s = wire.state
    return s is not None and not s.armed and s.landed_state == mav.MAV_LANDED_STATE_ON_GROUND


def test_the_px4_flies_in_a_child_process_that_owns_it(rig: tuple[Px4Wire, Served]) -> None:
    _wire, srv = rig
    assert_own_process(srv, "uav1", "sim-mavlink", SIM_ADDR)
    assert "flight stacks: uav1 in its own process" in srv.log_path.read_text()
    d = srv.drone()
    assert d["vehicle"]["mode"] == "process" and d["simulated"]
    assert d["extra"]["protocol"] == "mavlink" and d["extra"]["autopilot"] == "PX4"


def test_stalled_web_process_px4_holds_then_lands(rig: tuple[Px4Wire, Served]) -> None:
    wire, srv = rig
    pid = srv.vehicle()["pid"]
    take_off(wire, srv)
    home = wire.now(0.0)
    out = srv.command("go forward 20 meters")
    assert out["accepted"], out
    wait_for(lambda: (s := wire.state) and s.speed_m_s > 1.0, "the PX4 to fly the move", 10)
    srv.pause()  # the whole web process stops: no heartbeat, no REST, no rosbridge
    try:
        t0 = time.monotonic()
        # after 1 s of silence the vehicle puts the PX4 in its own hold mode (AUTO.LOITER: it
        # holds even if the vehicle process stops too): it stops short of the 20 m, still in
        # the air, and stays
        held = wait_for(
            lambda: (s := wire.now(t0 + 1.5)).speed_m_s < 0.3 and s, "the PX4 to hold", 4
        )
        later = wire.now(held.t)
        assert time.monotonic() - t0 < LAND_AFTER_S - 0.5, "no hold before the landing"
        for s in (held, later):
            assert s.armed and s.rel_alt_m > 1.5 and s.mode == "AUTO.LOITER", s
        moved = abs(complex(held.north_m - home.north_m, held.east_m - home.east_m))
        assert 1.0 < moved < 15.0, f"finished the move despite the silent server ({moved:.1f} m)"
        drift = abs(complex(later.north_m - held.north_m, later.east_m - held.east_m))
        assert drift < 0.5, f"the hold drifted {drift:.2f} m"
        # it lands after LAND_AFTER_S of silence
        wait_for(lambda: on_ground(wire), "the landing after a long loss", LAND_AFTER_S + 20)
        assert "AUTO.LAND" in [mode for t, _, mode in wire.history if t > t0], wire.history
    finally:
        srv.resume()
    srv.assert_rejoined_after_long_loss(pid)


def test_emergency_through_the_safety_door_force_disarms_the_px4(
    rig: tuple[Px4Wire, Served],
) -> None:
    wire, srv = rig
    door = srv.vehicle()["door_url"]
    take_off(wire, srv)
    # the vehicle's MAVROS topics cross the link: /mavros/state (latched) says armed
    with connect(srv.ws) as ws:
        sub = {"op": "subscribe", "topic": "/mavros/state", "type": "mavros_msgs/State"}
        ws.send(json.dumps(sub))

        def armed() -> bool:
            msg = json.loads(ws.recv(timeout=5))
            return bool(msg.get("topic") == "/mavros/state" and msg["msg"]["armed"])

        wait_for(armed, "/mavros/state armed", 15, period=0)
    srv.pause()
    try:
        t0 = time.monotonic()
        ack = door_stop(door, PILOT, "emergency", "px4-1")
        assert ack.action == "emergency" and ack.accepted, ack
        # motors off in the air: the PX4 accepted a forced disarm, and is on the ground
        wait_for(lambda: on_ground(wire) and wire.now(t0), "the PX4 to disarm", 10)
        after = [mode for t, _, mode in wire.history if t > t0]
        assert "AUTO.LAND" not in after, f"it landed instead of stopping its motors: {after}"
        assert srv.proc.poll() is None  # still stopped, not gone: the path never touched it
        with pytest.raises(ConnectionClosed):  # the pilot token only
            door_stop(door, "not-the-token", "emergency", "px4-2")
    finally:
        srv.resume()
    wait_for(lambda: srv.drone()["emergency"], "the console to show the emergency")
    r = srv.http.post("/api/v1/drones/uav1/reset")
    assert r.status_code == 200 and r.json()["accepted"], r.text
    wait_for(lambda: not srv.drone()["emergency"], "the drone to leave EMERGENCY")


def test_killed_vehicle_process_is_reported_and_restarted(rig: tuple[Px4Wire, Served]) -> None:
    wire, srv = rig
    lis = Listener(srv.ws, {"/console/reply": "uav_console/Reply"})
    try:
        old = srv.vehicle()["pid"]
        links = wire.connects
        os.kill(old, signal.SIGKILL)
        wait_for(
            lambda: any("flight process stopped" in t for t in reply_texts(lis.frames)),
            "the console's alert",
        )
        assert any("killed by signal 9" in t for t in reply_texts(lis.frames))
        again = wait_for(
            lambda: (v := srv.wait_vehicle())["pid"] != old and v,
            "a new vehicle process",
            40,
        )
        assert again["connected"]
        # its new PX4 speaks on the wire, and its telemetry reaches the console again
        wait_for(lambda: wire.connects > links, "the new PX4 on the test's link")
        wire.now(time.monotonic())
        t1 = srv.drone()["t"]
        wait_for(lambda: srv.drone()["t"] > t1 and srv.drone()["link_ok"], "fresh telemetry")
        take_off(wire, srv)
        r = srv.http.post("/api/v1/drones/uav1/land")
        assert r.status_code == 200 and r.json()["accepted"], r.text
        wait_for(lambda: on_ground(wire), "the PX4 to land", 30)
    finally:
        lis.close()
