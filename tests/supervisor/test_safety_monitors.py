"""The supervisor in lockstep with a dialog that speaks it: no battery alarm before a battery
reading, the world's ceiling (not a global number), the estimator disagreeing with the sensors,
the jog limited near a wall — each told to the operator once, with the reason."""

from __future__ import annotations

import pytest

from drone.lockstep import LockstepRig
from drone.sim.world import load_world
from drone.supervisor import Phase
from drone.supervisor.altitude import ceiling_of
from drone.supervisor.estimator import SensorAgreementMonitor
from drone.supervisor.jog import JogLimitMonitor
from server.dialog.adapters import TaskManagerPort, VehicleAdapter
from server.dialog.manager import DialogManager
from server.graph import Graph
from server.settings import Settings
from server.tasks import TaskManager
from tests.supervisor.snaps import snap, supervised


def _dialog(world_name: str, **rig_kw: object) -> tuple[LockstepRig, TaskManager, DialogManager]:
    world = load_world(world_name)
    rig = LockstepRig(world, seed=5, camera=False, **rig_kw)  # type: ignore[arg-type]
    tm = TaskManager(rig.vehicle, world, rig.clock)
    rig.add_stepper(lambda now, dt: tm.step(now))
    dm = DialogManager(
        Graph(),
        Settings(),
        TaskManagerPort(tm),
        VehicleAdapter(rig.vehicle, world),
        None,
        None,
        rig.clock.now,
    )
    rig.add_stepper(lambda now, dt: dm.step(now))
    supervised(rig, tm, world, dm)
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


def test_the_supervisor_watches_the_world_ceiling() -> None:
    indoor, outdoor = load_world("indoor"), load_world("outdoor")
    assert ceiling_of(None, indoor) == pytest.approx(2.7)  # the room's 3 m less the clearance
    assert ceiling_of(None, outdoor) == pytest.approx(20.0)  # the field's own limit
    assert ceiling_of(4.0, outdoor) == pytest.approx(4.0)  # a setting may only lower it
    assert ceiling_of(40.0, outdoor) == pytest.approx(20.0)


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
    m = SensorAgreementMonitor()
    ok = snap(battery_pct=50.0)
    bad = snap(battery_pct=50.0, estimator_disagreement=("altitude",))
    reset = snap(battery_pct=50.0, estimator_reinits=1)
    assert m.check(ok, Phase.EXECUTING, 0.0) is None
    alarm = m.check(bad, Phase.EXECUTING, 0.25)
    assert alarm is not None and alarm.severity == "alert" and "(altitude)" in alarm.text
    assert m.check(bad, Phase.EXECUTING, 0.5) is None  # latched
    alarm = m.check(reset, Phase.EXECUTING, 0.75)
    assert alarm is not None and "reset it" in alarm.text
    assert m.check(reset, Phase.EXECUTING, 1.0) is None


def test_jog_limit_monitor_says_why() -> None:
    m = JogLimitMonitor()
    slowed = snap(battery_pct=50.0, jog_limit="slowed 0.6 m from the wall")
    stopped = snap(battery_pct=50.0, jog_limit="stopped 0.1 m from the wall")
    a = m.check(slowed, Phase.AIRBORNE, 0.0)
    assert a is not None and a.text == "Jog limited: slowed 0.6 m from the wall."
    assert m.check(slowed, Phase.AIRBORNE, 0.25) is None
    b = m.check(stopped, Phase.AIRBORNE, 0.5)
    assert b is not None and "stopped" in b.text
    assert m.check(snap(battery_pct=50.0), Phase.AIRBORNE, 0.75) is None


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
