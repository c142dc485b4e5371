"""Mission state is honest (issue 26 finding 7): after the operator's Land, "stop", Emergency
or a jog on a patrolling drone, the mission reads ``paused by the operator (…)`` with its
drones' roles (not ``running`` with the drone ``patrolling``), the CTM sends nothing until the
operator resumes or ends it, and a resumed mission flies again.

Lockstep: the real simulator behind the AR.Drone protocol in memory, EKF, PID, task managers,
LTMs and the CTM (``experiments.patrol.PatrolExperiment``), with the operator's doors as they
reach the drone: the dialog (typed or spoken "land", "stop"), the task manager's preempt (the
page's and REST's Land and Emergency, ``/ardrone/land``, the safety door all call it), the
Hover button's cancel, and ``Vehicle.jog`` (``/cmd_vel``)."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import Any

import pytest

from drone.supervisor import supervise
from experiments.patrol import PatrolConfig, PatrolExperiment
from server.dialog.adapters import TaskManagerPort, VehicleAdapter
from server.dialog.manager import DialogManager
from server.fleet.central import CentralPatrol
from server.fleet.errors import IllegalTransition, MessageError
from server.fleet.ltm import interruption, operator_action
from server.fleet.messages import DroneRole, LtmStatus
from server.fleet.states import MissionEvent, MissionState, transition
from server.graph import Graph
from server.settings import Settings

FAST = {"flight_time_s": 150.0, "swap_s": 20.0}
ON_PATROL_S = 25.0  # the first drone is on the route well before this (test_patrol: < 30 s)


def test_one_table_and_illegal_transitions_raise() -> None:
    S, E = MissionState, MissionEvent
    assert transition(S.WAITING, E.ON_ROUTE) is S.RUNNING
    assert transition(S.RUNNING, E.OPERATOR) is S.PAUSED
    assert transition(S.PAUSED, E.RESUME) is S.WAITING
    assert transition(S.STALLED, E.READY) is S.WAITING
    assert transition(S.PAUSED, E.END) is S.ENDED
    with pytest.raises(IllegalTransition, match="cannot resume while running"):
        transition(S.RUNNING, E.RESUME)
    with pytest.raises(IllegalTransition, match="while ended"):
        transition(S.ENDED, E.OPERATOR)
    assert not S.ENDED.live and S.PAUSED.live and not S.PAUSED.flying


def test_operator_words_from_the_task_managers_reasons() -> None:
    assert operator_action("preempted by land") == "land"
    assert operator_action("preempted by emergency") == "emergency"
    assert operator_action("preempted by return_home") == "return home"
    assert operator_action("manual control took over") == "jog"
    assert operator_action("hover requested") == "hover"
    assert operator_action("cancelled") == "cancel"
    # the drone's own safety is not the operator
    assert interruption("preempted by land") == ("land", "")
    assert interruption("preempted by hover (central server silent)") == (
        "hover",
        "central server silent",
    )
    assert interruption("preempted by land (battery monitor)") == ("land", "battery monitor")


def test_status_carries_the_operator_and_refuses_a_long_one() -> None:
    base = {
        "name": "uav1",
        "t": 1.0,
        "seq": 1,
        "x": 0.0,
        "y": 0.0,
        "z": 0.0,
        "yaw_deg": 0.0,
        "battery_pct": 80.0,
        "flying": True,
        "state": "HOVERING",
        "link_ok": True,
        "station": {"x": 0.0, "y": 0.0, "z": 0.0},
    }
    assert LtmStatus.from_dict(base).operator == ""  # an older vehicle: nothing said
    st = LtmStatus.from_dict(base | {"operator": "land"})
    assert st.operator == "land" and LtmStatus.from_dict(st.to_dict()) == st
    with pytest.raises(MessageError, match="operator"):
        LtmStatus.from_dict(base | {"operator": "x" * 65})


class Pilot:
    """The operator at the lockstep fleet: ``act`` once the mission runs, then watch."""

    def __init__(self, exp: PatrolExperiment, act: Callable[[str, float], None]) -> None:
        self.exp = exp
        self.act = act
        self.acted_at: float | None = None
        self.victim = ""
        self.states: list[tuple[float, str, str]] = []  # (t, state, detail) on each change
        self.roles: dict[str, set[str]] = {}  # after the act: each drone's roles seen
        exp.hooks.append(self._hook)

    def mission(self) -> Any:
        return next(iter(self.exp.ctm.missions.values()))

    def _hook(self, now: float) -> None:
        ms = next(iter(self.exp.ctm.missions.values()), None)
        if ms is None:
            return
        if not self.states or self.states[-1][1:] != (ms.state.value, ms.detail):
            self.states.append((now, ms.state.value, ms.detail))
        if self.acted_at is None and ms.state is MissionState.RUNNING and now > ON_PATROL_S:
            assert ms.active is not None
            self.victim, self.acted_at = ms.active, now
            self.act(ms.active, now)
        if self.acted_at is not None:
            for name, rec in self.exp.ctm.drones.items():
                self.roles.setdefault(name, set()).add(rec.role.value)


def _index(name: str) -> int:
    return int(name.removeprefix("uav")) - 1


def _dialogs(exp: PatrolExperiment) -> dict[str, DialogManager]:
    """Each drone's dialog manager and the vehicle's safety monitors (its supervisor, whose
    alarms the dialog speaks), stepped with the rig as the console and the vehicle step them."""
    out = {}
    for i, v in enumerate(exp.rig.vehicles):
        dm = DialogManager(
            Graph(),
            Settings(),
            TaskManagerPort(exp.tasks[i]),
            VehicleAdapter(v, exp.world),
            None,
            None,
            exp.rig.clock.now,
            drone=v.name,
            fleet=CentralPatrol(exp.ctm, exp.world, clock=exp.rig.clock.now),
        )
        exp.hooks.append(dm.step)
        sup = supervise(v, exp.tasks[i], exp.world)
        sup.on_alarm(dm.hear)
        exp.hooks.append(sup.step)
        out[v.name] = dm
    return out


def _say(dm: DialogManager, text: str) -> str:
    """A typed or spoken sentence, through the drone's dialog manager."""
    return asyncio.run(dm.handle_utterance(text)).reply


