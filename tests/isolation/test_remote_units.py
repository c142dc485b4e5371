"""The web process's stand-in for a vehicle process, against an in-memory graph (no sockets).

What ``serve --vehicles process`` must do like an in-process drone: calls made while the vehicle
is still starting wait for it, a vehicle that never comes is a clear 503 (not a 404, not an
empty drone), direct actions get the vehicle's own verdict, and "stop the patrol" said to a
vehicle's dialog reaches the fleet through an awaitable port.
"""

from __future__ import annotations

import asyncio
import time
from typing import Any

import pytest

from server.graph import Graph
from server.vehicles import names
from server.vehicles.errors import VehicleUnavailable
from server.vehicles.remote import RemoteDroneStack
from tests.dialog.test_manager import Rig


def _stack(graph: Graph) -> RemoteDroneStack:
    return RemoteDroneStack(graph, "uav1", "", simulated=True)


async def test_a_call_waits_for_a_starting_vehicle_to_join() -> None:
    graph = Graph()
    graph.bind_loop(asyncio.get_running_loop())
    stack = _stack(graph)
    stack.expect(5.0)
    seen: list[dict[str, Any]] = []

    async def control(args: dict[str, Any]) -> dict[str, Any]:
        seen.append(args)
        return {"accepted": False, "detail": "I cannot take off: in emergency."}

    async def join_later() -> None:
        await asyncio.sleep(0.2)
        graph.advertise_service(names.control_service("uav1"), names.CONTROL_TYPE, control)

    joining = asyncio.create_task(join_later())
    accepted, detail = await stack.act("takeoff", 20.0)
    await joining
    assert (accepted, detail) == (False, "I cannot take off: in emergency.")
    assert seen == [{"op": "direct", "action": "takeoff", "check": True, "battery_low_pct": 20.0}]
    assert stack.expected_until is None  # joined: later calls do not wait


async def test_a_vehicle_that_is_not_there_is_unavailable_at_once() -> None:
    graph = Graph()
    graph.bind_loop(asyncio.get_running_loop())
    stack = _stack(graph)
    t0 = time.monotonic()
    with pytest.raises(VehicleUnavailable, match="not connected"):
        await stack.act("takeoff", 20.0)
    assert time.monotonic() - t0 < 1.0  # not expected: no wait


async def test_a_vehicle_that_never_joins_is_unavailable_after_the_wait() -> None:
    graph = Graph()
    graph.bind_loop(asyncio.get_running_loop())
    stack = _stack(graph)
    stack.expect(0.2)
    with pytest.raises(VehicleUnavailable, match="has not joined"):
        await stack.call({"op": "truth"})


async def test_truth_and_telemetry_of_a_silent_vehicle_are_unavailable_not_empty() -> None:
    graph = Graph()
    graph.bind_loop(asyncio.get_running_loop())
    stack = _stack(graph)
    stack.expect(0.2)
    # REST's sync routes run in a worker thread
    with pytest.raises(VehicleUnavailable):
        await asyncio.to_thread(stack.truth)
    with pytest.raises(VehicleUnavailable):
        await asyncio.to_thread(stack.telemetry)


async def test_telemetry_from_a_worker_thread_is_asked_of_the_vehicle_now() -> None:
    graph = Graph()
    graph.bind_loop(asyncio.get_running_loop())
    stack = _stack(graph)
    stack.last = {"mode": "landing", "link_ok": True}  # the last periodic one, stale

    async def control(args: dict[str, Any]) -> dict[str, Any]:
        assert args == {"op": "telemetry"}
        return {"mode": "idle", "link_ok": True}

    graph.advertise_service(names.control_service("uav1"), names.CONTROL_TYPE, control)
    out = await asyncio.to_thread(stack.telemetry)
    assert out["mode"] == "idle" and out["link_ok"] is True
    assert out["vehicle"]["connected"] is True


def test_seen_markers_come_from_the_telemetry() -> None:
    stack = _stack(Graph())
    marker = {"id": 3, "x": 0.0, "y": 0.0, "yaw_rad": 0.0, "marker_x": 2.0, "marker_y": 2.0}
    stack.last = {"markers": [marker, {"id": "bad"}]}
    (seen,) = stack.seen_markers()
    assert seen.id == 3 and seen.bearing_deg == pytest.approx(45.0)


class _Reply:
    def __init__(self, ok: bool, text: str) -> None:
        self.ok, self.text = ok, text


class _AsyncFleet:
    """A fleet port as a vehicle process has it: answers are awaitables."""

    def __init__(self, running: bool) -> None:
        self.running_now = running
        self.calls: list[str] = []

    async def _answer(self, op: str) -> _Reply:
        self.calls.append(op)
        if op == "stop" and not self.running_now:
            return _Reply(False, "No patrol is running.")
        return _Reply(True, "Stopping the patrol; the drones are flying home.")

    def start(self, threshold: float = 0.30) -> Any:
        return self._answer("start")

    def stop(self) -> Any:
        return self._answer("stop")


@pytest.mark.parametrize(
    ("running", "reply"),
    [(True, "Stopping the patrol; the drones are flying home."), (False, "OK, cancelled.")],
)
async def test_stop_the_patrol_through_an_awaitable_fleet_port(running: bool, reply: str) -> None:
    rig = Rig()  # the dialog tests' fakes, on a virtual clock
    fleet = _AsyncFleet(running)
    rig.dm.fleet = fleet
    result = await rig.dm.handle_utterance("stop the patrol")
    assert fleet.calls == ["stop"]  # no running(): the central server is asked
    assert result.reply == reply
    start = await rig.dm.handle_utterance("start the patrol with all drones")
    assert fleet.calls == ["stop", "start"] and start.accepted
