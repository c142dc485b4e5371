"""Vehicles on the bus for real: ``serve --fleet 0`` and a ``uav-console vehicle --bus-connect``
process (another "machine": its own data directory, its simulator inside), flown by REST, text
and rosbridge over the bus; bad parties refused, nothing flies; one lease across two consoles."""

from __future__ import annotations

import base64
import contextlib
import dataclasses
import json
import re
import subprocess
import sys
import textwrap
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from websockets.sync.client import connect as ws_connect

from tests.isolation.conftest import HOST, PILOT, Served, wait_for
from tests.isolation.conftest import serve as serve_quick
from tests.support.loopback import free_port
from tests.support.processes import bus_vehicle, vehicle_key

# serial: real consoles and vehicle processes on wall-clock deadlines (a command 2 s late
# is refused), which a second test run on the same 2 cores made them miss
pytestmark = pytest.mark.serial

NAME = "uav7"
# the shared rig's vehicle lands after this long without its console (20 s by default)
LAND_AFTER = {"UAVC_CENTRAL_LOSS_LAND_S": "4"}


@dataclass
class Rig:
    srv: Served
    endpoint: str
    data: Path
    vehicle: subprocess.Popen[bytes]
    vehicle_log: Path
    log_from: int = 0  # the vehicle's log as one test sees it: from this byte on

    def wait_joined(self, srv: Served | None = None) -> dict[str, Any]:
        srv = srv or self.srv

        seen: list[str] = []

        def joined() -> dict[str, Any] | None:
            r = srv.http.get(f"/api/v1/drones/{NAME}")
            seen.append(f"{r.status_code} {r.text[:300]}")
            ok = r.status_code == 200 and r.json()["vehicle"]["connected"] and r.json()["link_ok"]
            return dict(r.json()) if ok else None

        try:
            return dict(wait_for(joined, f"{NAME} on the bus and its drone link up", 90))
        except AssertionError as exc:
            raise AssertionError(f"{exc}; last answer: {seen[-1:]}") from None

    def flying(self, srv: Served | None = None) -> bool:
        return bool((srv or self.srv).drone(NAME)["flying"])

    def act(self, action: str, srv: Served | None = None) -> dict[str, Any]:
        r = (srv or self.srv).http.post(f"/api/v1/drones/{NAME}/{action}", timeout=30)
        r.raise_for_status()
        return dict(r.json())

    def vlog(self) -> str:
        return self.vehicle_log.read_bytes()[self.log_from :].decode(errors="replace")


@contextlib.contextmanager
def serve(
    tmp: Path, drone: str, *, extra: tuple[str, ...], port: int | None = None
) -> Iterator[Served]:
    """``serve`` (tests/isolation), given as long as a busy machine needs to start it."""
    with serve_quick(tmp, drone, extra=extra, port=port, start_s=120) as srv:
        yield srv


@pytest.fixture(scope="module")
def shared_rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Rig]:
    """One console and one bus vehicle for the module's tests that fly it and land it again
    (a console and a vehicle process start in seconds of CPU each)."""
    tmp = tmp_path_factory.mktemp("rig")
    data = tmp / "data"
    key = vehicle_key(data, NAME)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    extra = ("--fleet", "0", "--bus-listen", endpoint)
    with (
        serve(tmp, "sim", extra=extra) as srv,
        bus_vehicle(tmp, endpoint, NAME, key, LAND_AFTER) as (proc, log_path),
    ):
        yield Rig(srv, endpoint, data, proc, log_path)


@pytest.fixture
def rig(shared_rig: Rig) -> Rig:
    """The module's rig for one test: its drone on the ground (landed if a test before left it
    flying), the vehicle's log read from this test's start."""
    shared_rig.wait_joined()
    if shared_rig.flying():
        shared_rig.act("land")
        wait_for(lambda: not shared_rig.flying(), "the rig's drone landed", 40)
    assert shared_rig.vehicle.poll() is None, shared_rig.vlog()
    return dataclasses.replace(shared_rig, log_from=shared_rig.vehicle_log.stat().st_size)


def run_script(script: str, *args: str) -> dict[str, Any]:
    out = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(script), *args],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 0, out.stderr
    return dict(json.loads(out.stdout.strip().splitlines()[-1]))


# A third party's query on a drone's cmd key, with only a client file (docs/bus.md).
QUERY = """
    import json, sys, zenoh
    conf = zenoh.Config.from_file(sys.argv[1])
    with zenoh.open(conf) as session:
        replies = list(session.get(sys.argv[2], payload=sys.argv[3].encode(), timeout=5))
        out = [json.loads(r.ok.payload.to_string()) for r in replies if r.ok is not None]
        print(json.dumps({"replies": out}))
"""


