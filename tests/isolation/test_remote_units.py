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
from tests.support.polling import until_async


def _stack(graph: Graph) -> RemoteDroneStack:
    return RemoteDroneStack(graph, "uav1", "", simulated=True)


def _dialog(graph: Graph, stack: RemoteDroneStack, drones: list[str] | None = None) -> Any:
    """The console's dialog for ``stack``'s drone (no captioner, audit or fleet)."""
    from server.language.nlu import default_nlu
    from server.settings import Settings
    from server.vehicles.console_dialog import RemoteDialog

    return RemoteDialog(
        graph,
        Settings(),
        stack,
        None,
        None,
        None,
        nlu=default_nlu(),
        fleet=None,
        drones=lambda: drones or [stack.name],
    )


def _flying(stack: RemoteDroneStack, dialog: Any) -> None:
    """The vehicle's telemetry says it flies, and its dialog has followed."""
    stack.last = {"flying": True, "link_ok": True, "battery_pct": 80.0, "battery_known": True}
    stack.last_t = time.monotonic()
    dialog.step(0.0)


async def test_a_call_waits_for_a_starting_vehicle_to_join() -> None:
    graph = Graph()
    graph.bind_loop(asyncio.get_running_loop())
    stack = _stack(graph)
    stack.expect(5.0)
    seen: list[dict[str, Any]] = []

    async def control(args: dict[str, Any]) -> dict[str, Any]:
        seen.append(args)
        return {"accepted": False, "detail": "I cannot take off: in emergency."}

    acting = asyncio.create_task(stack.act("takeoff", 20.0))
    await asyncio.sleep(0)  # one turn of the loop: the call finds no vehicle and waits
    assert not acting.done() and not seen
    graph.advertise_service(names.control_service("uav1"), names.CONTROL_TYPE, control)
    accepted, detail = await acting
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


