"""Command deadlines on a real ``serve`` (``--vehicles process``): a motion command that reaches
the drone too long after the operator gave it is not flown, is audited as expired and is told.

One ``serve`` for the module, its vehicle in its own process, flying a simulated AR.Drone the
test runs itself (``drone.sim.probe.SimThread``: the test reads the drone's wire — a take-off
is a rising take-off bit in ``AT*REF`` — and its ground truth, never through the server under
test). Clients are real: httpx over TCP and ``websockets`` on the rosbridge endpoint. The web
process and the vehicle process are each stopped (SIGSTOP) for 3 s with a take-off on its way:
the console judges one, the vehicle (on its own clock) the other.
"""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from drone.sim.probe import SimThread
from tests.isolation.conftest import Served, reply_texts, serve, wait_for
from tests.isolation.test_processes import Listener
from tests.support.loopback import fresh_address

pytestmark = pytest.mark.timeout(240)
SIM_ADDR = fresh_address()
STALL_S = 3.0  # how long a process is stopped with a command on its way (deadline: 2 s)
REPLY = {"/console/reply": "uav_console/Reply"}
TWIST = "geometry_msgs/Twist"
FORWARD = {"linear": {"x": 0.3, "y": 0.0, "z": 0.0}, "angular": {"x": 0.0, "y": 0.0, "z": 0.0}}
STILL = {"linear": {"x": 0.0, "y": 0.0, "z": 0.0}, "angular": {"x": 0.0, "y": 0.0, "z": 0.0}}


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[SimThread, Served, Path]]:
    tmp: Path = tmp_path_factory.mktemp("deadlines")
    with (
        SimThread(SIM_ADDR) as sim,
        serve(tmp, SIM_ADDR, extra=("--vehicles", "process")) as srv,
    ):
        srv.wait_vehicle()
        yield sim, srv, tmp / "data" / "audit.db"


class Pilot(Listener):
    """A rosbridge pilot holding the lease; REST calls name its key, as the console page does."""

    def __init__(self, srv: Served) -> None:
        super().__init__(srv.ws, REPLY)
        self.send({"op": "set_level", "level": "info"})
        self.key = str(self.call("/console/lease", {"action": "acquire"})["key"])

    def call(self, service: str, args: dict[str, Any]) -> dict[str, Any]:
        cid = f"call:{service}:{time.monotonic()}"
        self.send({"op": "call_service", "id": cid, "service": service, "args": args})
        frame = wait_for(lambda: self._frame("service_response", cid), f"{service}'s answer")
        return dict(frame["values"])

    def _frame(self, op: str, fid: str) -> dict[str, Any] | None:
        for f in list(self.frames):
            obj = json.loads(f)
            if obj.get("op") == op and obj.get("id") == fid:
                return dict(obj)
        return None

    def status(self, fid: str) -> dict[str, Any]:
        return dict(wait_for(lambda: self._frame("status", fid), f"status of {fid}"))

    def publish(self, topic: str, msg: dict[str, Any], issued: float, fid: str = "") -> None:
        frame: dict[str, Any] = {"op": "publish", "topic": topic, "msg": msg, "issued": issued}
        if fid:
            frame["id"] = fid
        self.send(frame)

    def synced(self) -> None:
        """Every op sent before has been handled by the server (ops run in order)."""
        self.call("/rosapi/get_time", {})

    def post(
        self, srv: Served, path: str, issued: float | None, *, fresh: bool = False, **kw: Any
    ) -> httpx.Response:
        """A pilot's POST naming the lease; ``fresh``: on a new connection (a kept-alive one
        may be closed by the server's keep-alive timer while the test holds it stopped)."""
        headers = {"X-Pilot-Lease": self.key}
        if issued is not None:
            headers["X-Command-Issued"] = f"{issued:.3f}"
        if not fresh:
            return srv.http.post(path, headers=headers, timeout=30, **kw)
        with httpx.Client(base_url=srv.http.base_url, headers=srv.http.headers) as client:
            return client.post(path, headers=headers, timeout=30, **kw)


def expired_rows(db: Path) -> list[dict[str, Any]]:
    with sqlite3.connect(f"file:{db}?mode=ro", uri=True) as conn:
        rows = conn.execute(
            "SELECT source, commands, outcome FROM audit WHERE action = 'expired' ORDER BY id"
        ).fetchall()
    return [{"source": s, "commands": json.loads(c), "outcome": o} for s, c, o in rows]