def command(op: str, **args: Any) -> str:
    body = {"v": 1, "id": "script-1", "op": op, "args": args, "issued": time.time()}
    return json.dumps({**body, "console": "script", "pilot": "me"})


class Ros:
    """A pilot's rosbridge client (what a third-party ROS tool or the page speaks)."""

    def __init__(self, ws: Any) -> None:
        self.ws = ws
        self.n = 0
        self.seen: dict[str, list[dict[str, Any]]] = {}

    def _recv(self) -> dict[str, Any]:
        frame = dict(json.loads(self.ws.recv(timeout=10)))
        if frame.get("op") == "publish":
            self.seen.setdefault(str(frame["topic"]), []).append(frame["msg"])
        return frame

    def subscribe(self, topic: str, typ: str) -> None:
        self.ws.send(json.dumps({"op": "subscribe", "topic": topic, "type": typ}))

    def wait_topic(
        self, topic: str, what: str, pred: Callable[[list[dict[str, Any]]], bool] = bool
    ) -> list[dict[str, Any]]:
        deadline = time.monotonic() + 30
        while not pred(self.seen.get(topic, [])):
            assert time.monotonic() < deadline, f"{what}: not on {topic} ({self.seen.get(topic)})"
            self._recv()
        return self.seen[topic]

    def call(self, service: str, args: dict[str, Any]) -> dict[str, Any]:
        self.n += 1
        cid = f"c{self.n}"
        self.ws.send(
            json.dumps({"op": "call_service", "id": cid, "service": service, "args": args})
        )
        while True:
            frame = self._recv()
            if frame.get("op") == "service_response" and frame.get("id") == cid:
                return frame

    def publish(self, topic: str, msg: dict[str, Any]) -> None:
        self.ws.send(json.dumps({"op": "publish", "topic": topic, "msg": msg}))
        self.call("/rosapi/get_time", {})  # handled in order: the publish is through


def test_a_bus_vehicle_flies_by_rest_text_and_rosbridge(rig: Rig) -> None:
    drone = rig.wait_joined()
    assert drone["name"] == NAME and drone["vehicle"]["mode"] == "process"
    took = rig.act("takeoff")
    assert took["accepted"], took
    wait_for(lambda: rig.flying(), "the REST take-off", 40)
    landed = rig.act("land")
    assert landed["accepted"], landed
    wait_for(lambda: not rig.flying(), "the REST landing", 40)

    r = rig.srv.http.post("/api/v1/command", json={"text": f"{NAME} take off"}, timeout=30)
    assert r.status_code == 200 and r.json()["accepted"], r.text
    wait_for(lambda: rig.flying(), "the typed take-off", 40)

    with ws_connect(rig.srv.ws, open_timeout=10) as ws:
        ros = Ros(ws)
        lease = ros.call("/console/lease", {"action": "acquire"})
        assert lease["result"], lease
        # the vehicle's graph and camera, shown on the console's over the bus
        ros.subscribe(f"/{NAME}/ardrone/navdata", "ardrone_autonomy/Navdata")
        ros.subscribe(f"/{NAME}/ardrone/image_raw/compressed", "sensor_msgs/CompressedImage")
        ros.subscribe("/console/reply", "uav_console/Reply")
        ros.wait_topic(f"/{NAME}/ardrone/navdata", "navdata", lambda seen: len(seen) >= 3)
        [image, *_] = ros.wait_topic(f"/{NAME}/ardrone/image_raw/compressed", "the camera")
        assert image["format"] == "jpeg"
        assert base64.b64decode(image["data"], validate=True).startswith(b"\xff\xd8")  # a JPEG
        # a sentence typed in a page (rosbridge): the vehicle's dialog hears and answers it
        ros.publish("/console/utterance", {"text": f"{NAME} go up 0.3 meters", "source": "text"})
        ros.wait_topic(
            "/console/reply",
            "the vehicle's spoken reply",
            lambda seen: any("Climbing" in r["text"] for r in seen),
        )
        ros.publish(f"/{NAME}/ardrone/land", {})
        wait_for(lambda: not rig.flying(), "the rosbridge landing", 40)
        ros.publish(f"/{NAME}/ardrone/takeoff", {})
        wait_for(lambda: rig.flying(), "the rosbridge take-off", 40)
        ros.publish(f"/{NAME}/ardrone/land", {})
        wait_for(lambda: not rig.flying(), "the rosbridge landing", 40)
    assert "accepted" not in rig.vlog() or "refused" not in rig.vlog()
    status = rig.srv.drone(NAME)
    assert status["vehicle"]["connected"]