def _other(name: str) -> str:
    return "uav2" if name == "uav1" else "uav1"


def test_land_by_voice_pauses_the_mission_and_nothing_flies_until_resumed() -> None:
    exp = PatrolExperiment(PatrolConfig(drones=2, duration_s=70.0, **FAST))
    dialogs = _dialogs(exp)
    said: list[str] = []
    pilot = Pilot(exp, lambda name, now: said.append(_say(dialogs[name], "land")))
    exp.run()
    assert said == ["Landing."]
    ms = pilot.mission()
    info = exp.ctm.mission_info(ms.mission.id, exp.rig.clock.now())
    # before the fix: state "running", the landed drone "patrolling"
    assert info["state"] == "paused", pilot.states
    assert info["detail"] == "paused by the operator (land)"
    assert info["drones"] == [
        {"name": pilot.victim, "role": "paused", "was": "patrolling", "operator": "land"}
    ]
    assert info["active"] is None and info["relief"] is None
    status = {d["name"]: d for d in exp.ctm.fleet_status(exp.rig.clock.now())["drones"]}
    assert status[pilot.victim]["role"] == "paused"
    # nothing was sent while paused: the landed drone stays down, the other never took off
    victim, other = exp.rig.sims[_index(pilot.victim)], exp.rig.sims[_index(_other(pilot.victim))]
    assert not victim.truth.flying and not other.truth.flying
    assert pilot.roles[_other(pilot.victim)] == {"idle"}
    paused_at = next(t for t, state, _ in pilot.states if state == "paused")
    assert paused_at - (pilot.acted_at or 0.0) <= 1.5  # the next LTM status and CTM round


