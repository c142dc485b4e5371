"""Issue 13 §1, §2, §3, §4 on the ANS side: no battery alarm before a battery reading, the
world's ceiling (not a global number), the estimator disagreeing with the sensors, the jog
limited near a wall — each told to the operator once, with the reason."""

from __future__ import annotations

import pytest

from drone.lockstep import LockstepRig
from drone.sim.world import load_world
from server.dialog.adapters import TaskManagerPort, VehiclePort
from server.dialog.manager import DialogManager
from server.dialog.ports import VehicleSnapshot
from server.dialog.safety_monitors import EstimatorMonitor, JogLimitMonitor, ans_ceiling_m
from server.dialog.states import State
from server.graph import Graph
from server.settings import Settings
from server.tasks import TaskManager


def _dialog(world_name: str, **rig_kw: object) -> tuple[LockstepRig, TaskManager, DialogManager]:
    world = load_world(world_name)
    rig = LockstepRig(world, seed=5, camera=False, **rig_kw)  # type: ignore[arg-type]
    tm = TaskManager(rig.vehicle, world, rig.clock)
    rig.add_stepper(lambda now, dt: tm.step(now))
    dm = DialogManager(
        Graph(),
        Settings(),
        TaskManagerPort(tm),
        VehiclePort(rig.vehicle, world),
        None,
        None,
        rig.clock.now,
    )
    rig.add_stepper(lambda now, dt: dm.step(now))
    return rig, tm, dm


def test_no_battery_alarm_while_navdata_carries_no_battery_reading() -> None:
    """The link comes up on bootstrap navdata (no demo option, so no battery reading): before
    the fix the ANS said "Battery critical at 0 percent" right then."""
    rig, _, dm = _dialog("indoor")
    assert rig.run_until(lambda: rig.vehicle.snapshot().link_ok, 3.0)
    assert not rig.vehicle.snapshot().battery_known  # still bootstrap: no reading yet
    rig.run(3.0)  # through the handshake into demo navdata
    assert rig.vehicle.snapshot().battery_known
    assert [r["text"] for r in dm.replies if "Battery" in r["text"]] == []


def test_a_real_low_battery_is_still_told() -> None:
    rig, _, dm = _dialog("indoor")
    rig.run(3.0)
    rig.sim.physics.battery.drain_to(10.0)
    rig.run(2.0)
    texts = [r["text"] for r in dm.replies if "Battery" in r["text"]]
    assert texts == ["Battery critical at 10 percent. Do not take off."]


def test_the_ans_watches_the_world_ceiling() -> None:
    indoor = VehiclePort(None, load_world("indoor"))
    outdoor = VehiclePort(None, load_world("outdoor"))
    assert indoor.ceiling_m == pytest.approx(2.7)  # the room's 3 m less the clearance
    assert outdoor.ceiling_m == pytest.approx(20.0)  # the field's own limit
    assert ans_ceiling_m(None, outdoor) == pytest.approx(20.0)
    assert ans_ceiling_m(4.0, outdoor) == pytest.approx(4.0)  # a setting may only lower it
    assert ans_ceiling_m(40.0, outdoor) == pytest.approx(20.0)


def test_outdoor_cruise_at_5_m_is_not_replaced_by_move_down() -> None:
    """Before: the global 2.8 m ceiling replaced an outdoor task at 5 m with "move down"."""
    rig, tm, dm = _dialog("outdoor", starts=[(0.0, 0.0, 0.0)])
    assert rig.takeoff_all()
    rig.run(0.5)
    d = tm.submit([{"action": "waypoints", "waypoints": [{"x": 0.0, "y": 0.0, "z": 5.0}]}])
    assert d[0].accepted, d
    assert rig.run_until(lambda: rig.sim.truth.z > 4.8, 20.0)
    rig.run(2.0)
    assert [r["text"] for r in dm.replies if "ceiling" in r["text"]] == []
    assert tm.current is None and tm.history[-1][0].name == "waypoints"
    assert tm.history[-1][1].startswith("Reached")


def test_estimator_monitor_tells_once_per_episode() -> None:
    m = EstimatorMonitor()
    ok = VehicleSnapshot(50.0, 1.0, True)
    bad = VehicleSnapshot(50.0, 1.0, True, estimator_disagreement=("altitude",))
    reset = VehicleSnapshot(50.0, 1.0, True, estimator_reinits=1)
    assert m.check(ok, State.EXECUTING, 0.0) is None
    alarm = m.check(bad, State.EXECUTING, 0.25)
    assert alarm is not None and alarm.level == "alert" and "(altitude)" in alarm.text
    assert m.check(bad, State.EXECUTING, 0.5) is None  # latched
    alarm = m.check(reset, State.EXECUTING, 0.75)
    assert alarm is not None and "reset it" in alarm.text
    assert m.check(reset, State.EXECUTING, 1.0) is None


def test_jog_limit_monitor_says_why() -> None:
    m = JogLimitMonitor()
    slowed = VehicleSnapshot(50.0, 1.0, True, jog_limit="slowed 0.6 m from the wall")
    stopped = VehicleSnapshot(50.0, 1.0, True, jog_limit="stopped 0.1 m from the wall")
    a = m.check(slowed, State.AIRBORNE_IDLE, 0.0)
    assert a is not None and a.text == "Jog limited: slowed 0.6 m from the wall."
    assert m.check(slowed, State.AIRBORNE_IDLE, 0.25) is None
    b = m.check(stopped, State.AIRBORNE_IDLE, 0.5)
    assert b is not None and "stopped" in b.text
    assert m.check(VehicleSnapshot(50.0, 1.0, True), State.AIRBORNE_IDLE, 0.75) is None


def test_the_operator_is_alerted_when_the_estimate_disagrees_with_the_sensors() -> None:
    """A vehicle whose EKF is confidently wrong about its height (as after a lock-out): the
    ultrasound is gated out a few times (alert), then the height restarts from it (alert)."""
    rig, _, dm = _dialog("indoor")
    assert rig.takeoff_all()
    rig.run(1.0)
    tr = rig.sim.truth
    rig.vehicle.ekf.reset(rig.clock.now(), tr.x, tr.y, tr.z + 1.5, tr.yaw_rad, pos_sigma=0.01)
    rig.run(1.5)
    alerts = [r["text"] for r in dm.replies if r["level"] == "alert"]
    assert any("disagrees with the drone's sensors (altitude" in t for t in alerts), alerts
    assert any("I reset it from them" in t for t in alerts), alerts
    assert abs(rig.vehicle.ekf.latest.z - rig.sim.truth.z) < 0.05
