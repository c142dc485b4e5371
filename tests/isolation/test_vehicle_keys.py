"""Issue 26 finding 5 and "Vehicles have their own credentials", on a real ``serve --fleet 2
--vehicles process`` (each vehicle process owns its simulated AR.Drone) with real WebSocket and
HTTP clients on loopback:

- the vehicles join the bus with their own keys, handed over out of ``ps``'s sight;
- the pilot token (or the observer's) does not open the bus as a vehicle: a second pilot
  posing as one moved a flying drone 0.8 m and made observers hear a fake "Battery critical at
  2 percent" reply;
- a vehicle key shows only its own drone's topics, never another's, a command, or
  ``/console/*``; its nodes' replies reach observers through the console's check;
- every door into commands judges a pilot without the lease the same way: a jog (or take-off,
  a move, a patrol) refused; land, hover and emergency go through (DESIGN §5).
"""

from __future__ import annotations

import contextlib
import json
import os
import stat
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
import zenoh
from websockets.sync.client import ClientConnection, connect

from drone.bus import keys
from drone.bus.config import client_config
from drone.bus.errors import BusConfigError
from drone.bus.session import open_session
from tests.isolation.conftest import PILOT, Served, serve, wait_for
from tests.support.loopback import fresh_address

pytestmark = pytest.mark.timeout(240)
HOST = fresh_address()
SIM_BASE = fresh_address()
OBSERVER = "vehicle-keys-observer-token"
JOG = {"linear": {"x": 0.5, "y": 0.0, "z": 0.0}, "angular": {"x": 0.0, "y": 0.0, "z": 0.0}}
ZERO = {"linear": {"x": 0.0, "y": 0.0, "z": 0.0}, "angular": {"x": 0.0, "y": 0.0, "z": 0.0}}
FAKE = "Battery critical at 2 percent. Landing now."


class Client:
    """A rosbridge v2 client (``websockets``) keeping every frame it receives."""

    def __init__(self, url: str, token: str | None = None) -> None:
        headers = {"Authorization": f"Bearer {token}"} if token else None
        self._cm = connect(url, additional_headers=headers, max_size=None)
        self.ws: ClientConnection = self._cm.__enter__()
        self.frames: list[dict[str, Any]] = []
        self._ids = 0
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        with contextlib.suppress(Exception):
            for frame in self.ws:
                if isinstance(frame, str):
                    self.frames.append(json.loads(frame))

    def send(self, obj: dict[str, Any]) -> str:
        self._ids += 1
        op_id = obj.setdefault("id", f"{obj['op']}:{self._ids}")
        self.ws.send(json.dumps(obj))
        return str(op_id)

    def find(self, op: str, op_id: str) -> dict[str, Any] | None:
        return next(
            (f for f in list(self.frames) if f.get("op") == op and f.get("id") == op_id), None
        )

    def call(self, service: str, args: dict[str, Any] | None = None) -> dict[str, Any]:
        op_id = self.send({"op": "call_service", "service": service, "args": args or {}})
        found = wait_for(
            lambda: self.find("service_response", op_id) or self.find("status", op_id),
            f"{service}'s answer",
        )
        assert found["op"] == "service_response", found
        return dict(found)

    def errors_of(self, op: dict[str, Any]) -> list[str]:
        """Send ``op``; the status errors it got (none: a later call's answer came first,
        and the server answers a connection's frames in order)."""
        op_id = self.send(op)
        self.call("/rosapi/topics")
        return [
            str(f["msg"])
            for f in list(self.frames)
            if f.get("op") == "status" and f.get("id") == op_id and f.get("level") == "error"
        ]

    def replies(self) -> list[dict[str, Any]]:
        return [
            f["msg"]
            for f in list(self.frames)
            if f.get("op") == "publish" and f.get("topic") == "/console/reply"
        ]

    def close(self) -> None:
        self._cm.__exit__(None, None, None)


@contextlib.contextmanager
def client(url: str, token: str | None = None) -> Iterator[Client]:
    c = Client(url, token)
    try:
        yield c
    finally:
        c.close()


@pytest.fixture(scope="module")
def srv(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Served]:
    tmp: Path = tmp_path_factory.mktemp("vehicle-keys")
    env = {"UAVC_SIM_BASE_ADDR": SIM_BASE}
    extra = ("--vehicles", "process", "--fleet", "2", "--observer-token", OBSERVER)
    with serve(tmp, "sim", extra=extra, env=env, host=HOST) as served:
        for name in ("uav1", "uav2"):
            served.wait_vehicle(name, timeout=90)
        yield served


def rosbridge(srv: Served) -> str:
    return f"ws://{srv.host}:{srv.port}/rosbridge"


def data_dir(srv: Served) -> Path:
    return srv.log_path.parent / "data"


def key_of(srv: Served, name: str) -> str:
    return (data_dir(srv) / "vehicle-keys" / f"{name}.key").read_text().strip()


def truth(srv: Served, name: str) -> dict[str, Any]:
    r = srv.http.get(f"/api/v1/sim/{name}/truth")
    r.raise_for_status()
    return dict(r.json())


