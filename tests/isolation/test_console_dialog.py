"""The console's dialog for a drone in a vehicle process, against an in-memory graph: what is
said is understood here and reaches the vehicle as typed commands, in the order given (a stop
never waits), the vehicle's task notices and supervisor alarms are followed and said, and the
bus carries the task ops with the same checks as every command."""

from __future__ import annotations

import asyncio
import json
import time
from typing import Any

import pytest

from drone.bus.commands import decode_command
from drone.bus.errors import PayloadError
from drone.supervisor.alarms import ActionKind, Alarm, AlarmAction, BadAlarm, Severity
from server.dialog.states import State
from server.graph import Graph
from server.language.nlu import default_nlu
from server.settings import Settings
from server.vehicles import names
from server.vehicles.console_dialog import RemoteDialog
from server.vehicles.remote import RemoteDroneStack
from tests.support.polling import until_async


class _Vehicle:
    """A vehicle's control service: records every op; ``slow`` ops wait for ``release``."""

    def __init__(self, graph: Graph, name: str = "uav1") -> None:
        self.seen: list[dict[str, Any]] = []
        self.slow: set[str] = set()
        self.release = asyncio.Event()
        self.decisions: list[dict[str, Any]] | None = None
        self.telemetry: dict[str, Any] = {}  # what it answers when asked for its telemetry now
        graph.advertise_service(names.control_service(name), names.CONTROL_TYPE, self.control)

    async def control(self, args: dict[str, Any]) -> dict[str, Any]:
        self.seen.append(args)
        if args["op"] in self.slow:
            await self.release.wait()
        if args["op"] == "telemetry":
            return self.telemetry
        if args["op"] == "submit":
            given = self.decisions
            ok = [{"accepted": True, "reason": "", "question": False}] * len(args["commands"])
            return {"decisions": given if given is not None else ok}
        return {"accepted": True, "detail": ""}


def _rig(graph: Graph) -> tuple[RemoteDroneStack, RemoteDialog, list[dict[str, Any]]]:
    stack = RemoteDroneStack(graph, "uav1", "", simulated=True)
    dialog = RemoteDialog(
        graph,
        Settings(),
        stack,
        None,
        None,
        None,
        nlu=default_nlu(),
        fleet=None,
        drones=lambda: ["uav1"],
    )
    replies: list[dict[str, Any]] = []
    graph.subscribe("/console/reply", replies.append, type="uav_console/Reply")
    return stack, dialog, replies


def _flying(stack: RemoteDroneStack, dialog: RemoteDialog) -> None:
    stack.last = {"flying": True, "link_ok": True, "battery_pct": 80.0, "battery_known": True}
    stack.last_t = time.monotonic()
    dialog.step(0.0)


async def test_a_sentence_is_understood_here_and_sent_as_typed_commands() -> None:
    graph = Graph()
    graph.bind_loop(asyncio.get_running_loop())
    vehicle = _Vehicle(graph)
    stack, dialog, _ = _rig(graph)
    _flying(stack, dialog)
    result = await dialog.handle_utterance("go up 0.4 meters then turn left 90 degrees")
    assert result.accepted, result.reply
    assert vehicle.seen == [
        {
            "op": "submit",
            "commands": [
                {"action": "move", "direction": "up", "distance": 0.4},
                {"action": "turn", "direction": "left", "angle": 90},
            ],
        }
    ]
    # the vehicle's executor refuses: its reason is the answer, nothing is said to happen
    vehicle.decisions = [{"accepted": False, "reason": "no station to go home to"}]
    result = await dialog.handle_utterance("go up 0.4 meters")
    assert not result.accepted and "no station to go home to" in result.reply


async def test_a_refusal_is_judged_again_on_the_telemetry_of_now() -> None:
    """The periodic telemetry still says flying, the drone has just landed: "take off" is not
    refused with "I am already flying" but asked of the vehicle's telemetry of now, and sent."""
    graph = Graph()
    graph.bind_loop(asyncio.get_running_loop())
    vehicle = _Vehicle(graph)
    stack, dialog, _ = _rig(graph)
    _flying(stack, dialog)
    vehicle.telemetry = {**stack.last, "flying": False}
    result = await dialog.handle_utterance("take off")
    assert result.accepted, result.reply
    assert [a["op"] for a in vehicle.seen] == ["telemetry", "submit"]
    # it really flies: asked again, the refusal stands, and nothing is sent
    other = Graph()
    other.bind_loop(asyncio.get_running_loop())
    vehicle = _Vehicle(other)
    stack, dialog, _ = _rig(other)
    _flying(stack, dialog)
    vehicle.telemetry = dict(stack.last)
    result = await dialog.handle_utterance("take off")
    assert not result.accepted and result.reply == "I am already flying."
    assert [a["op"] for a in vehicle.seen] == ["telemetry"]


async def test_a_stop_goes_at_once_and_what_follows_it_waits_for_it() -> None:
    graph = Graph()
    graph.bind_loop(asyncio.get_running_loop())
    vehicle = _Vehicle(graph)
    stack, dialog, _ = _rig(graph)
    _flying(stack, dialog)
    vehicle.slow = {"submit"}  # a vehicle slow to answer a queued sentence
    moving = asyncio.create_task(dialog.handle_utterance("go forward 1 meter"))
    await until_async(lambda: len(vehicle.seen) == 1, 5.0, "the submit sent")
    landing = await dialog.handle_utterance("land")  # said while the submit is unanswered
    assert landing.accepted
    await until_async(lambda: len(vehicle.seen) == 2, 5.0, "the land sent")
    assert vehicle.seen[1] == {"op": "preempt", "command": {"action": "land"}, "by": ""}
    vehicle.release.set()
    await moving


