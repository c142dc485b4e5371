"""The supervisor's monitors: thresholds, latching, periods."""

from __future__ import annotations

from dataclasses import replace

import pytest

from drone.supervisor import Phase, Supervisor
from drone.supervisor.altitude import AltitudeMonitor
from drone.supervisor.battery import BatteryMonitor
from drone.supervisor.estimator import EstimatorMonitor
from drone.supervisor.geofence import GeofenceMonitor
from drone.supervisor.link import LinkMonitor
from drone.supervisor.markers import MarkersLostMonitor
from drone.supervisor.navdata import NavdataMonitor
from drone.vehicle import VehicleSnapshot
from tests.supervisor.snaps import cmd, snap


def test_battery_low_then_critical_fire_once_each() -> None:
    m = BatteryMonitor(25, 12)
    assert m.check(snap(battery_pct=30), Phase.EXECUTING, 0) is None
    low = m.check(snap(battery_pct=24), Phase.EXECUTING, 1)
    assert low is not None and low.severity == "warn" and cmd(low) == {"action": "return_home"}
    assert m.check(snap(battery_pct=23), Phase.RETURNING, 2) is None  # latched
    crit = m.check(snap(battery_pct=11), Phase.RETURNING, 3)
    assert crit is not None and crit.severity == "alert" and cmd(crit) == {"action": "land"}
    assert m.check(snap(battery_pct=10), Phase.LANDING, 4) is None
    # recharged above low + hysteresis: re-armed
    assert m.check(snap(battery_pct=90, flying=False), Phase.GROUNDED, 5) is None
    again = m.check(snap(battery_pct=20, flying=False), Phase.GROUNDED, 6)
    assert again is not None and again.action is None  # on the ground: tell, do not fly home


def test_a_doubted_stream_defers_the_battery_action_until_it_is_trusted() -> None:
    """Readings the driver may not trust: tell, hover (the navdata monitor), act once trusted."""
    m = BatteryMonitor(25, 12)
    doubt = "packets that do not follow the drone's navdata sequence"
    low = m.check(snap(battery_pct=24, navdata_doubt=doubt), Phase.AIRBORNE, 0)
    assert low is not None and low.action is None and "doubt" in low.text
    crit = m.check(snap(battery_pct=11, navdata_doubt=doubt), Phase.AIRBORNE, 1)
    assert crit is not None and crit.action is None and crit.severity == "alert"
    assert "land" in crit.text.lower()  # the operator is asked
    assert m.check(snap(battery_pct=11, navdata_doubt=doubt), Phase.AIRBORNE, 2) is None
    trusted = m.check(snap(battery_pct=11), Phase.AIRBORNE, 3)
    assert trusted is not None and cmd(trusted) == {"action": "land"}
    assert m.check(snap(battery_pct=11), Phase.LANDING, 4) is None
    # deferred low, trusted again while still low: home
    m2 = BatteryMonitor(25, 12)
    assert m2.check(snap(battery_pct=24, navdata_doubt=doubt), Phase.EXECUTING, 0) is not None
    home = m2.check(snap(battery_pct=24), Phase.AIRBORNE, 1)
    assert home is not None and cmd(home) == {"action": "return_home"}
    # deferred, then landed by the operator: nothing more to do
    m3 = BatteryMonitor(25, 12)
    assert m3.check(snap(battery_pct=11, navdata_doubt=doubt), Phase.AIRBORNE, 0)
    assert m3.check(snap(battery_pct=11, flying=False), Phase.GROUNDED, 1) is None


def test_the_navdata_monitor_hovers_and_asks_once_per_episode() -> None:
    m = NavdataMonitor()
    doubt = "battery readings that no discharge or sag explains"
    assert m.check(snap(), Phase.EXECUTING, 0) is None
    a = m.check(snap(navdata_doubt=doubt), Phase.EXECUTING, 1)
    assert a is not None and a.severity == "alert" and cmd(a) == {"action": "hover"}
    assert a.text.startswith("Navdata inconsistent: sensor fault or spoofing: " + doubt)
    assert "say land" in a.text.lower()
    assert m.check(snap(navdata_doubt=doubt), Phase.AIRBORNE, 2) is None  # latched
    back = m.check(snap(), Phase.AIRBORNE, 3)
    assert back is not None and back.severity == "info" and back.action is None
    grounded = m.check(snap(navdata_doubt=doubt, flying=False), Phase.GROUNDED, 4)
    assert grounded is not None and grounded.action is None  # on the ground: tell only
    assert m.check(snap(navdata_doubt=doubt, flying=False), Phase.GROUNDED, 5) is None
    # took off while the doubt lasts: hover and ask then
    up = m.check(snap(navdata_doubt=doubt), Phase.AIRBORNE, 6)
    assert up is not None and cmd(up) == {"action": "hover"}


def test_altitude_ceiling_descends_under_it() -> None:
    m = AltitudeMonitor(2.8)
    a = m.check(snap(altitude_m=3.2), Phase.EXECUTING, 0)
    assert a is not None and cmd(a) == {"action": "move", "direction": "down", "distance": 0.6}
    assert m.check(snap(altitude_m=3.1), Phase.EXECUTING, 1) is None
    assert m.check(snap(altitude_m=2.0), Phase.EXECUTING, 2) is None
    assert m.check(snap(altitude_m=3.0), Phase.EXECUTING, 3) is not None


