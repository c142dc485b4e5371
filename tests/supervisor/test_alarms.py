"""The supervisor's alarms as they travel: typed, JSON on ``/NAME/vehicle/alarm``, which a
vehicle's link shares with the console (and its flight recording)."""

from __future__ import annotations

import asyncio
import json
from collections.abc import Callable
from typing import Any

import httpx

from drone.supervisor import ActionKind, Alarm, AlarmAction, Severity
from server.vehicles import names
from server.vehicles.host import shared_topics
from tests.app_client import app_fixture


def test_an_alarm_says_its_monitor_severity_text_and_the_command_it_ran() -> None:
    a = Alarm(
        "altitude", Severity.WARN, "Descending.", AlarmAction(ActionKind.DESCEND, distance_m=0.4)
    )
    assert json.loads(json.dumps(a.as_message("uav2"))) == {
        "drone": "uav2",
        "monitor": "altitude",
        "severity": "warn",
        "text": "Descending.",
        "action": {"action": "move", "direction": "down", "distance": 0.4},
    }
    away = AlarmAction(ActionKind.BACK_OFF, to=(1.0, 2.0, 1.5))
    assert away.command() == {"action": "waypoints", "waypoints": [{"x": 1.0, "y": 2.0, "z": 1.5}]}
    assert (away.event, AlarmAction(ActionKind.LAND).event) == ("move", "land")
    assert Alarm("link", Severity.ALERT, "Lost.").as_message()["action"] is None


def test_a_vehicle_shares_its_alarms_with_the_console() -> None:
    out = {t.name: t.type for t in shared_topics("uav3", "/uav3")}
    assert out[names.alarm_topic("uav3")] == names.STRING
    assert names.alarm_topic("uav3") == "/uav3/vehicle/alarm"


api = app_fixture("alarm-pilot", "alarm-observer")


async def wait_for(client: httpx.AsyncClient, path: str, pred: Callable[[Any], bool]) -> None:
    """Poll ``path`` until ``pred`` holds (the simulator runs in real time here)."""
    for _ in range(600):
        if pred((await client.get(path)).json()):
            return
        await asyncio.sleep(0.05)
    raise AssertionError(f"{path} never satisfied the condition")


async def test_an_inline_drones_supervisor_publishes_and_its_dialog_speaks(
    api: httpx.AsyncClient,
) -> None:
    """A link loss (sim fault) in a console with an inline drone: the supervisor's link alarm on
    ``/uav1/vehicle/alarm`` and the dialog's reply naming the monitor, then the all-clear."""
    runtime = api.app.state.runtime  # type: ignore[attr-defined]
    alarms: list[dict[str, object]] = []
    replies: list[dict[str, object]] = []
    runtime.graph.subscribe(
        names.alarm_topic("uav1"), lambda m: alarms.append(json.loads(m["data"]))
    )
    runtime.graph.subscribe("/console/reply", replies.append)
    await wait_for(api, "/api/v1/drones/uav1", lambda d: d["link_ok"])
    r = await api.post("/api/v1/sim/uav1/fault", json={"kind": "link_loss", "duration_s": 3.0})
    assert r.status_code == 200
    await wait_for(api, "/api/v1/drones/uav1", lambda d: not d["link_ok"])
    await wait_for(api, "/api/v1/drones/uav1", lambda d: d["link_ok"])
    for _ in range(100):  # the monitor's next period after the link is back
        if any(a["severity"] == "info" for a in alarms):
            break
        await asyncio.sleep(0.05)
    assert [(a["monitor"], a["severity"]) for a in alarms] == [("link", "alert"), ("link", "info")]
    # the drone is on the ground: nothing to hover (in flight: "It will hover on its own.")
    assert alarms[0]["text"] == "I lost the link to the drone. It was on the ground."
    spoken = [m for m in replies if m.get("alarm") == "link"]
    assert [m["text"] for m in spoken] == [a["text"] for a in alarms]