def no_lease_http(srv: Served) -> httpx.Client:
    """A second pilot on REST: the pilot token, no ``X-Pilot-Lease``."""
    return httpx.Client(
        base_url=f"http://{srv.host}:{srv.port}",
        headers={"Authorization": f"Bearer {PILOT}"},
        timeout=20,
    )


def test_each_vehicle_joins_with_its_own_key_handed_over_out_of_sight(srv: Served) -> None:
    keys_dir = data_dir(srv) / "vehicle-keys"
    assert stat.S_IMODE(os.stat(keys_dir).st_mode) == 0o700
    secrets = {}
    for name in ("uav1", "uav2"):
        path = keys_dir / f"{name}.key"
        assert stat.S_IMODE(os.stat(path).st_mode) == 0o600
        secrets[name] = key_of(srv, name)
        assert secrets[name].startswith("uavk_") and secrets[name] != PILOT
        pid = int(srv.vehicle(name)["pid"])
        cmdline = Path(f"/proc/{pid}/cmdline").read_bytes().decode()
        assert secrets[name] not in cmdline and PILOT not in cmdline  # `ps` shows neither
        environ = Path(f"/proc/{pid}/environ").read_bytes().decode().split("\0")
        assert f"UAVC_VEHICLE_KEY={secrets[name]}" in environ
    assert secrets["uav1"] != secrets["uav2"]
    # The console alone publishes /console/reply: no connection (vehicle link or client) does.
    with client(rosbridge(srv), OBSERVER) as obs:
        pubs = obs.call("/rosapi/publishers", {"topic": "/console/reply"})["values"]["publishers"]
        assert pubs and not [p for p in pubs if p.startswith("/rosbridge/")], pubs


def test_a_vehicles_replies_state_and_interpreter_reach_clients_through_the_console(
    srv: Served,
) -> None:
    with client(rosbridge(srv), OBSERVER) as obs:
        obs.send({"op": "subscribe", "topic": "/console/reply", "type": "uav_console/Reply"})
        obs.send({"op": "subscribe", "topic": "/uav2/console/state"})
        r = srv.http.post("/api/v1/command", json={"text": "what is your battery", "drone": "uav2"})
        assert r.status_code == 200, r.text
        said = wait_for(
            lambda: [m for m in obs.replies() if "battery" in m["text"].lower()], "the reply"
        )
        assert said[0]["drone"] == "uav2"
        state = wait_for(
            lambda: [f for f in list(obs.frames) if f.get("topic") == "/uav2/console/state"],
            "uav2's dialog state (latched)",
        )
        assert state[0]["msg"]["drone"] == "uav2" and state[0]["msg"]["state"].lower() == "landed"
        out = obs.call("/uav2/console/interpret", {"text": "take off"})
        assert out["result"] is True and "takeoff" in json.dumps(out["values"]), out


def vehicle_session(srv: Served, name: str, password: str) -> zenoh.Session:
    """A Zenoh client on the console's bus as ``vehicle-NAME`` with ``password``."""
    endpoint = srv.http.get("/api/v1/health").json()["bus"]["endpoints"][0]
    config = client_config(connect=[endpoint], user=f"vehicle-{name}", password=password)
    return open_session(config)


def test_the_pilot_token_does_not_open_the_bus_as_a_vehicle(srv: Served) -> None:
    """Finding 5 was a pilot connection posing as a vehicle: neither token is a vehicle's
    password on the bus, and a garbage one neither."""
    for token in (PILOT, OBSERVER, "uavk_" + "x" * 43):
        with pytest.raises(BusConfigError):
            vehicle_session(srv, "uav1", token).close()  # type: ignore[no-untyped-call]