def test_link_loss_and_recovery() -> None:
    m = LinkMonitor()
    lost = m.check(snap(link_ok=False), Phase.EXECUTING, 0)
    assert lost is not None and lost.severity == "alert"
    assert m.check(snap(link_ok=False), Phase.EXECUTING, 1) is None
    back = m.check(snap(link_ok=True), Phase.EXECUTING, 2)
    assert back is not None and back.severity == "info"


def test_link_loss_says_it_hovers_only_in_flight() -> None:
    flying = LinkMonitor().check(snap(link_ok=False, flying=True), Phase.EXECUTING, 0)
    assert flying is not None and "hover on its own" in flying.text
    landed = LinkMonitor().check(snap(link_ok=False, flying=False), Phase.GROUNDED, 0)
    assert landed is not None and landed.severity == "alert"
    assert "hover" not in landed.text and "on the ground" in landed.text


def test_markers_lost_after_delay_only_while_executing() -> None:
    m = MarkersLostMonitor(1.5)
    assert m.check(snap(), Phase.EXECUTING, 0.0) is None
    assert m.check(snap(), Phase.EXECUTING, 1.0) is None
    assert m.check(snap(), Phase.EXECUTING, 1.6) is not None
    assert m.check(snap(), Phase.EXECUTING, 2.0) is None
    lost = m.check(snap(), Phase.EXECUTING, 1.6 + 1e-9)  # (told above: not again)
    assert lost is None
    found = m.check(snap(markers=(3,)), Phase.EXECUTING, 2.5)
    assert found is not None and found.severity == "info" and "marker 3 again" in found.text
    assert m.check(snap(markers=(3,)), Phase.EXECUTING, 3.0) is None
    assert m.check(snap(), Phase.AIRBORNE, 9.0) is None
    # never a claim of searching: the task manager decides and says so (issue 13 item 8)
    m2 = MarkersLostMonitor(1.5)
    m2.check(snap(), Phase.EXECUTING, 0.0)
    told = m2.check(snap(), Phase.EXECUTING, 2.0)
    assert told is not None and "search" not in told.text
    assert m2.check(snap(), Phase.SEARCHING, 3.0) is None


def test_each_monitor_runs_on_its_own_period() -> None:
    calls: dict[str, list[float]] = {"a": [], "b": []}

    class Counting:
        def __init__(self, name: str, period_s: float) -> None:
            self.name, self.period_s = name, period_s

        def check(self, s: VehicleSnapshot, st: Phase, now: float) -> None:
            calls[self.name].append(now)

    ans = Supervisor([Counting("a", 0.5), Counting("b", 1.0)], snap, lambda s: Phase.EXECUTING)
    for i in range(21):
        ans.step(i * 0.1)
    assert calls["a"] == pytest.approx([0.0, 0.5, 1.0, 1.5, 2.0])
    assert calls["b"] == pytest.approx([0.0, 1.0, 2.0])
    # periods are kept by name: two monitors of one name are refused, not one silently muted
    with pytest.raises(ValueError, match="repeated: a"):
        Supervisor([Counting("a", 0.5), Counting("a", 0.25)], snap, lambda s: Phase.AIRBORNE)


def test_geofence_alerts_and_hovers_once_then_clears() -> None:
    fence = GeofenceMonitor(0.0, 8.0, 0.0, 6.0)
    inside = snap(x=4.0, y=3.0)
    outside = replace(inside, x=8.4)
    assert fence.check(inside, Phase.EXECUTING, 0.0) is None
    alarm = fence.check(outside, Phase.EXECUTING, 0.5)
    assert alarm is not None and alarm.severity == "alert" and cmd(alarm) == {"action": "hover"}
    assert "Geofence" in alarm.text and "8.4" in alarm.text
    assert fence.check(outside, Phase.AIRBORNE, 1.0) is None  # latched: told once
    back = fence.check(inside, Phase.AIRBORNE, 1.5)
    assert back is not None and back.severity == "info"
    # No fix, no fence: an unlocalised estimate is not a position.
    assert fence.check(replace(outside, localised=False), Phase.EXECUTING, 2.0) is None
    assert fence.check(outside, Phase.GROUNDED, 2.5) is None


def test_estimator_trouble_is_told_after_a_while_and_when_it_is_over() -> None:
    mon = EstimatorMonitor(lost_after_s=5.0)
    lost = snap(localised=False)
    assert mon.check(lost, Phase.AIRBORNE, 0.0) is None
    assert mon.check(lost, Phase.AIRBORNE, 4.9) is None
    alarm = mon.check(lost, Phase.AIRBORNE, 5.0)
    assert alarm is not None and alarm.severity == "warn" and "no position fix" in alarm.text
    assert mon.check(lost, Phase.AIRBORNE, 6.0) is None
    fixed = replace(lost, localised=True, position_sigma_m=0.05)
    again = mon.check(fixed, Phase.AIRBORNE, 6.5)
    assert again is not None and again.severity == "info"
    vague = replace(fixed, position_sigma_m=1.4)
    mon.check(vague, Phase.EXECUTING, 10.0)
    alarm = mon.check(vague, Phase.EXECUTING, 15.0)
    assert alarm is not None and "1.4 meters" in alarm.text
    assert EstimatorMonitor().check(lost, Phase.GROUNDED, 99.0) is None