def test_stop_by_voice_pauses_and_resume_flies_the_hovering_drone_again() -> None:
    exp = PatrolExperiment(PatrolConfig(drones=2, duration_s=60.0, **FAST))
    dialogs = _dialogs(exp)
    replies: list[str] = []

    def stop(name: str, now: float) -> None:
        replies.append(_say(dialogs[name], "stop"))  # "stop" is a hover

    pilot = Pilot(exp, stop)

    def resume(now: float) -> None:
        if pilot.acted_at is not None and now > pilot.acted_at + 15.0 and len(replies) == 1:
            # the dialog's "resume the patrol" calls the Central patrol's resume
            replies.append(_say(dialogs[_other(pilot.victim)], "resume the patrol"))

    exp.hooks.append(resume)
    exp.run()
    assert replies[0] == "Holding position."
    assert replies[1] == "Resuming the patrol; the first drone ready flies to the route."
    states = [s for _, s, _ in pilot.states]
    # running → paused (hover) for 15 s → waiting → running again
    assert states[states.index("paused") :][:3] == ["paused", "waiting", "running"], pilot.states
    paused = [d for _, s, d in pilot.states if s == "paused"]
    assert paused == ["paused by the operator (hover)"]
    ms = pilot.mission()
    assert ms.state is MissionState.RUNNING
    # the hovering drone was nearest the route: it carries on at once, the other stays down
    assert ms.active == pilot.victim
    assert pilot.roles[_other(pilot.victim)] == {"idle"}
    assert exp.ctm.drones[pilot.victim].role is DroneRole.PATROLLING


def test_emergency_pauses_and_end_brings_the_others_home() -> None:
    exp = PatrolExperiment(PatrolConfig(drones=2, duration_s=60.0, **FAST))

    def emergency(name: str, now: float) -> None:
        exp.tasks[_index(name)].preempt("emergency")  # the page's, REST's and safety door's

    pilot = Pilot(exp, emergency)
    exp.run()
    ms = pilot.mission()
    assert ms.state is MissionState.PAUSED and ms.detail == "paused by the operator (emergency)"
    assert ms.replacements == 0  # not handed to another drone as a failure would be
    assert exp.rig.sims[_index(_other(pilot.victim))].truth.flying is False
    now = exp.rig.clock.now()
    exp.ctm.control_mission(ms.mission.id, "end", now)
    info = exp.ctm.mission_info(ms.mission.id, now)
    assert info["state"] == "ended" and info["detail"] == "ended by the operator"
    with pytest.raises(IllegalTransition, match="cannot resume while ended"):
        exp.ctm.control_mission(ms.mission.id, "resume", now)


@pytest.mark.parametrize(
    ("door", "word"),
    [
        ("hover_button", "hover"),  # the page's Hover: DroneStack.direct cancels with a reason
        ("jog", "jog"),  # /cmd_vel
        ("rest_land", "land"),  # POST /drones/{id}/land, /ardrone/land, the safety door
    ],
)
def test_every_door_pauses(door: str, word: str) -> None:
    exp = PatrolExperiment(PatrolConfig(drones=2, duration_s=40.0, **FAST))

    def act(name: str, now: float) -> None:
        i = _index(name)
        if door == "hover_button":
            exp.tasks[i].cancel("hover requested")
            exp.rig.vehicles[i].hover()
        elif door == "jog":
            exp.rig.vehicles[i].jog(0.0, 0.5, 0.0, 0.0)
        else:
            exp.tasks[i].preempt("land")

    pilot = Pilot(exp, act)
    exp.run()
    ms = pilot.mission()
    assert ms.state is MissionState.PAUSED, pilot.states
    assert ms.detail == f"paused by the operator ({word})"
    assert ms.paused == {pilot.victim: "patrolling"}