def test_bad_parties_are_refused_and_nothing_flies(rig: Rig) -> None:
    rig.wait_joined()
    bus = rig.data / "bus"
    key = f"uavc/default/{NAME}/cmd"
    # an observer's command: the router refuses the query, no vehicle hears it
    watched = run_script(QUERY, str(bus / "client.json5"), key, command("direct", action="takeoff"))
    assert watched["replies"] == []
    # a pilot's malformed command: refused by the vehicle with the reason, said in its log
    bad = run_script(QUERY, str(bus / "pilot.json5"), key, command("direct", action="loop"))
    [reply] = bad["replies"]
    assert not reply["accepted"] and reply["id"] == "script-1"
    assert reply["reason"].startswith("malformed command: command args.action: 'loop'")
    wait_for(lambda: "refused: malformed command" in rig.vlog(), "the refusal in the log", 10)
    # an unknown vehicle: nobody answers on the bus, REST says 404
    nobody = run_script(
        QUERY, str(bus / "pilot.json5"), "uavc/default/uav9/cmd", command("telemetry")
    )
    assert nobody["replies"] == []
    assert rig.srv.http.post("/api/v1/drones/uav9/takeoff").status_code == 404
    time.sleep(1.0)  # anything that would fly has had its chance: still on the ground
    assert not rig.flying()


SPOOF = """
    import json, sys, time, zenoh
    conf = {"mode": "client", "connect": {"endpoints": [sys.argv[1]]},
            "scouting": {"multicast": {"enabled": False}},
            "transport": {"auth": {"usrpwd": {"user": "vehicle-uav7", "password": sys.argv[2]}}}}
    with zenoh.open(zenoh.Config.from_json5(json.dumps(conf))) as session:
        token = session.liveliness().declare_token("uavc/default/uav8/alive")
        t = {"v": 1, "drone": "uav8", "stamp": time.time(), "x": 0, "y": 0, "z": 1,
             "yaw_deg": 0, "battery_pct": 50, "state": "FLYING"}
        for _ in range(30):
            session.put("uavc/default/uav8/telemetry", json.dumps(t))
            time.sleep(0.1)
        print(json.dumps({"done": True}))
"""


def test_a_vehicle_publishing_under_another_name_reaches_nobody(rig: Rig) -> None:
    rig.wait_joined()
    key = vehicle_key(rig.data, NAME)
    assert run_script(SPOOF, rig.endpoint, key)["done"]
    names = [d["name"] for d in rig.srv.http.get("/api/v1/drones").json()]
    assert names == [NAME]
    assert rig.srv.http.get("/api/v1/health").json()["bus"]["alive"] == [NAME]


def test_one_lease_across_two_consoles(tmp_path: Path) -> None:
    """Two ``serve`` processes on one bus (the second joins the first's router): the console
    whose pilot flies first holds the vehicle's lease; the other's motion is refused by the
    vehicle, its land, hover and emergency are not."""
    data = tmp_path / "data"
    key = vehicle_key(data, NAME)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    west_extra = ("--fleet", "0", "--bus-listen", endpoint)
    east_extra = ("--fleet", "0", "--bus-listen", f"tcp/127.0.0.1:{free_port()}")
    east_extra += ("--bus-connect", endpoint)
    with (
        serve(tmp_path, "sim", extra=west_extra) as west,
        serve(tmp_path, "sim", extra=east_extra, port=free_port(HOST)) as east,
        bus_vehicle(tmp_path, endpoint, NAME, key) as (proc, log_path),
    ):
        rig = Rig(west, endpoint, data, proc, log_path)
        rig.wait_joined(west)
        rig.wait_joined(east)
        assert rig.act("takeoff", west)["accepted"]
        wait_for(lambda: rig.flying(west), "west's take-off", 40)
        refused = rig.act("takeoff", east)
        assert not refused["accepted"] and "pilot lease is held by pilot@" in refused["detail"]
        # east's dialog checks a sentence against the drone's bus telemetry and follows a
        # take-off it did not make within its reconcile period: until it has, it refuses a
        # motion itself ("I need to take off first"), sending nothing
        wait_for(lambda: rig.flying(east), "east sees it flying", 20)

        def typed_motion() -> Any:
            r = east.http.post("/api/v1/command", json={"text": f"{NAME} go up one metre"})
            return None if "take off first" in r.text else r

        typed = wait_for(typed_motion, "east's dialog following the take-off", 10)
        assert typed.status_code == 200 and not typed.json()["accepted"], typed.text
        assert "lease" in typed.json()["reply"]
        hover = rig.act("hover", east)
        assert hover["accepted"], hover
        land = rig.act("land", east)
        assert land["accepted"], land
        wait_for(lambda: not rig.flying(west), "east's landing", 40)
        assert "takeoff from pilot@" in log_path.read_text()  # the refusal, in the vehicle's log
    assert PILOT


