"""The grace of a drone on a plan: with no console holding the central role (the only one was
``kill -9``-ed), a vehicle on a patrol plan keeps flying the patrol (its watch of the console
does not hover it), then after ``central_grace_s`` flies home and lands at its station.

The bus outlives the console: the test runs a router of its own (a ``zenohd`` stand-in, with the
fleet's credentials and access control), joined to the console's; the vehicle fails over to it,
and the test watches the vehicle's telemetry and LTM status there."""

from __future__ import annotations

import contextlib
import json
import math
import os
import signal
import threading
import time
from pathlib import Path
from typing import Any

import pytest

from drone.bus.config import CONSOLE_USER, access_control, router_config
from drone.bus.credentials import Credentials
from server.cli import main as cli_main
from server.fleet.continuity import CoverageTracker
from server.fleet.geo import Enu
from tests.failover.test_failover import central_of, serve, vehicle
from tests.isolation.conftest import wait_for
from tests.support.loopback import free_port

# serial: real consoles and vehicles on wall-clock deadlines, which a second test run on the
# same 2 cores made them miss
pytestmark = [pytest.mark.slow, pytest.mark.serial, pytest.mark.timeout(600)]

# The console and the vehicle on a clock three times as fast as the wall clock
# (server/timewarp.py): the flights to the route and home take a third of the wall time (14.5 s
# a run against 21 s at 2). The grace is the LTM's, in clock seconds (judged so); the console's
# watch of its link (hover after 1 s) is in wall seconds.
CLOCK_SPEED = 3.0
GRACE_S = 16.0  # UAVC_CENTRAL_GRACE_S for the vehicle (60 s by default), in clock seconds
GRACE_WALL_S = GRACE_S / CLOCK_SPEED  # the same grace on the wall clock (the stamps')
STATION = Enu(1.0, 3.0, 0.0)  # worlds/indoor.yaml: home1, uav1's pad


class SiteRouter:
    """A Zenoh router in the test process with the fleet's credentials (as ``zenohd`` would
    run), joined to ``connect``; it watches the fleet's telemetry and LTM statuses."""

    def __init__(self, bus_dir: Path, listen: str, connect: list[str]) -> None:
        import zenoh

        creds = Credentials.load_or_create(bus_dir, [])
        config = router_config(
            listen=[listen],
            connect=connect,
            password=creds.password(CONSOLE_USER),
            dictionary_file=str(creds.path),
            acl=access_control("default", creds.vehicles()),
        )
        self.lock = threading.Lock()
        self.telemetry: list[dict[str, Any]] = []
        self.ltm: list[dict[str, Any]] = []
        self.session = zenoh.open(zenoh.Config.from_json5(json.dumps(config)))
        self.subs = [
            self.session.declare_subscriber("uavc/default/*/telemetry", self._on(self.telemetry)),
            self.session.declare_subscriber("uavc/default/*/ltm", self._on(self.ltm)),
        ]

    def _on(self, into: list[dict[str, Any]]) -> Any:
        def on(sample: Any) -> None:
            obj = json.loads(sample.payload.to_string())
            obj["_rx"] = time.time()
            with self.lock:
                into.append(obj)

        return on

    def close(self) -> None:
        for s in self.subs:
            s.undeclare()
        self.session.close()


def test_a_drone_on_a_plan_flies_on_for_the_grace_then_home(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    assert cli_main(["vehicle-key", "uav1", "--data-dir", str(tmp_path / "data")]) == 0
    bus_a, bus_t = f"tcp/127.0.0.1:{free_port()}", f"tcp/127.0.0.1:{free_port()}"
    extra = ("--vehicles", "process", "--fleet", "0", "--bus-listen", bus_a)
    grace_env = {"UAVC_CENTRAL_GRACE_S": str(GRACE_S)}
    monkeypatch.setenv("UAVC_CLOCK_SPEED", f"{CLOCK_SPEED:g}")  # for every process started here
    with contextlib.ExitStack() as stack:
        # the vehicle starts while the console takes the central role (it joins the bus, which
        # the console opens before it answers; the site router needs the fleet's credentials)
        a = stack.enter_context(serve(tmp_path, "console-a", extra))
        stack.enter_context(vehicle(tmp_path, "uav1", 0, [bus_a, bus_t], grace_env))
        router = SiteRouter(tmp_path / "data" / "bus", bus_t, [bus_a])
        stack.callback(router.close)
        wait_for(lambda: central_of(a)["role"] == "central", "console-a central", 30)
        wait_for(lambda: central_of(a)["on_bus"] == ["uav1"], "uav1's LTM on the bus", 90)
        r = a.http.post("/api/v1/patrol", json={})
        assert r.status_code == 200, r.text
        patrol = wait_for(
            lambda: (p := a.http.get("/api/v1/patrol").json())["state"] == "running" and p,
            "the patrol running",
            90,
        )
        route = tuple(
            Enu(w["x"], w["y"], w["z"]) for w in patrol["mission"]["coverage"]["waypoints"]
        )

        def visited() -> int:
            wps = a.http.get("/api/v1/patrol").json()["mission"]["coverage"]["waypoints"]
            return sum(w["visits"] >= 1 for w in wps)

        # on the route: it has flown from one waypoint to the next
        wait_for(lambda: visited() >= 2, "two waypoints visited", 120, period=0.5)
        killed = time.time()
        os.kill(a.proc.pid, signal.SIGKILL)
        a.proc.wait()

        def landed() -> dict[str, Any] | None:
            with router.lock:
                late = [t for t in router.telemetry if t["stamp"] > killed + GRACE_WALL_S]
            return late[-1] if late and not late[-1]["flying"] else None

        last = wait_for(landed, "uav1 landed after the grace", GRACE_WALL_S + 90, period=0.5)
        with router.lock:
            tel = [t for t in router.telemetry if t["drone"] == "uav1"]
            ltm = [s for s in router.ltm if s["name"] == "uav1"]
        # it flew the patrol on through the grace: it visited waypoints after the console's
        # watch would have hovered it (1 s), and never stopped flying before the grace was out
        tracker = CoverageTracker(route, killed)
        for t in tel:
            tracker.observe("uav1", Enu(t["x"], t["y"], t["z"]), t["flying"], t["stamp"])
        during = [
            v for vs in tracker.visits for v in vs if killed + 1.5 < v < killed + GRACE_WALL_S
        ]
        assert during, "no waypoint visited during the grace"
        in_grace = [t for t in tel if killed < t["stamp"] < killed + GRACE_WALL_S]
        assert in_grace and all(t["flying"] for t in in_grace)
        # then home, on its own, when the grace was out: the LTM says why
        silent = [s for s in ltm if s["autonomous"] == "ctm_silent"]
        assert silent, "the LTM never went home for the central's silence"
        went_home = (silent[0]["_rx"] - killed) * CLOCK_SPEED  # in the LTM's clock seconds
        print(
            f"grace: went home {went_home:.2f} clock s ({went_home / CLOCK_SPEED:.2f} wall s) "
            f"after the kill (grace {GRACE_S} clock s)"
        )
        assert GRACE_S - 0.5 <= went_home <= GRACE_S + 3.0
        assert math.hypot(last["x"] - STATION.x, last["y"] - STATION.y) < 1.0
