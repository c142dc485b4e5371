"""REST is typed end to end: every route documents its response in the OpenAPI schema, and a
direct action is chosen from a fixed table, never by a name the client sent."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import httpx
import pytest
from fastapi import FastAPI

from drone.commands import ACTIONS, DirectAction
from server.app import create_app
from server.recorder import replay_app
from server.settings import Settings
from server.vehicles.stack import DroneStack
from tests.app_client import app_fixture
from tests.core.conftest import OBSERVER, PILOT

api = app_fixture(PILOT, OBSERVER, sim_speed=4.0)

NOT_ACTIONS = ("snapshot", "set_setpoint", "__class__", "__init__", "takeoff2", "LAND", "video")


def _undocumented(spec: dict[str, Any]) -> list[str]:
    """The operations of ``spec`` whose success answer has no schema beyond "some object"."""

    def named(schema: dict[str, Any]) -> bool:
        if "$ref" in schema or schema.get("format") == "binary":
            return True
        return schema.get("type") == "array" and named(schema.get("items", {}))

    bad = []
    for path, ops in spec["paths"].items():
        for method, op in ops.items():
            ok = {c: r for c, r in op.get("responses", {}).items() if c.startswith("2")}
            contents = [body for r in ok.values() for body in r.get("content", {}).values()]
            if not contents or not all(named(body.get("schema") or {}) for body in contents):
                bad.append(f"{method.upper()} {path}")
    return bad


def test_every_route_has_a_response_schema(tmp_path: Path) -> None:
    app = create_app(Settings(data_dir=tmp_path, token=PILOT, observer_token=OBSERVER))
    spec = app.openapi()
    assert len(spec["paths"]) >= 20
    assert _undocumented(spec) == []
    schemas = spec["components"]["schemas"]
    assert {"name", "simulated", "link_ok"} <= set(schemas["DroneInfo"]["properties"])
    assert schemas["DirectAction"]["enum"] == [a.value for a in DirectAction]


def _refs(node: Any) -> set[str]:
    if isinstance(node, dict):
        return {v for k, v in node.items() if k == "$ref"} | {
            r for v in node.values() for r in _refs(v)
        }
    if isinstance(node, list):
        return {r for v in node for r in _refs(v)}
    return set()


def test_commands_are_documented_as_the_typed_union(tmp_path: Path) -> None:
    app = create_app(Settings(data_dir=tmp_path, token=PILOT, observer_token=OBSERVER))
    spec = app.openapi()
    schemas = spec["components"]["schemas"]
    union = {"$ref": "#/components/schemas/Command"}
    for body in ("InterpretResponse", "CommandResponse", "SpeechResponse"):
        assert schemas[body]["properties"]["commands"]["items"] == union, body
    mapping = schemas["Command"]["discriminator"]["mapping"]
    assert set(mapping) == ACTIONS
    move = schemas["CommandMove"]["properties"]["direction"]["anyOf"][0]
    assert move["enum"] == ["forward", "backward", "left", "right", "up", "down"]
    missing = {r for r in _refs(spec) if r.removeprefix("#/components/schemas/") not in schemas}
    assert missing == set()
    assert app.openapi() is spec


def test_the_replay_routes_have_response_schemas() -> None:
    app = FastAPI()
    app.include_router(replay_app.router, prefix="/api/v1")
    spec = app.openapi()
    assert list(spec["paths"]) == ["/api/v1/replay"]
    assert _undocumented(spec) == []


def test_the_checker_sees_a_bare_dict() -> None:
    app = FastAPI()

    @app.get("/bare")
    def bare() -> dict[str, Any]:
        return {}

    assert _undocumented(app.openapi()) == ["GET /bare"]


class _RecordingVehicle:
    """The methods a drone stack calls, recorded in order (the vehicle's side of ``direct``)."""

    def __init__(self) -> None:
        self.calls: list[str] = []

    def __getattr__(self, name: str) -> Any:
        def call(*args: Any, **kwargs: Any) -> None:
            self.calls.append(name)

        return call


@pytest.mark.parametrize("name", NOT_ACTIONS)
def test_direct_refuses_a_name_that_is_no_action(name: str) -> None:
    vehicle = _RecordingVehicle()
    stack = DroneStack("uav1", "", vehicle, driver=None)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="is not a valid DirectAction"):
        stack.direct(name)
    assert vehicle.calls == []


def test_direct_sends_each_action_by_its_own_method() -> None:
    vehicle = _RecordingVehicle()
    stack = DroneStack("uav1", "", vehicle, driver=None)  # type: ignore[arg-type]
    for action in DirectAction:
        assert stack.direct(action.value) == f"{action.value} sent"
    assert vehicle.calls == ["takeoff", "land", "hover", "emergency", "reset"]


class _Watch:
    """The real vehicle, with every attribute asked of it by name written down."""

    def __init__(self, inner: Any) -> None:
        self._inner = inner
        self.asked: list[str] = []

    def __getattr__(self, name: str) -> Any:
        self.asked.append(name)
        return getattr(self._inner, name)


async def test_a_path_segment_that_is_no_action_never_reaches_the_vehicle(
    api: httpx.AsyncClient,
) -> None:
    stack = api.app.state.runtime.drones["uav1"]  # type: ignore[attr-defined]
    watch = _Watch(stack.vehicle)
    stack.vehicle = watch
    try:
        for name in NOT_ACTIONS:
            r = await api.post(f"/api/v1/drones/uav1/{name}")
            assert r.status_code == 422, (name, r.text)
            [err] = r.json()["detail"]
            assert err["loc"] == ["path", "action"]
            assert "'takeoff', 'land', 'hover', 'emergency' or 'reset'" in err["msg"]
        assert not {*NOT_ACTIONS, *(a.value for a in DirectAction)} & set(watch.asked)
        # the same door with a real action does reach it
        assert (await api.post("/api/v1/drones/uav1/hover")).status_code == 200
        assert "hover" in watch.asked
    finally:
        stack.vehicle = watch._inner


async def test_typed_responses_keep_the_wire_as_it_was(api: httpx.AsyncClient) -> None:
    """The response models document; they add nothing the producer left out."""
    runtime = api.app.state.runtime  # type: ignore[attr-defined]
    stack = runtime.drones["uav1"]
    drone = (await api.get("/api/v1/drones/uav1")).json()
    assert set(drone) == set(stack.telemetry())
    assert (await api.get("/api/v1/drones")).json()[0]["name"] == "uav1"
    world = (await api.get("/api/v1/world")).json()
    assert world == json.loads(json.dumps(runtime.world.to_dict()))
    truth = (await api.get("/api/v1/sim/uav1/truth")).json()
    assert set(truth) == set(stack.truth())
    fault = await api.post("/api/v1/sim/uav1/fault", json={"kind": "clear"})
    assert fault.json() == {"drone": "uav1", "fault": "clear", "applied": True}
    flights = (await api.get("/api/v1/flights")).json()
    assert set(flights) == {"flights"}
    version = (await api.get("/version")).json()
    assert version["protocol"]["name"] == "rosbridge"