@pytest.mark.timeout(480)
def test_a_console_started_first_joins_the_one_it_names_when_that_one_comes(
    tmp_path: Path,
) -> None:
    """``serve --bus-connect`` before the console it joins is up: it says it will join it,
    keeps dialling, and joins when it comes; the consoles share the bus credentials with
    ``--bus-credentials`` (each has its own data directory); the vehicle on the second console
    is seen and flown from the first."""
    east_data, west_data = tmp_path / "east", tmp_path / "west"
    key = vehicle_key(west_data, NAME)
    west_bus, east_bus = f"tcp/127.0.0.1:{free_port()}", f"tcp/127.0.0.1:{free_port()}"
    east_extra = ("--fleet", "0", "--console-name", "east", "--bus-listen", east_bus)
    east_extra += ("--bus-connect", west_bus)
    credentials = east_data / "bus" / "credentials.txt"
    west_extra = ("--fleet", "0", "--console-name", "west", "--bus-listen", west_bus)
    west_extra += ("--bus-credentials", str(credentials))
    with serve_quick(
        tmp_path, "sim", extra=east_extra, env={"UAVC_DATA_DIR": str(east_data)}, start_s=120
    ) as east:
        [join] = east.http.get("/api/v1/health").json()["bus"]["joins"]
        assert join["endpoint"] == west_bus and not join["joined"]
        said = f"uav-console: bus: the router at {west_bus} is not up; joining it when it is"
        wait_for(lambda: said in east.log(), "east says it will join", 20)
        with (
            serve_quick(
                tmp_path,
                "sim",
                extra=west_extra,
                env={"UAVC_DATA_DIR": str(west_data)},
                port=free_port(HOST),
                start_s=120,
            ) as west,
            bus_vehicle(tmp_path, west_bus, NAME, key) as (proc, log_path),
        ):
            rig = Rig(west, west_bus, west_data, proc, log_path)
            wait_for(
                lambda: east.http.get("/api/v1/health").json()["bus"]["joins"][0]["joined"],
                "east joined west's router",
                60,
            )
            assert f"uav-console: bus: joined the router at {west_bus}" in east.log()
            rig.wait_joined(east)
            assert rig.act("takeoff", east)["accepted"]
            wait_for(lambda: rig.flying(west), "the take-off from east, seen at west", 40)
            assert rig.act("land", east)["accepted"]
            wait_for(lambda: not rig.flying(east), "the landing", 40)


def test_a_vehicle_needs_a_bus(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    from server.cli import main as cli_main

    monkeypatch.delenv("UAVC_BUS_CONNECT", raising=False)
    assert cli_main(["vehicle", "--name", NAME]) == 2
    assert "--bus-connect ENDPOINT is needed" in capsys.readouterr().err
    # no rosbridge central is a way in: one line saying what joins a console instead
    for central in (
        ["--central", "ws://console.invalid/rosbridge"],
        ["--central=wss://console.invalid:8000/rosbridge"],
        ["--central", "ws://console.invalid/vehicle-link"],
    ):
        assert cli_main(["vehicle", "--name", NAME, *central]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "--bus-connect ENDPOINT" in err and "not --central" in err
    # the installed command says the same (python -m server: the same entry point)
    argv = [sys.executable, "-m", "server", "vehicle", "--central", "ws://h/rosbridge"]
    out = subprocess.run(argv, capture_output=True, text=True, timeout=60, check=False)
    assert out.returncode == 2 and out.stderr.count("\n") == 1, out.stderr
    assert "--bus-connect ENDPOINT" in out.stderr and not out.stdout


def test_a_bus_vehicle_hovers_then_lands_when_its_console_stalls(rig: Rig) -> None:
    """Its console's heartbeat stops (``serve`` stopped, SIGSTOP): the vehicle on the bus hovers
    after ``heartbeat_timeout_s`` and lands after ``central_loss_land_s``, on its own."""
    srv = rig.srv
    assert rig.act("takeoff")["accepted"]
    wait_for(lambda: rig.flying(), "the take-off", 40)
    srv.pause()
    try:
        wait_for(lambda: re.search(r"silent for [\d.]+ s: land", rig.vlog()), "the land", 30)
        assert re.search(r"silent for [\d.]+ s: hover", rig.vlog())
    finally:
        srv.resume()
    wait_for(lambda: not rig.flying(), "the drone on the ground", 40)
    assert srv.drone(NAME)["central_loss"]["actions"][-2:] == ["hover", "land"]
