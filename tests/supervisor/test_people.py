"""Keep away from people: the world's people (walking along their paths, seeded), a target
too close refused with the reason said, a way past someone re-routed round them, and a person
walking up to a hovering drone making it back off and say why. Lockstep, camera off."""

from __future__ import annotations

import math
import re
from dataclasses import replace

import pytest

from drone.control.pid import Setpoint
from drone.limits import limits_of
from drone.sim.people import people_at
from drone.sim.world import SceneObject, Walk, World, WorldError, load_world, parse_world
from drone.supervisor.people import KeepAway, Rerouted
from tests.dialog.lockstep_dialog import dialog_rig


def _person(x: float, y: float, walk: Walk | None = None) -> SceneObject:
    size = (0.5, 0.3, 1.75)
    return SceneObject("person1", "person", "orange", (0, 128, 255), (x, y, 0.0), 0.0, size, walk)


def _room(*people: SceneObject, distance_m: float | None = None) -> World:
    """The indoor room with only these people in it (no furniture: none matters here)."""
    w = load_world("indoor")
    limits = dict(w.limits or {})
    if distance_m is not None:
        limits["person_distance_m"] = distance_m
    return replace(w, objects=tuple(people), limits=limits)


def _doc(**person: object) -> dict[str, object]:
    obj = {"id": "p", "kind": "person", "colour": "blue", "position": [1, 1, 0], "size": [1, 1, 2]}
    obj.update(person)
    return {
        "name": "t",
        "bounds": dict(x_min=0, x_max=8, y_min=0, y_max=6, z_min=0, z_max=3),
        "objects": [obj],
    }


def test_worlds_say_how_far_to_keep_from_people_and_where_people_walk() -> None:
    assert limits_of(load_world("outdoor")).person_distance_m == 2.0  # the default
    assert limits_of(load_world("indoor")).person_distance_m == 1.0  # the room's own
    # worlds stay hashable with a limits section (renderers are cached per world)
    assert len({load_world("indoor"), load_world("outdoor")}) == 2
    w = parse_world(_doc(walk={"path": [[5, 1], [5, 4]], "speed_m_s": 0.5, "seed": 2}))
    assert w.objects[0].walk == Walk(((5.0, 1.0), (5.0, 4.0)), 0.5, 2)
    with pytest.raises(WorldError, match="only people walk"):
        parse_world(_doc(kind="box", walk={"path": [[5, 1]], "speed_m_s": 0.5}))
    with pytest.raises(WorldError, match=r"walk.path\[0\].*outside the bounds"):
        parse_world(_doc(walk={"path": [[50, 1]], "speed_m_s": 0.5}))
    with pytest.raises(WorldError, match="speed_m_s"):
        parse_world(_doc(walk={"path": [[5, 1]], "speed_m_s": 30}))


def test_people_walk_their_path_and_back_the_same_for_every_simulator() -> None:
    w = parse_world(_doc(walk={"path": [[5, 1]], "speed_m_s": 1.0, "seed": 0}))
    (p0,) = people_at(w, 0.0)
    assert (p0.x, p0.y) == (1.0, 1.0)
    xs = [people_at(w, k / 10)[0].x for k in range(200)]
    assert max(xs) == pytest.approx(5.0, abs=0.05) and min(xs[40:]) < 1.2  # there and back
    assert people_at(w, 7.3) == people_at(w, 7.3)  # a function of the time: every sim agrees
    other = parse_world(_doc(walk={"path": [[5, 1]], "speed_m_s": 1.0, "seed": 9}))
    assert people_at(other, 3.0) != people_at(w, 3.0)  # the seed varies the pace


def test_a_way_past_a_person_goes_round_and_a_target_beside_them_is_refused() -> None:
    world = _room(_person(4.0, 1.5))
    keep = KeepAway(lambda: people_at(world, 0.0), 1.0, limits_of(world))
    way = keep.reroute((1.5, 1.5), [Setpoint(6.8, 1.5, 1.0, 0.0)])
    assert isinstance(way, Rerouted) and way.origin == [None, 0] and way.around == ["person1", ""]
    for a, b in zip([(1.5, 1.5)] + [(s.x, s.y) for s in way.legs], way.legs, strict=False):
        assert keep._blocker(a, (b.x, b.y)) is None  # every line is clear now
    assert keep.target_refusal(4.5, 1.5) == (
        "that would take me to 0.5 m from person1, and I keep 1 m from people"
    )
    assert keep.target_refusal(6.8, 1.5) is None
    # a person mid-room with 3 m to keep: the walls leave no way round
    mid = _room(_person(4.0, 3.0))
    tight = KeepAway(lambda: people_at(mid, 0.0), 3.0, limits_of(mid))
    why = tight.reroute((0.5, 3.0), [Setpoint(7.5, 3.0, 1.0, 0.0)])
    assert why == "the way passes closer than 3 m to person1 and there is no room to go round"


async def test_a_command_to_fly_beside_a_person_is_refused_and_the_reason_said() -> None:
    r = dialog_rig(
        seed=2, start=(2.0, 2.0, 0.0), world=_room(_person(6.0, 2.2), distance_m=2.0), people=True
    )
    assert r.rig.takeoff_all()
    res = await r.dm.handle_utterance("go to the person")
    assert not res.accepted
    assert "I keep 2 m from people" in res.reply, res.reply
    assert r.tm.current is None  # nothing flies
    assert r.replies[-1]["level"] == "warn"