# ---- commands to an unreachable vehicle: 503 with Retry-After, within a few seconds ---------
async def test_a_command_to_a_vehicle_that_does_not_join_gives_up_within_a_few_seconds(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from server.vehicles import remote

    assert remote.COMMAND_JOIN_WAIT_S <= 5.0 < remote.JOIN_WAIT_S
    monkeypatch.setattr(remote, "COMMAND_JOIN_WAIT_S", 0.2)
    graph = Graph()
    graph.bind_loop(asyncio.get_running_loop())
    stack = _stack(graph)
    stack.expect()  # restarting: other calls may wait 30 s for it
    dialog = _dialog(graph, stack)
    t0 = time.monotonic()
    with pytest.raises(VehicleUnavailable, match="has not joined") as caught:
        await dialog.handle_utterance("take off")
    assert time.monotonic() - t0 < 5.0  # before: the whole JOIN_WAIT_S (30 s), then a 200
    assert caught.value.drone == "uav1" and caught.value.retry_after_s > 0
    assert stack.expected_until is not None  # still expected: a retry waits again


async def test_a_silent_vehicle_is_sent_no_command_and_one_falling_silent_is_given_up(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from server.vehicles import remote

    monkeypatch.setattr(remote, "SILENT_S", 0.3)
    graph = Graph()
    graph.bind_loop(asyncio.get_running_loop())
    stack = _stack(graph)
    seen: list[dict[str, Any]] = []
    never = asyncio.Event()

    async def control(args: dict[str, Any]) -> dict[str, Any]:
        seen.append(args)
        await never.wait()  # a stopped (SIGSTOP) or stalled vehicle process
        return {}

    graph.advertise_service(names.control_service("uav1"), names.CONTROL_TYPE, control)
    dialog = _dialog(graph, stack)
    _flying(stack, dialog)
    stack.last_t = time.monotonic() - 1.0  # its telemetry stopped a second ago
    with pytest.raises(VehicleUnavailable, match="nothing was sent"):
        await dialog.handle_utterance("go forward 1 meter")
    assert seen == []  # not queued to act whenever the process comes back
    stack.last_t = time.monotonic()  # fresh; it falls silent while answering
    with pytest.raises(VehicleUnavailable, match="stopped answering"):
        await dialog.handle_utterance("go forward 1 meter")
    # understood here, sent as the typed command
    assert [a["op"] for a in seen] == ["submit"]
    assert seen[0]["commands"] == [{"action": "move", "direction": "forward", "distance": 1.0}]


class _Speech:
    """``runtime.speech`` that hears "take off" in any WAV (no model)."""

    async def recognize_wav(self, body: bytes) -> Any:
        from server.speech.recognizer import Recognition

        return Recognition("take off", 0.95, [{"action": "takeoff"}], heard="take off")

    async def stop(self) -> None:
        return None


async def test_rest_command_and_speech_answer_503_with_retry_after(
    tmp_path: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    from server.settings import Settings
    from server.vehicles import remote
    from tests.app_client import app_client

    monkeypatch.setattr(remote, "COMMAND_JOIN_WAIT_S", 0.2)
    monkeypatch.setattr(remote, "SILENT_S", 3600.0)  # uav2's one telemetry stays fresh
    settings = Settings(data_dir=tmp_path, token="units-pilot", drone="none")
    async with app_client(settings) as client:
        rt = client.app.state.runtime  # type: ignore[attr-defined]
        for name in ("uav1", "uav2"):
            stack = RemoteDroneStack(rt.graph, name, f"/{name}", simulated=True)
            rt.drones[name] = stack
            rt.dialogs[name] = _dialog(rt.graph, stack, ["uav1", "uav2"])
        rt.drones["uav1"].expect()  # uav1 is starting and never joins
        _flying(rt.drones["uav2"], rt.dialogs["uav2"])
        rt.speech = _Speech()
        sent: list[dict[str, Any]] = []

        async def uav2(args: dict[str, Any]) -> dict[str, Any]:
            sent.append(args)
            return {"accepted": True, "detail": "land"}

        rt.graph.advertise_service(names.control_service("uav2"), names.CONTROL_TYPE, uav2)
        r = await client.post("/api/v1/command", json={"text": "take off", "drone": "uav1"})
        assert r.status_code == 503, r.text
        assert r.headers["Retry-After"] == "2"
        body = r.json()
        assert body["drone"] == "uav1" and body["retry_after_s"] == 2
        assert "uav1's flight process has not joined the server yet" in body["detail"]
        wav = {"Content-Type": "audio/wav"}
        r = await client.post("/api/v1/speech?drone=uav1", content=b"RIFF", headers=wav)
        assert r.status_code == 503 and r.headers["Retry-After"] == "2", r.text
        assert r.json()["drone"] == "uav1"
        # a fleet command: uav2 lands, and the reply says uav1 did not get it (no 503 to retry)
        r = await client.post("/api/v1/command", json={"text": "all drones land"})
        assert r.status_code == 200, r.text
        assert (
            "uav1's flight process" in r.json()["reply"] and "uav2: Landing." in r.json()["reply"]
        )
        assert not r.json()["accepted"]
        await until_async(
            lambda: sent, 5.0, "the stop sent to uav2"
        )  # uav2's dialog sent the stop as a typed command
        # with when the operator gave it (REST: its arrival), for the vehicle's deadline check
        [stop] = sent
        assert isinstance(stop.pop("issued"), float)
        assert stop == {"op": "preempt", "command": {"action": "land"}, "by": ""}


async def test_rest_advertises_the_safety_door_at_the_host_the_caller_used(
    tmp_path: Any,
) -> None:
    """A vehicle's safety door bound to every interface (``serve --host 0.0.0.0``) is
    advertised at the address the caller reached the console by, with the door's scheme; a
    pilot gets a ticket for it, an observer none; the console page's CSP names the door."""
    from server.settings import Settings
    from server.vehicles.tickets import verify
    from tests.app_client import app_client

    settings = Settings(
        data_dir=tmp_path, token="units-pilot", observer_token="units-obs", drone="none"
    )
    async with app_client(settings) as client:
        rt = client.app.state.runtime  # type: ignore[attr-defined]
        stack = RemoteDroneStack(rt.graph, "uav1", "", simulated=True)
        stack.info = {"door_url": "wss://0.0.0.0:47001", "pid": 4242}
        rt.drones["uav1"] = stack
        secret = rt.vehicles.door_secrets.get_or_create("uav1")

        async def control(args: dict[str, Any]) -> dict[str, Any]:
            return {"mode": "idle", "link_ok": True}

        rt.graph.advertise_service(names.control_service("uav1"), names.CONTROL_TYPE, control)
        phone = await client.get("https://192.168.1.7:8000/api/v1/drones/uav1")
        assert phone.status_code == 200, phone.text
        vehicle = phone.json()["vehicle"]
        assert vehicle["door_url"] == "wss://192.168.1.7:47001"
        assert verify(secret, vehicle["door_ticket"], "uav1", time.time() + 11 * 3600) == "pilot"
        listed = await client.get("https://laptop:8000/api/v1/drones")
        assert listed.json()[0]["vehicle"]["door_url"] == "wss://laptop:47001"
        observer = await client.get(
            "/api/v1/drones/uav1", headers={"Authorization": "Bearer units-obs"}
        )
        assert observer.json()["vehicle"]["door_ticket"] is None
        page = await client.get("https://192.168.1.7:8000/?token=units-pilot")
        csp = page.headers["content-security-policy"]
        assert "connect-src 'self' wss://192.168.1.7:47001;" in csp
        # A door URL as a vehicle reports it (data: nothing listens there), bound to loopback.
        stack.info = {"door_url": "ws://127.0.0.1:47002", "pid": 4242}
        local = await client.get("/api/v1/drones/uav1")
        assert local.json()["vehicle"]["door_url"] == "ws://127.0.0.1:47002"
        page = await client.get("/?token=units-pilot")
        assert "connect-src 'self' ws://127.0.0.1:47002;" in page.headers["content-security-policy"]
        api = await client.get("/api/v1/health")  # every other response: this origin only
        assert "connect-src 'self';" in api.headers["content-security-policy"]


async def test_a_stop_with_an_id_goes_to_the_vehicle_and_its_verdict_comes_back(
    tmp_path: Any,
) -> None:
    """REST ``POST /drones/uav1/emergency {"id", "issued"}``: the vehicle gets the id and
    issued time; its verdict (here: its door had brought the stop first) is the answer."""
    from server.settings import Settings
    from tests.app_client import app_client

    settings = Settings(data_dir=tmp_path, token="units-pilot", drone="none")
    async with app_client(settings) as client:
        rt = client.app.state.runtime  # type: ignore[attr-defined]
        stack = RemoteDroneStack(rt.graph, "uav1", "", simulated=True)
        rt.drones["uav1"] = stack
        calls: list[dict[str, Any]] = []

        async def control(args: dict[str, Any]) -> dict[str, Any]:
            calls.append(args)
            return {
                "accepted": True,
                "ran": False,
                "detail": "emergency s1 was already delivered by the door road",
                "delivered": 1000.5,
                "road": "door",
                "late_s": 0.01,
            }

        rt.graph.advertise_service(names.control_service("uav1"), names.CONTROL_TYPE, control)
        r = await client.post("/api/v1/drones/uav1/emergency", json={"id": "s1", "issued": 1000.49})
        assert r.status_code == 200, r.text
        body = r.json()
        assert body["accepted"] and body["road"] == "door" and body["delivered"] == 1000.5
        assert body["id"] == "s1" and "already delivered by the door" in body["detail"]
        assert calls == [{"op": "direct", "action": "emergency", "id": "s1", "issued": 1000.49}]
        # a bad id or issued is refused before anything is sent
        for bad in ({"id": "a b"}, {"id": "x", "issued": -1}, {"id": "x", "extra": 1}):
            assert (await client.post("/api/v1/drones/uav1/land", json=bad)).status_code == 422
        assert len(calls) == 1