def assert_no_take_off_on_the_wire(sim: SimThread, since: float) -> None:
    """No take-off reached the drone since monotonic ``since``: after a second more of its
    AT stream (≥ 30 datagrams a second), anything sent would be on the wire."""
    seen = sim.call(lambda: sim.sim.datagrams)
    wait_for(lambda: sim.call(lambda: sim.sim.datagrams) > seen + 30, "a second of AT stream")
    assert sim.call(lambda: sim.sim.first_takeoff_after(since)) is None
    assert not sim.truth.flying


def land(sim: SimThread, pilot: Pilot, srv: Served) -> None:
    r = pilot.post(srv, "/api/v1/drones/uav1/land", time.time())
    assert r.status_code == 200, r.text
    wait_for(lambda: not sim.truth.flying, "landing", 30)


def test_late_commands_at_every_door_are_not_flown_told_and_audited(
    rig: tuple[SimThread, Served, Path],
) -> None:
    sim, srv, db = rig
    pilot = Pilot(srv)
    try:
        t0 = time.monotonic()
        before = len(expired_rows(db))
        late = time.time() - 5.0
        # REST, X-Command-Issued
        r = pilot.post(srv, "/api/v1/drones/uav1/takeoff", late)
        assert r.status_code == 200 and r.json()["accepted"] is False, r.text
        assert r.json()["detail"].startswith("Not flown: 'take off' reached the drone 5.")
        assert r.json()["detail"].endswith("(deadline 2 s).")
        # REST, the body's issued
        r = pilot.post(srv, "/api/v1/drones/uav1/takeoff", None, json={"issued": late})
        assert r.json()["accepted"] is False and "Not flown" in r.json()["detail"], r.text
        # REST, a sentence
        r = pilot.post(srv, "/api/v1/command", None, json={"text": "take off", "issued": late})
        assert r.json()["accepted"] is False and r.json()["reply"].startswith("Not flown")
        # REST, the patrol: not started
        r = pilot.post(srv, "/api/v1/patrol", late)
        assert r.status_code == 409 and r.json()["accepted"] is False, r.text
        assert r.json()["detail"].startswith("Not flown: 'patrol'")
        # rosbridge: the topic, and an utterance (the vehicle's dialog judges that one)
        pilot.publish("/ardrone/takeoff", {}, late, "topic")
        assert "Not flown: 'take off'" in pilot.status("topic")["msg"]
        utter = {"text": "take off", "confidence": 1.0, "source": "text"}
        pilot.publish("/console/utterance", utter, late)
        wait_for(
            lambda: sum("Not flown" in t for t in reply_texts(pilot.frames)) >= 6,
            "every late command said on /console/reply",
        )
        assert_no_take_off_on_the_wire(sim, t0)
        rows = wait_for(lambda: (r := expired_rows(db)[before:]) and len(r) >= 6 and r, "rows")
        assert {row["source"] for row in rows} >= {"rest", "rosbridge", "text"}
        assert all(row["outcome"].startswith("expired: delivered") for row in rows), rows
    finally:
        pilot.close()


def test_in_time_it_flies_a_late_jog_does_not_move_and_a_late_stop_still_lands(
    rig: tuple[SimThread, Served, Path],
) -> None:
    sim, srv, _ = rig
    pilot = Pilot(srv)
    try:
        r = pilot.post(srv, "/api/v1/drones/uav1/takeoff", time.time())
        assert r.json()["accepted"] is True, r.text
        wait_for(lambda: sim.truth.flying and sim.truth.z > 0.6, "take-off", 30)
        wait_for(lambda: abs(sim.truth.vx) < 0.05 and abs(sim.truth.vy) < 0.05, "a still hover")

        def jog(issued_ago: float) -> float:
            """Jog forward for a second, as the page does (10 Hz); metres moved."""
            x0 = sim.truth.x
            for _ in range(10):
                pilot.publish("/cmd_vel", FORWARD, time.time() - issued_ago)
                time.sleep(0.1)  # the operator's key held for a second
            pilot.publish("/cmd_vel", STILL, time.time() - issued_ago)  # a stop: never late
            pilot.synced()
            time.sleep(0.5)  # the drone coasts on what it was told
            return float(sim.truth.x - x0)

        assert abs(jog(issued_ago=3.0)) < 0.15, "a late jog moved the drone"
        assert any("Not flown: 'jog'" in t for t in reply_texts(pilot.frames))
        assert jog(issued_ago=0.0) > 0.3, "a jog in time should move it (the test can fail)"
        # a stop issued long ago still lands the drone
        r = pilot.post(srv, "/api/v1/drones/uav1/land", time.time() - 60.0)
        assert r.json()["accepted"] is True, r.text
        wait_for(lambda: not sim.truth.flying, "the late landing", 30)
    finally:
        pilot.close()
        if sim.truth.flying:
            srv.http.post("/api/v1/drones/uav1/land")