def test_a_way_past_a_person_is_flown_round_them() -> None:
    r = dialog_rig(seed=3, start=(1.5, 1.5, 0.0), world=_room(_person(4.0, 1.5)), people=True)
    assert r.rig.takeoff_all()
    d = r.tm.submit([{"action": "waypoints", "waypoints": [{"x": 6.8, "y": 1.5, "z": 1.0}]}])
    assert d[0].accepted, d
    closest, widest = math.inf, 0.0
    for _ in range(4000):
        r.rig.step()
        tr = r.rig.sim.truth
        closest = min(closest, math.hypot(tr.x - 4.0, tr.y - 1.5))
        widest = max(widest, tr.y)
        if r.tm.current is None:
            break
    name, result = r.tm.history[-1][0].name, r.tm.history[-1][1]
    assert name == "waypoints" and result.startswith("Reached"), result
    assert math.hypot(r.rig.sim.truth.x - 6.8, r.rig.sim.truth.y - 1.5) < 0.4
    assert widest > 2.6  # it went round (the straight line is y = 1.5)
    assert closest > 0.9, closest  # never closer than the room's 1 m, less position error


def test_a_person_walking_up_to_a_hovering_drone_makes_it_back_off_and_say_why() -> None:
    walker = _person(7.0, 4.3, Walk(((2.5, 4.3),), 0.5, seed=0))
    r = dialog_rig(seed=4, start=(4.0, 3.8, 0.0), world=_room(walker), people=True)
    assert r.rig.takeoff_all()
    closest = math.inf
    for _ in range(1500):  # 15 s: the walker passes the drone
        r.rig.step()
        tr = r.rig.sim.truth
        p = r.rig.sim.people()[0]
        closest = min(closest, math.hypot(tr.x - p.x, tr.y - p.y))
    said = [x for x in r.replies if x.get("alarm") == "people"]
    assert said, [x["text"] for x in r.replies]
    assert said[0]["level"] == "alert"
    assert re.fullmatch(
        r"person1 is \d\.\d meters from me, closer than the 1 meter I keep from people\. "
        r"Backing off\.",
        said[0]["text"],
    ), said[0]["text"]
    assert closest > 0.6, closest  # it reacted: the walker passes 0.5 m from where it hovered
    rows = [e for e in r.audit.recent(50) if e.action == "ans:people"]
    assert rows and rows[-1].commands[0]["action"] == "waypoints"
    assert r.rig.sim.truth.flying  # backed off, still flying


def test_the_monitor_backs_off_a_hovering_drone_and_holds_once_where_there_is_no_room() -> None:
    from drone.supervisor import Phase
    from drone.supervisor.people import KeepAwayMonitor
    from tests.supervisor.snaps import cmd, snap

    world = _room(_person(4.0, 3.0))
    m = KeepAwayMonitor(KeepAway(lambda: people_at(world, 0.0), 1.0, limits_of(world)))
    assert m.check(snap(x=4.0, y=3.5), Phase.EXECUTING, 0.0) is None  # a task's legs went round
    a = m.check(snap(x=4.0, y=3.5, z=1.0), Phase.AIRBORNE, 0.25)
    assert a is not None and cmd(a) == {
        "action": "waypoints",
        "waypoints": [{"x": 4.0, "y": 5.0, "z": 1.0}],  # straight away, 1 m beyond the metre
    }
    assert m.check(snap(x=4.0, y=3.5), Phase.GROUNDED, 0.5) is None
    boxed = KeepAwayMonitor(KeepAway(lambda: people_at(world, 0.0), 4.5, limits_of(world)))
    held = boxed.check(snap(x=4.0, y=3.2), Phase.AIRBORNE, 0.0)
    assert held is not None and cmd(held) == {"action": "hover"} and "no room" in held.text
    assert boxed.check(snap(x=4.0, y=3.2), Phase.AIRBORNE, 0.25) is None  # told once


def test_a_looping_patrol_flies_the_detour_from_its_start_once_not_every_lap() -> None:
    """The way from where the task started to its first waypoint went round a person; each
    lap after the first goes from the last waypoint straight back to the first (the route),
    not by that detour again (the live patrol left its route every lap for it)."""
    field = replace(load_world("outdoor"), objects=(_person(5.0, 0.0),))  # GPS: no markers
    r = dialog_rig(seed=5, start=(0.0, 0.0, 0.0), world=field, people=True)
    assert r.rig.takeoff_all()
    route = [{"x": 10.0, "y": 0.0, "z": 2.5}, {"x": 10.0, "y": 6.0, "z": 2.5}]
    route.append({"x": 6.0, "y": 6.0, "z": 2.5})
    d = r.tm.submit([{"action": "waypoints", "waypoints": route, "loop": True}])
    assert d[0].accepted, d
    details: dict[int, set[str]] = {}
    west_after_lap_1 = math.inf
    for _ in range(20000):
        r.rig.step()
        task = r.tm.current
        assert task is not None, r.tm.history[-1]
        details.setdefault(task.lap, set()).add(task.detail)
        if task.lap >= 1:
            west_after_lap_1 = min(west_after_lap_1, r.rig.sim.truth.x)
        if task.lap >= 3:
            break
    assert task.lap >= 3, details
    assert "going round person1" in details[0]  # the first way went round
    assert all(not any(d.startswith("going round") for d in details[lap]) for lap in (1, 2))
    assert west_after_lap_1 > 5.0, west_after_lap_1  # never back by the person's side