def test_sent_home_is_relieved_not_paused() -> None:
    """A return home (the operator's "go home", or the battery monitor's at its low level)
    is the drone leaving its post: the other drone takes over, the mission keeps running."""
    exp = PatrolExperiment(PatrolConfig(drones=2, duration_s=90.0, **FAST))
    dialogs = _dialogs(exp)
    said: list[str] = []
    pilot = Pilot(exp, lambda name, now: said.append(_say(dialogs[name], "return home")))
    exp.run()
    ms = pilot.mission()
    assert said and said[0].startswith("Returning home")
    assert "paused" not in [s for _, s, _ in pilot.states]
    assert ms.state is MissionState.RUNNING and ms.active == _other(pilot.victim)
    assert "returning" in pilot.roles[pilot.victim]


def test_the_drones_own_safety_is_not_the_operator() -> None:
    """The vehicle's watch of the central server hovers a drone the console went silent on
    (``host._on_loss``): not the operator's doing, so the mission is not paused; the drone is
    free again and, still the nearest, flies the patrol on."""
    exp = PatrolExperiment(PatrolConfig(drones=2, duration_s=50.0, **FAST))

    def silent(name: str, now: float) -> None:
        exp.tasks[_index(name)].preempt("hover", by="central server silent")

    pilot = Pilot(exp, silent)
    exp.run()
    states = [s for _, s, _ in pilot.states]
    assert "paused" not in states, pilot.states
    assert states[-1] == "running"
    ms = pilot.mission()
    assert ms.active == pilot.victim and ms.replacements == 0
    left = [t for _, t in exp.ctm.events if "left on its own" in t]
    assert left == [f"{pilot.victim} left on its own (held: hover (central server silent))"]
    assert pilot.roles[_other(pilot.victim)] == {"idle"}


def test_a_safety_monitors_landing_hands_the_post_to_another_drone() -> None:
    """The battery monitor lands a patrolling drone at its critical level (12 %): the mission
    is not paused by anyone; the other drone takes the route over. Both start at 22 % (the
    paper's 12-minute battery, a 5 % threshold: each is above the mission's reserve), so the
    first reaches 12 % on patrol a minute later; its LTM's own reserve (a few percent) lies
    below the monitor's level, so the monitor acts first."""
    exp = PatrolExperiment(PatrolConfig(drones=2, duration_s=120.0, threshold=0.05, swap_s=20.0))
    for sim in exp.rig.sims:
        sim.physics.battery.drain_to(22.0)
    _dialogs(exp)  # each drone's safety monitors, as the console runs them
    pilot = Pilot(exp, lambda name, now: None)  # the operator does nothing
    exp.run()
    states = [s for _, s, _ in pilot.states]
    assert "paused" not in states, pilot.states
    ms = pilot.mission()
    assert ms.state is MissionState.RUNNING and ms.active == _other(pilot.victim)
    left = [t for _, t in exp.ctm.events if "left on its own" in t]
    assert left == [f"{pilot.victim} left on its own (held: land (battery monitor))"]
    assert not exp.rig.sims[_index(pilot.victim)].truth.flying  # it landed where it was


def test_a_monitor_that_holds_the_drone_for_the_operator_pauses_the_mission() -> None:
    """A safety monitor's hover that asks the operator (navdata in doubt, out of the geofence)
    is not the CTM's to override: the mission waits for the operator."""
    exp = PatrolExperiment(PatrolConfig(drones=2, duration_s=45.0, **FAST))

    def doubt(name: str, now: float) -> None:  # as the supervisor preempts for an alarm
        TaskManagerPort(exp.tasks[_index(name)]).preempt({"action": "hover"}, by="navdata monitor")

    pilot = Pilot(exp, doubt)
    exp.run()
    ms = pilot.mission()
    assert ms.state is MissionState.PAUSED, pilot.states
    assert ms.detail == f"paused: {pilot.victim} held by its navdata monitor (hover)"
    assert [t for _, lv, t in exp.ctm.notices if lv == "warn"] == [
        f"Patrol m1 is {ms.detail}; resume or end it."
    ]
    assert exp.rig.sims[_index(pilot.victim)].truth.flying  # hovering where it was held
    assert pilot.roles[_other(pilot.victim)] == {"idle"}
