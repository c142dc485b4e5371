"""ANS monitors: thresholds, latching, periods, and the SNS transition table."""

from __future__ import annotations

import pytest

from server.dialog.autonomic import (
    AltitudeMonitor,
    Autonomic,
    BatteryMonitor,
    LinkMonitor,
    MarkersLostMonitor,
)
from server.dialog.errors import IllegalTransition
from server.dialog.monitors import NavdataMonitor
from server.dialog.ports import VehicleSnapshot
from server.dialog.states import TRANSITIONS, State, next_state
from server.language.nlu import NLU


def snap(**kw: object) -> VehicleSnapshot:
    base = {"battery_pct": 80.0, "altitude_m": 1.0, "flying": True}
    base.update(kw)
    return VehicleSnapshot(**base)  # type: ignore[arg-type]


def test_battery_low_then_critical_fire_once_each() -> None:
    m = BatteryMonitor(25, 12)
    assert m.check(snap(battery_pct=30), State.EXECUTING, 0) is None
    low = m.check(snap(battery_pct=24), State.EXECUTING, 1)
    assert low is not None and low.level == "warn" and low.action == {"action": "return_home"}
    assert m.check(snap(battery_pct=23), State.RETURNING, 2) is None  # latched
    crit = m.check(snap(battery_pct=11), State.RETURNING, 3)
    assert crit is not None and crit.level == "alert" and crit.action == {"action": "land"}
    assert m.check(snap(battery_pct=10), State.LANDING, 4) is None
    # recharged above low + hysteresis: re-armed
    assert m.check(snap(battery_pct=90, flying=False), State.LANDED, 5) is None
    again = m.check(snap(battery_pct=20, flying=False), State.LANDED, 6)
    assert again is not None and again.action is None  # on the ground: tell, do not fly home


def test_a_doubted_stream_defers_the_battery_action_until_it_is_trusted() -> None:
    """Readings the driver may not trust: tell, hover (the navdata monitor), act once trusted."""
    m = BatteryMonitor(25, 12)
    doubt = "packets that do not follow the drone's navdata sequence"
    low = m.check(snap(battery_pct=24, navdata_doubt=doubt), State.AIRBORNE_IDLE, 0)
    assert low is not None and low.action is None and "doubt" in low.text
    crit = m.check(snap(battery_pct=11, navdata_doubt=doubt), State.AIRBORNE_IDLE, 1)
    assert crit is not None and crit.action is None and crit.level == "alert"
    assert "land" in crit.text.lower()  # the operator is asked
    assert m.check(snap(battery_pct=11, navdata_doubt=doubt), State.AIRBORNE_IDLE, 2) is None
    trusted = m.check(snap(battery_pct=11), State.AIRBORNE_IDLE, 3)
    assert trusted is not None and trusted.action == {"action": "land"}
    assert m.check(snap(battery_pct=11), State.LANDING, 4) is None
    # deferred low, trusted again while still low: home
    m2 = BatteryMonitor(25, 12)
    assert m2.check(snap(battery_pct=24, navdata_doubt=doubt), State.EXECUTING, 0) is not None
    home = m2.check(snap(battery_pct=24), State.AIRBORNE_IDLE, 1)
    assert home is not None and home.action == {"action": "return_home"}
    # deferred, then landed by the operator: nothing more to do
    m3 = BatteryMonitor(25, 12)
    assert m3.check(snap(battery_pct=11, navdata_doubt=doubt), State.AIRBORNE_IDLE, 0)
    assert m3.check(snap(battery_pct=11, flying=False), State.LANDED, 1) is None


def test_the_navdata_monitor_hovers_and_asks_once_per_episode() -> None:
    m = NavdataMonitor()
    doubt = "battery readings that no discharge or sag explains"
    assert m.check(snap(), State.EXECUTING, 0) is None
    a = m.check(snap(navdata_doubt=doubt), State.EXECUTING, 1)
    assert a is not None and a.level == "alert" and a.action == {"action": "hover"}
    assert a.text.startswith("Navdata inconsistent: sensor fault or spoofing: " + doubt)
    assert "say land" in a.text.lower()
    assert m.check(snap(navdata_doubt=doubt), State.AIRBORNE_IDLE, 2) is None  # latched
    back = m.check(snap(), State.AIRBORNE_IDLE, 3)
    assert back is not None and back.level == "info" and back.action is None
    grounded = m.check(snap(navdata_doubt=doubt, flying=False), State.LANDED, 4)
    assert grounded is not None and grounded.action is None  # on the ground: tell only
    assert m.check(snap(navdata_doubt=doubt, flying=False), State.LANDED, 5) is None
    # took off while the doubt lasts: hover and ask then
    up = m.check(snap(navdata_doubt=doubt), State.AIRBORNE_IDLE, 6)
    assert up is not None and up.action == {"action": "hover"}