def _stalled(pid: int, pilot: Pilot, srv: Served) -> tuple[httpx.Response, float]:
    """Stop process ``pid``, take off by REST and by ``/ardrone/takeoff`` as the operator
    clicks (issued now), resume it ``STALL_S`` later: (the REST answer, the click's time)."""
    answer: list[httpx.Response | Exception] = []

    def take_off() -> None:
        try:
            answer.append(pilot.post(srv, "/api/v1/drones/uav1/takeoff", clicked, fresh=True))
        except httpx.HTTPError as exc:
            answer.append(exc)

    os.kill(pid, signal.SIGSTOP)
    try:
        clicked = time.time()
        thread = threading.Thread(target=take_off)
        thread.start()
        pilot.publish("/ardrone/takeoff", {}, clicked, "stalled")
        time.sleep(STALL_S)  # the stall itself: what the test is about
    finally:
        os.kill(pid, signal.SIGCONT)
    thread.join(40)
    assert answer, "the take-off request got no answer"
    assert isinstance(answer[0], httpx.Response), f"{answer[0]!r}\n{srv.log()}"
    return answer[0], clicked


def test_a_take_off_queued_while_the_web_server_is_stopped_is_dropped(
    rig: tuple[SimThread, Served, Path],
) -> None:
    sim, srv, db = rig
    pilot = Pilot(srv)
    try:
        t0 = time.monotonic()
        before = len(expired_rows(db))
        r, _ = _stalled(srv.proc.pid, pilot, srv)
        assert r.status_code == 200 and r.json()["accepted"] is False, r.text
        assert r.json()["detail"].startswith("Not flown: 'take off' reached the drone 3.")
        assert "Not flown: 'take off' reached the drone 3." in pilot.status("stalled")["msg"]
        wait_for(
            lambda: sum("Not flown" in t for t in reply_texts(pilot.frames)) >= 2,
            "both said on /console/reply",
        )
        assert_no_take_off_on_the_wire(sim, t0)
        rows = wait_for(lambda: (r := expired_rows(db)[before:]) and len(r) >= 2 and r, "rows")
        assert {row["source"] for row in rows} == {"rest", "rosbridge"}
    finally:
        pilot.close()


def test_a_take_off_queued_while_the_vehicle_is_stopped_is_dropped_by_the_vehicle(
    rig: tuple[SimThread, Served, Path],
) -> None:
    """The console hands both over in time; the vehicle, stopped meanwhile, receives them
    3 s late and judges them on its own clock (the offset from the console's heartbeat)."""
    sim, srv, db = rig
    pilot = Pilot(srv)
    try:
        t0 = time.monotonic()
        before = len(expired_rows(db))
        r, _ = _stalled(int(srv.vehicle()["pid"]), pilot, srv)
        assert r.status_code == 200 and r.json()["accepted"] is False, r.text
        assert r.json()["detail"].startswith("Not flown: 'take off' reached the drone 3.")
        wait_for(
            lambda: sum("Not flown" in t for t in reply_texts(pilot.frames)) >= 2,
            "both said by the vehicle on /console/reply",
        )
        assert_no_take_off_on_the_wire(sim, t0)
        rows = wait_for(lambda: (r := expired_rows(db)[before:]) and len(r) >= 2 and r, "rows")
        # the REST row by the console (told by the vehicle), the topic's by the vehicle itself
        assert {row["source"] for row in rows} == {"rest", "topic"}
        assert srv.vehicle()["connected"]
    finally:
        pilot.close()
