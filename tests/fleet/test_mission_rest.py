"""Mission state through the whole server (issue 26 finding 7): two simulated drones behind the
AR.Drone protocol on loopback addresses of their own, the Central patrol started by REST, the
patrolling drone landed by the page's Land (``POST /drones/{id}/land``), the mission read back,
resumed by voice (``POST /command`` "resume the patrol") and ended by voice, in real time."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Awaitable, Callable
from typing import Any

import httpx
import pytest

from tests.app_client import app_fixture

PILOT = "pilot-token-missions"
OBSERVER = "observer-token-missions"

api = app_fixture(PILOT, OBSERVER, fleet=2)


async def wait_for_async(
    get: Callable[[], Awaitable[Any]], pred: Callable[[Any], bool], timeout: float, what: str
) -> Any:
    """``await get()`` every 100 ms until ``pred`` holds for it (returned); fails naming
    ``what`` (``tests.support.polling.wait_for`` for a server in this event loop)."""
    deadline = time.monotonic() + timeout
    last: Any = None
    while time.monotonic() < deadline:
        last = await get()
        if pred(last):
            return last
        await asyncio.sleep(0.1)
    raise AssertionError(f"{what}: condition not met in {timeout} s; last: {last!r}")


async def _patrol(api: httpx.AsyncClient) -> dict[str, Any]:
    r = await api.get("/api/v1/patrol")
    assert r.status_code == 200, r.text
    return dict(r.json())


async def _say(api: httpx.AsyncClient, text: str, drone: str = "uav1") -> str:
    r = await api.post("/api/v1/command", json={"text": text, "drone": drone})
    assert r.status_code == 200, r.text
    return str(r.json()["reply"])


@pytest.mark.timeout(150)
async def test_land_pauses_then_resume_and_end(api: httpx.AsyncClient) -> None:
    await wait_for_async(
        lambda: _patrol(api),
        lambda b: len(b["drones"]) == 2 and all(d["role"] == "idle" for d in b["drones"]),
        20.0,
        "both drones joined and idle",
    )
    start = await api.post("/api/v1/patrol")
    assert start.status_code == 200, start.text
    body = await wait_for_async(
        lambda: _patrol(api),
        lambda b: b["state"] == "running",
        45.0,
        "a drone patrolling",
    )
    mid = body["mission"]["id"]
    active = body["mission"]["active"]
    assert body["running"] and body["mission"]["detail"] == f"running: {active} patrolling"
    # a resume while running is refused by the state table, with the reason
    bad = await api.post(f"/api/v1/missions/{mid}", json={"action": "resume"})
    assert bad.status_code == 409 and "cannot resume while running" in bad.json()["detail"]

    land = await api.post(f"/api/v1/drones/{active}/land")  # the page's Land button
    assert land.status_code == 200, land.text
    body = await wait_for_async(
        lambda: _patrol(api), lambda b: b["state"] == "paused", 5.0, "the mission paused"
    )
    m = body["mission"]
    assert not body["running"] and m["state"] == "paused"
    assert m["detail"] == "paused by the operator (land)"
    # its role now: paused, unless a navdata gap on a loaded machine has it lost for a moment
    # (the fleet's loss rule); what it was and what the operator did stay
    (d,) = m["drones"]
    assert (d["name"], d["was"], d["operator"]) == (active, "patrolling", "land")
    assert d["role"] in ("paused", "lost"), d
    roles = {d["name"]: d["role"] for d in body["drones"]}
    assert "patrolling" not in roles.values()
    same = (await api.get(f"/api/v1/missions/{mid}")).json()
    assert same["state"] == "paused" and same["detail"] == m["detail"]
    # the Start button on a paused patrol says what to do instead
    again = await api.post("/api/v1/patrol")
    assert again.status_code == 409
    assert again.json()["detail"] == (
        "The patrol is paused by the operator (land); resume the patrol or end the patrol."
    )

    reply = await _say(api, "resume the patrol")
    assert reply == "Resuming the patrol; the first drone ready flies to the route."
    body = await wait_for_async(
        lambda: _patrol(api), lambda b: b["state"] == "running", 45.0, "patrolling again"
    )
    assert body["mission"]["id"] == mid  # the same mission, not a new one
    nothing = await api.post("/api/v1/patrol", json={"action": "resume"})
    assert nothing.status_code == 409 and nothing.json()["detail"] == "The patrol is not paused."

    reply = await _say(api, "end the patrol")
    assert reply == "Stopping the patrol; the drones are flying home."
    body = await _patrol(api)
    assert body["state"] == "none" and body["mission"] is None and not body["running"]
    ended = (await api.get(f"/api/v1/missions/{mid}")).json()
    assert ended["state"] == "ended" and ended["detail"] == "ended by the operator"
    gone = await api.post(f"/api/v1/missions/{mid}", json={"action": "resume"})
    assert gone.status_code == 409 and "while ended" in gone.json()["detail"]
    # everyone lands again
    await api.post("/api/v1/drones/uav1/land")
    await api.post("/api/v1/drones/uav2/land")


async def test_missions_take_the_handoff_rule(api: httpx.AsyncClient) -> None:
    route = {"markers": [1, 4], "altitude_m": 1.4, "handoff": "reactive", "name": "paper"}
    made = await api.post("/api/v1/missions", json=route)
    assert made.status_code == 201, made.text
    assert made.json()["handoff"] == "reactive" and made.json()["state"] == "waiting"
    bad = await api.post("/api/v1/missions", json=route | {"handoff": "sideways", "name": "x"})
    assert bad.status_code == 422 and "handoff" in bad.text
    plain = await api.post("/api/v1/missions", json=route | {"name": "ours"} | {"handoff": None})
    assert plain.status_code == 422  # null is not a rule; leave it out for the default
    default = {k: v for k, v in route.items() if k != "handoff"} | {"name": "ours"}
    made = await api.post("/api/v1/missions", json=default)
    assert made.status_code == 201 and made.json()["handoff"] == "predictive"
    for mid in ("paper", "ours"):
        ended = await api.post(f"/api/v1/missions/{mid}", json={"action": "end"})
        assert ended.status_code == 200 and ended.json()["state"] == "ended"
    bad = await api.post("/api/v1/missions/paper", json={"action": "fly"})
    assert bad.status_code == 422