async def test_what_follows_a_stop_is_sent_once_the_stop_was_answered() -> None:
    graph = Graph()
    graph.bind_loop(asyncio.get_running_loop())
    vehicle = _Vehicle(graph)
    stack, dialog, _ = _rig(graph)
    _flying(stack, dialog)
    vehicle.slow = {"preempt"}
    both = asyncio.create_task(dialog.handle_utterance("hover then go up 0.3 meters"))
    await until_async(lambda: vehicle.seen, 5.0, "the hover sent")
    for _ in range(20):  # turns of the loop for a submit sent out of order to show itself
        await asyncio.sleep(0)
    assert [a["op"] for a in vehicle.seen] == ["preempt"]
    vehicle.release.set()
    assert (await both).accepted
    assert [a["op"] for a in vehicle.seen] == ["preempt", "submit"]


async def test_the_vehicles_task_notices_and_alarms_are_followed_and_said() -> None:
    graph = Graph()
    graph.bind_loop(asyncio.get_running_loop())
    _Vehicle(graph)
    stack, dialog, replies = _rig(graph)
    _flying(stack, dialog)
    notices = names.task_event_topic("uav1")
    graph.advertise(notices, names.STRING)
    note = {"kind": "done", "text": "", "task": "land", "state": "idle", "queued": 0}
    graph.publish(notices, {"data": json.dumps(note)})
    assert replies[-1]["text"] == "Landed." and dialog.state is State.LANDED
    graph.publish(notices, {"data": "not json"})  # logged, not raised
    alarm = Alarm(
        "battery", Severity.ALERT, "Battery critical: landing.", AlarmAction(ActionKind.LAND)
    )
    graph.advertise(names.alarm_topic("uav1"), names.STRING)
    _flying(stack, dialog)
    graph.publish(names.alarm_topic("uav1"), {"data": json.dumps(alarm.as_message("uav1"))})
    said = replies[-1]
    assert said["text"] == "Battery critical: landing." and said["alarm"] == "battery"
    assert said["level"] == "alert" and dialog.state is State.LANDING


@pytest.mark.parametrize(
    "action",
    [
        None,
        AlarmAction(ActionKind.HOVER),
        AlarmAction(ActionKind.RETURN_HOME),
        AlarmAction(ActionKind.DESCEND, distance_m=0.4),
        AlarmAction(ActionKind.BACK_OFF, to=(1.0, 2.0, 1.5)),
    ],
)
def test_an_alarm_reads_back_as_the_vehicle_wrote_it(action: AlarmAction | None) -> None:
    alarm = Alarm("altitude", Severity.WARN, "Too high.", action)
    assert Alarm.from_message(json.loads(json.dumps(alarm.as_message("uav1")))) == alarm


@pytest.mark.parametrize(
    "msg",
    [
        [],
        {"monitor": "", "severity": "warn", "text": "x"},
        {"monitor": "m", "severity": "loud", "text": "x"},
        {"monitor": "m", "severity": "warn", "text": "x", "action": {"action": "flip"}},
        {"monitor": "m", "severity": "warn", "text": "x", "action": "land"},
    ],
)
def test_a_malformed_alarm_is_refused_with_the_reason(msg: object) -> None:
    with pytest.raises(BadAlarm):
        Alarm.from_message(msg)


def _cmd(op: str, **args: Any) -> bytes:
    return json.dumps({"id": "1", "op": op, "args": args, "console": "c", "pilot": "p"}).encode()


def test_the_task_ops_on_the_bus_carry_typed_commands_and_a_preempted_stop_is_a_stop() -> None:
    land = decode_command(_cmd("preempt", command={"action": "land"}))
    assert land.is_stop and land.action == "land"
    home = decode_command(_cmd("preempt", command={"action": "return_home"}))
    assert not home.is_stop  # under the lease, like any other command
    ok = decode_command(_cmd("submit", commands=[{"action": "takeoff"}]))
    assert not ok.is_stop
    assert not decode_command(_cmd("cancel")).is_stop
    for bad, why in [
        (_cmd("submit", commands=[]), "needs a list of commands"),
        (_cmd("submit", commands=[{"action": "loop"}]), "commands.0: unknown action 'loop'"),
        (_cmd("submit", commands=[{"action": "move", "distance": "far"}]), "commands.0"),
        (_cmd("preempt"), "a preempt needs one command"),
    ]:
        with pytest.raises(PayloadError, match=why):
            decode_command(bad)


class _Sample:
    """What the vehicle reads of a Zenoh sample: its payload's bytes."""

    def __init__(self, data: bytes) -> None:
        self.payload = self
        self._data = data

    def to_bytes(self) -> bytes:
        return self._data


async def test_a_consoles_beat_gives_a_vehicle_on_the_bus_the_recording_id() -> None:
    """The id of the flight recording reaches a vehicle with no vehicle link (its audit rows
    carry it), in the consoles' beats; a beat without one, or a bad one, changes nothing."""
    from types import SimpleNamespace

    from server.vehicles.bus_vehicle import BusVehicleSide

    loop = asyncio.get_running_loop()
    host = SimpleNamespace(recording_id="")
    side = SimpleNamespace(host=host)
    for payload in (b'{"t": 1.0, "recording": "20261126-120000"}', b'{"t": 2.0}', b"junk"):
        BusVehicleSide._on_beat(side, _Sample(payload), loop)  # type: ignore[arg-type]
        await asyncio.sleep(0)
        assert host.recording_id == "20261126-120000"