def test_altitude_ceiling_descends_under_it() -> None:
    m = AltitudeMonitor(2.8)
    a = m.check(snap(altitude_m=3.2), State.EXECUTING, 0)
    assert a is not None and a.action == {"action": "move", "direction": "down", "distance": 0.6}
    assert m.check(snap(altitude_m=3.1), State.EXECUTING, 1) is None
    assert m.check(snap(altitude_m=2.0), State.EXECUTING, 2) is None
    assert m.check(snap(altitude_m=3.0), State.EXECUTING, 3) is not None


def test_link_loss_and_recovery() -> None:
    m = LinkMonitor()
    lost = m.check(snap(link_ok=False), State.EXECUTING, 0)
    assert lost is not None and lost.level == "alert"
    assert m.check(snap(link_ok=False), State.EXECUTING, 1) is None
    back = m.check(snap(link_ok=True), State.EXECUTING, 2)
    assert back is not None and back.level == "info"


def test_link_loss_says_it_hovers_only_in_flight() -> None:
    flying = LinkMonitor().check(snap(link_ok=False, flying=True), State.EXECUTING, 0)
    assert flying is not None and "hover on its own" in flying.text
    landed = LinkMonitor().check(snap(link_ok=False, flying=False), State.LANDED, 0)
    assert landed is not None and landed.level == "alert"
    assert "hover" not in landed.text and "on the ground" in landed.text


def test_markers_lost_after_delay_only_while_executing() -> None:
    m = MarkersLostMonitor(1.5)
    assert m.check(snap(), State.EXECUTING, 0.0) is None
    assert m.check(snap(), State.EXECUTING, 1.0) is None
    assert m.check(snap(), State.EXECUTING, 1.6) is not None
    assert m.check(snap(), State.EXECUTING, 2.0) is None
    lost = m.check(snap(), State.EXECUTING, 1.6 + 1e-9)  # (told above: not again)
    assert lost is None
    found = m.check(snap(visible_markers=(3,)), State.EXECUTING, 2.5)
    assert found is not None and found.level == "info" and "marker 3 again" in found.text
    assert m.check(snap(visible_markers=(3,)), State.EXECUTING, 3.0) is None
    assert m.check(snap(), State.AIRBORNE_IDLE, 9.0) is None
    # never a claim of searching: the task manager decides and says so (issue 13 item 8)
    m2 = MarkersLostMonitor(1.5)
    m2.check(snap(), State.EXECUTING, 0.0)
    told = m2.check(snap(), State.EXECUTING, 2.0)
    assert told is not None and "search" not in told.text
    assert m2.check(snap(), State.SEARCHING, 3.0) is None


def test_each_monitor_runs_on_its_own_period() -> None:
    calls: dict[str, list[float]] = {"a": [], "b": []}

    class Counting:
        def __init__(self, name: str, period_s: float) -> None:
            self.name, self.period_s = name, period_s

        def check(self, s: VehicleSnapshot, st: State, now: float) -> None:
            calls[self.name].append(now)

    ans = Autonomic([Counting("a", 0.5), Counting("b", 1.0)])
    for i in range(21):
        ans.step(snap(), State.EXECUTING, i * 0.1)
    assert calls["a"] == pytest.approx([0.0, 0.5, 1.0, 1.5, 2.0])
    assert calls["b"] == pytest.approx([0.0, 1.0, 2.0])
    # periods are kept by name: two monitors of one name are refused, not one silently muted
    with pytest.raises(ValueError, match="repeated: a"):
        Autonomic([Counting("a", 0.5), Counting("a", 0.25)])


def test_transition_table_is_complete_and_strict() -> None:
    assert set(TRANSITIONS) == set(State)
    assert next_state(State.LANDED, "takeoff") is State.TAKING_OFF
    with pytest.raises(IllegalTransition) as exc:
        next_state(State.LANDED, "land")
    assert exc.value.reason == "I am already on the ground."
    # every state of the machine has its active grammars in states.xml
    assert set(NLU().grammar.states) == {s.value for s in State}