def test_a_vehicle_key_shows_only_its_own_drones_topics(srv: Served) -> None:
    """uav1's key on the bus: another drone's keys reach nobody (the router's access control),
    a topic that is not its own is not shown (the console), and its own reply and alarm are
    said only as uav1's words, whatever drone they name (the console's relay)."""
    reply = {"text": FAKE, "level": "alert", "speak": True, "drone": "uav1"}
    session = vehicle_session(srv, "uav1", key_of(srv, "uav1"))
    with client(rosbridge(srv), OBSERVER) as obs:
        obs.send({"op": "subscribe", "topic": "/console/reply", "type": "uav_console/Reply"})
        obs.send({"op": "subscribe", "topic": "/uav2/ardrone/navdata"})
        obs.send({"op": "subscribe", "topic": "/rosout"})  # the console's log lines
        obs.call("/rosapi/topics")

        def put(drone: str, topic: str, msg: dict[str, Any]) -> None:
            session.put(keys.graph("default", drone, topic), json.dumps(msg))

        def logged(text: str) -> list[str]:
            lines = [str(f["msg"]["msg"]) for f in list(obs.frames) if f.get("topic") == "/rosout"]
            return [line for line in lines if text in line]

        try:
            # another drone's: refused by the router, heard by nobody
            put("uav2", "/uav2/vehicle/reply", {**reply, "drone": "uav2"})
            put("uav2", "/uav2/ardrone/navdata", {"batteryPercent": 2.0})
            put("uav2", "/uav2/vehicle/alarm", {"data": "{}"})
            # under its own name but not its own topic: not shown
            put("uav1", "/console/reply", reply)
            put("uav1", "/uav1/cmd_vel", JOG)
            wait_for(lambda: logged("uav1: its topic /console/reply is not shown here"), "log")
            # its own reply topic: re-published only as its own drone's words
            put("uav1", "/uav1/vehicle/reply", {**reply, "drone": "uav2"})
            wait_for(
                lambda: logged("uav1: reply from its vehicle not re-published: it names drone"),
                "the relay's refusal in the log",
            )
            mine = {**reply, "text": "uav1 speaking for itself", "drone": ""}
            put("uav1", "/uav1/vehicle/reply", mine)
            said = wait_for(
                lambda: [m for m in obs.replies() if "for itself" in m["text"]], "relay"
            )
            assert said[0]["drone"] == "uav1"
            # its own alarm topic: said by the console's dialog for uav1, whatever it names
            alarm = {"drone": "uav2", "monitor": "link", "severity": "warn",
                     "text": "uav1 alarmed for itself", "action": None}  # fmt: skip
            put("uav1", "/uav1/vehicle/alarm", {"data": json.dumps(alarm)})
            said = wait_for(
                lambda: [m for m in obs.replies() if "alarmed for" in m["text"]], "alarm"
            )
            assert said[0]["drone"] == "uav1" and said[0]["alarm"] == "link"
            obs.call("/rosapi/topics")
            assert not [m for m in obs.replies() if FAKE in m["text"]]
            assert not [f for f in list(obs.frames) if f.get("topic") == "/uav2/ardrone/navdata"
                        and f["msg"].get("batteryPercent") == 2.0]  # fmt: skip
            assert not truth(srv, "uav1")["flying"]  # its own cmd_vel is a console's to send
        finally:
            session.close()  # type: ignore[no-untyped-call]


def test_every_door_judges_a_pilot_without_the_lease_alike(srv: Served) -> None:
    """rosbridge (topics, utterances, services), REST (actions, commands, the patrol, faults):
    a pilot who does not hold the lease may land, hover and stop, and nothing else."""
    with (
        client(rosbridge(srv), PILOT) as holder,
        client(rosbridge(srv), PILOT) as other,
        no_lease_http(srv) as rest,
    ):
        assert holder.call("/console/lease", {"action": "acquire"})["values"]["held_by_me"]
        lease = "holds the pilot lease"
        # rosbridge topics: the jog and a take-off need the lease; land and a zero twist do not
        jog = other.errors_of({"op": "publish", "topic": "/uav1/cmd_vel", "msg": JOG})
        assert jog and lease in jog[0], jog
        takeoff = other.errors_of({"op": "publish", "topic": "/uav1/ardrone/takeoff", "msg": {}})
        assert takeoff and lease in takeoff[0], takeoff
        assert not other.errors_of({"op": "publish", "topic": "/uav1/cmd_vel", "msg": ZERO})
        assert not other.errors_of({"op": "publish", "topic": "/uav1/ardrone/land", "msg": {}})
        # rosbridge utterances: judged by what they ask, as POST /command
        utt = {"op": "publish", "topic": "/console/utterance"}
        move = other.errors_of({**utt, "msg": {"text": "uav1 move forward 1 meter"}})
        assert move and lease in move[0], move
        for text in ("uav1 land", "uav1 hover"):
            assert not other.errors_of({**utt, "msg": {"text": text, "drone": "uav1"}}), text
        # rosbridge services: the patrol and a vehicle's control service need the lease
        out = other.call("/fleet/patrol", {"op": "start"})
        assert out["result"] is False and lease in out["values"], out
        out = other.call("/uav1/vehicle/control", {"op": "direct", "action": "takeoff"})
        assert out["result"] is False and lease in out["values"], out
        # REST
        assert rest.post("/api/v1/drones/uav1/takeoff").status_code == 409
        r = rest.post("/api/v1/command", json={"text": "move forward 1 meter", "drone": "uav1"})
        assert r.status_code == 409, r.text
        assert rest.post("/api/v1/patrol").status_code == 409
        assert rest.post("/api/v1/sim/uav1/fault", json={"kind": "link_loss"}).status_code == 409
        for action in ("land", "hover"):
            r = rest.post(f"/api/v1/drones/uav1/{action}")
            assert r.status_code == 200, (action, r.text)
        r = rest.post("/api/v1/command", json={"text": "land", "drone": "uav1"})
        assert r.status_code == 200, r.text
        r = rest.post("/api/v1/drones/uav2/emergency")
        assert r.status_code == 200 and r.json()["accepted"], r.text
        wait_for(lambda: truth(srv, "uav2")["emergency"], "uav2's emergency state")
        # and the holder still holds it: nothing above took it
        assert holder.call("/console/lease", {"action": "status"})["values"]["held_by_me"]
