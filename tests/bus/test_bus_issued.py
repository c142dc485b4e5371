"""A typed sentence carries when the operator gave it onto the bus, and the vehicle judges its
deadline again as it receives it: ``serve --fleet 0`` and a ``uav-console vehicle
--bus-connect`` process, for real, on loopback.

The vehicle keeps a stricter deadline (1 s) than its console (10 s), so a sentence given 3 s
ago passes the console's own check and reaches the vehicle late whatever the machine's load:
the vehicle answers ``expired`` and the console says it was not flown. Stops never expire."""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from tests.isolation.conftest import Served, serve, wait_for
from tests.support.loopback import free_port
from tests.support.processes import bus_vehicle, vehicle_key

# serial: a console and a vehicle process on wall-clock deadlines
pytestmark = pytest.mark.serial

NAME = "uav7"
CONSOLE_DEADLINE_S = 10.0
VEHICLE_DEADLINE_S = 1.0
GIVEN_AGO_S = 3.0  # late for the vehicle, in time for the console


@dataclass
class Rig:
    srv: Served
    vehicle_log: Path

    def say(self, text: str, issued: float) -> dict[str, Any]:
        r = self.srv.http.post(
            "/api/v1/command", json={"text": f"{NAME} {text}", "issued": issued}, timeout=30
        )
        assert r.status_code == 200, r.text
        return dict(r.json())

    def flying(self) -> bool:
        return bool(self.srv.drone(NAME)["flying"])

    def vlog(self) -> str:
        return self.vehicle_log.read_text(errors="replace")


@pytest.fixture
def rig(tmp_path: Path) -> Iterator[Rig]:
    key = vehicle_key(tmp_path / "data", NAME)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    extra = ("--fleet", "0", "--bus-listen", endpoint)
    env = {"UAVC_COMMAND_DEADLINE_S": str(CONSOLE_DEADLINE_S)}
    with (
        serve(tmp_path, "sim", extra=extra, env=env, start_s=120) as srv,
        bus_vehicle(
            tmp_path, endpoint, NAME, key, {"UAVC_COMMAND_DEADLINE_S": str(VEHICLE_DEADLINE_S)}
        ) as (_proc, log_path),
    ):
        rig = Rig(srv, log_path)

        def joined() -> bool:
            r = srv.http.get(f"/api/v1/drones/{NAME}")
            return r.status_code == 200 and r.json()["vehicle"]["connected"] and r.json()["link_ok"]

        wait_for(joined, f"{NAME} on the bus and its drone link up", 90)
        yield rig


def test_a_sentence_that_reaches_the_vehicle_late_is_not_flown_and_a_stop_always_is(
    rig: Rig,
) -> None:
    late = rig.say("take off", time.time() - GIVEN_AGO_S)
    assert not late["accepted"], late
    said = f"{NAME}: Not flown: '{NAME} take off' reached the drone"
    assert late["reply"].startswith(said), late
    assert f"(deadline {VEHICLE_DEADLINE_S:g} s)" in late["reply"], late
    # the vehicle refused it itself, before its task executor saw it
    wait_for(lambda: "submit from" in rig.vlog() and "Not flown" in rig.vlog(), "its log", 10)
    assert not rig.flying()

    # the same sentence in time flies: the vehicle could, it only would not fly it late
    now = rig.say("take off", time.time())
    assert now["accepted"], now
    wait_for(rig.flying, "the take-off given in time", 40)

    # a stop never expires, however late it reaches the vehicle
    stop = rig.say("land", time.time() - GIVEN_AGO_S)
    assert stop["accepted"], stop
    wait_for(lambda: not rig.flying(), "the late landing", 40)
