"""Geodesy, messages, planner and the CTM's decisions (sans-I/O, synthetic LTM statuses)."""

from __future__ import annotations

import contextlib
import math
from dataclasses import replace
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from server.fleet.ctm import CentralTaskManager, route_distance
from server.fleet.errors import GeoError, MessageError, MissionError, NotFoundError, PlanError
from server.fleet.geo import Enu, Geo, to_enu, to_geo
from server.fleet.messages import DroneRole, FlightPlan, LtmStatus, MissionRequest, PlanKind
from server.fleet.planner import (
    FlightModel,
    StationModel,
    coverage_bound,
    lead_time_s,
    should_dispatch,
    time_to_threshold_s,
)
from tests.support.ltm_status import ltm_status

ORIGIN = Geo(36.367164, 127.363472, 60.0)
SQUARE = (Enu(-15, -15, 5), Enu(15, -15, 5), Enu(15, 15, 5), Enu(-15, 15, 5))


# ---------------------------------------------------------------- geo
def test_geo_known_offsets() -> None:
    # 1e-3 degree of latitude is ~110.9 m at 36° N; of longitude ~89.6 m (WGS-84)
    p = to_enu(Geo(ORIGIN.lat_deg + 1e-3, ORIGIN.lon_deg + 1e-3, 60.0), ORIGIN)
    assert p.y == pytest.approx(110.9, abs=0.3)
    assert p.x == pytest.approx(89.7, abs=0.3)


@settings(max_examples=50, deadline=None)
@given(st.floats(-500, 500), st.floats(-500, 500), st.floats(-50, 200))
def test_geo_roundtrip(x: float, y: float, z: float) -> None:
    back = to_enu(to_geo(Enu(x, y, z), ORIGIN), ORIGIN)
    assert back.dist(Enu(x, y, z)) < 1e-3


@pytest.mark.parametrize(
    ("lat", "lon", "alt"),
    [(91.0, 0.0, 0.0), (0.0, 181.0, 0.0), (math.nan, 0.0, 0.0), (0.0, 0.0, math.inf)],
)
def test_geo_bad_input(lat: float, lon: float, alt: float) -> None:
    with pytest.raises(GeoError):
        Geo(lat, lon, alt)


# ---------------------------------------------------------------- messages
def test_messages_roundtrip() -> None:
    s = ltm_status(plan_id=3, task="waypoints")
    assert LtmStatus.from_dict(s.to_dict()) == s
    p = FlightPlan(7, PlanKind.PATROL, "m1", SQUARE, True, 2, 5.0, 1.0)
    assert FlightPlan.from_dict(p.to_dict()) == p


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"battery_pct": "full"}, "battery_pct"),
        ({"flying": 1}, "flying"),
        ({"name": ""}, "name"),
        ({"station": [0, 0]}, "station"),
        ({"seq": -1}, "seq"),
        ({"x": float("nan")}, "'x'"),
    ],
)
def test_status_bad_fields_named(change: dict[str, Any], field: str) -> None:
    d = ltm_status().to_dict() | change
    with pytest.raises(MessageError, match=field):
        LtmStatus.from_dict(d)


@pytest.mark.parametrize(
    "plan",
    [
        {"plan_id": 1, "kind": "dance"},
        {"plan_id": 1, "kind": "patrol", "route": []},
        {"plan_id": 1, "kind": "patrol", "route": [{"x": 0, "y": 0, "z": 5}], "start_index": 3},
        {"plan_id": "1", "kind": "return"},
        {"plan_id": 1, "kind": "return", "tolerance_m": 0},
        [1, 2],
    ],
)
def test_plan_bad_input(plan: Any) -> None:
    with pytest.raises(MessageError):
        FlightPlan.from_dict(plan)


@settings(max_examples=100, deadline=None)
@given(
    st.dictionaries(
        st.sampled_from([*list(ltm_status().to_dict()), "kind", "route"]),
        st.none() | st.integers() | st.floats() | st.text() | st.booleans(),
    )
)
def test_arbitrary_input_parses_or_raises_message_error(d: dict[str, Any]) -> None:
    for cls in (LtmStatus, FlightPlan):
        with contextlib.suppress(MessageError):
            cls.from_dict(d)


def test_mission_request_validation() -> None:
    with pytest.raises(ValidationError):
        MissionRequest()  # no route
    with pytest.raises(ValidationError):
        MissionRequest(markers=[1], waypoints=[{"lat": 1, "lon": 2}])
    with pytest.raises(ValidationError):
        MissionRequest(markers=[1], handoff_threshold=1.2)
    assert MissionRequest(markers=[1, 2]).handoff_threshold == 0.30


# ---------------------------------------------------------------- planner
def test_planner_timing() -> None:
    m = FlightModel(speed_m_s=2.0, climb_m_s=0.5, takeoff_s=4.0, margin_s=10.0, drain_pct_s=0.5)
    lead = lead_time_s(Enu(0, 0, 0), Enu(20, 0, 5), m)
    assert lead == pytest.approx(4 + 10 + 10 + 10)
    assert time_to_threshold_s(60.0, 30.0, 0.5) == 60.0
    assert not should_dispatch(60.0, 30.0, 0.5, lead)  # 60 s left, 34 s needed
    assert should_dispatch(47.0, 30.0, 0.5, lead)  # 34 s left
    with pytest.raises(PlanError):
        FlightModel(speed_m_s=0)
    with pytest.raises(PlanError):
        StationModel(charge_pct_s=-1)


def test_a_flight_model_follows_the_battery_it_is_given() -> None:
    """``flight_time_s`` (the setting ``serve`` and the vehicles share) sets the drain and scales
    the least shift worth a take-off; the AR.Drone's 720 s gives the defaults."""
    assert FlightModel.for_flight_time(720.0) == FlightModel()
    short = FlightModel.for_flight_time(240.0)
    assert short.drain_pct_s == pytest.approx(100.0 / 240.0)
    assert short.min_shift_s == pytest.approx(20.0)
    for bad in (0.0, -1.0, math.inf, math.nan):
        with pytest.raises(PlanError):
            FlightModel.for_flight_time(bad)


def test_coverage_bound() -> None:
    m = FlightModel()
    b = coverage_bound(Enu(0, 0, 0), SQUARE[0], 0.30, m, StationModel())
    # 504 s usable at 30 %, a 2-min swap: two drones suffice, one covers ~73 %
    assert b.drones_needed == 2
    assert 0.6 < b.coverage_upper[1] < 0.8 and b.coverage_upper[2] == 1.0
    slow = coverage_bound(Enu(0, 0, 0), SQUARE[0], 0.30, m, StationModel(charge_pct_s=0.05))
    assert slow.drones_needed > 3  # charging 70 % at 0.05 %/s takes 23 min
    with pytest.raises(PlanError):
        coverage_bound(Enu(0, 0, 0), SQUARE[0], 1.0, m, StationModel())


def test_route_distance() -> None:
    assert route_distance(Enu(0, -15, 5), SQUARE, True) == pytest.approx(0.0)
    assert route_distance(Enu(0, 0, 5), SQUARE, True) == pytest.approx(15.0)
    # the closing leg wp4 -> wp1 only exists on a loop
    assert route_distance(Enu(-16, 0, 5), SQUARE, True) == pytest.approx(1.0)
    assert route_distance(Enu(-16, 0, 5), SQUARE, False) == pytest.approx(math.hypot(1, 15))


# ---------------------------------------------------------------- CTM decisions
def make_ctm(n: int = 3) -> CentralTaskManager:
    ctm = CentralTaskManager(origin=ORIGIN, lost_after_s=3.0)
    for i in range(n):
        ctm.on_status(ltm_status(f"uav{i + 1}", station=Enu(1.5 * i, 0, 0)), 0.0)
    return ctm


def fly(ctm: CentralTaskManager, name: str, now: float, **kw: Any) -> None:
    rec = ctm.drones[name]
    assert rec.status is not None
    pid = rec.plan.plan_id if rec.plan else 0
    ctm.on_status(replace(rec.status, t=now, plan_id=pid, **kw), now)


def test_ctm_dispatches_relief_at_lead_time_and_hands_over() -> None:
    ctm = make_ctm(2)
    ctm.add_mission(SQUARE, now=0.0)
    first = ctm.step(0.0)
    assert len(first) == 1 and first[0].plan.kind is PlanKind.PATROL
    a = first[0].drone
    b = "uav2" if a == "uav1" else "uav1"
    fly(ctm, a, 1.0, x=-15, y=-15, z=5, flying=True, state="FLYING", battery_pct=95)
    ctm.on_status(replace(ctm.drones[b].status, t=1.0), 1.0)  # type: ignore[arg-type]
    ctm.step(1.0)
    assert ctm.drones[a].role is DroneRole.PATROLLING
    lead = lead_time_s(Enu(0, 0, 0), SQUARE[0], ctm.model)
    drain = ctm.model.drain_pct_s
    t, out = 1.0, []
    battery = 95.0
    while not out:
        t += 1.0
        battery -= drain
        fly(ctm, a, t, x=-15, y=0, z=5, flying=True, state="FLYING", battery_pct=battery)
        ctm.on_status(replace(ctm.drones[b].status, t=t), t)  # type: ignore[arg-type]
        out = ctm.step(t)
    assert out[0].drone == b and ctm.drones[b].role is DroneRole.RELIEVING
    assert battery == pytest.approx(30.0 + lead * drain, abs=2 * drain)
    # the relief reaches the route: handoff, the tired drone goes home
    fly(ctm, b, t + 1, x=-14, y=-15, z=5, flying=True, state="FLYING", battery_pct=99)
    fly(ctm, a, t + 1, x=-15, y=0, z=5, flying=True, state="FLYING", battery_pct=battery)
    out = ctm.step(t + 1)
    assert [(d.drone, d.plan.kind) for d in out] == [(a, PlanKind.RETURN)]
    assert ctm.drones[a].role is DroneRole.RETURNING and ctm.drones[b].role is DroneRole.PATROLLING
    assert ctm.missions["m1"].handoffs == 1
    fly(ctm, a, t + 30, flying=False, state="LANDED", battery_pct=28)
    fly(ctm, b, t + 30, x=0, y=-15, z=5, flying=True, state="FLYING", battery_pct=90)
    ctm.step(t + 30)
    assert ctm.drones[a].role is DroneRole.CHARGING
    fly(ctm, a, t + 150, flying=False, state="LANDED", battery_pct=100)
    fly(ctm, b, t + 150, x=0, y=-15, z=5, flying=True, state="FLYING", battery_pct=80)
    ctm.step(t + 150)
    assert ctm.drones[a].role is DroneRole.IDLE


@pytest.mark.parametrize(
    ("failure", "reason"),
    [({"emergency": True}, "emergency"), ({"link_ok": False}, "drone link lost"), (None, "silent")],
)
def test_ctm_replaces_failed_drone(failure: dict[str, Any] | None, reason: str) -> None:
    ctm = make_ctm(3)
    ctm.add_mission(SQUARE, now=0.0)
    a = ctm.step(0.0)[0].drone
    fly(ctm, a, 1.0, x=-15, y=-15, z=5, flying=True, state="FLYING", battery_pct=90)
    for r in ctm.drones.values():
        if r.name != a:
            ctm.on_status(replace(r.status, t=1.0), 1.0)  # type: ignore[arg-type]
    ctm.step(1.0)
    others = [r for r in ctm.drones.values() if r.name != a]
    t = 2.0 if failure else 5.0
    if failure:
        fly(ctm, a, t, **failure)
    if reason == "drone link lost":
        # a blip is not a loss: its drone link must stay down as long as a silence would
        assert ctm.step(t) == [] and ctm.drones[a].role is DroneRole.PATROLLING
        t = 5.0
        fly(ctm, a, t, x=-15, y=-15, z=5, flying=True, state="FLYING", **failure)
    for r in others:
        ctm.on_status(replace(r.status, t=t), t)  # type: ignore[arg-type]
    out = ctm.step(t)
    assert ctm.drones[a].role is DroneRole.LOST and ctm.drones[a].lost_reason == reason
    assert len(out) == 1 and out[0].drone != a and out[0].plan.kind is PlanKind.PATROL
    assert ctm.missions["m1"].replacements == 1
    # back and still flying: its post went to another, so it is sent home
    healthy = {"emergency": False, "link_ok": True}
    fly(ctm, a, t + 1, x=-15, y=-15, z=5, flying=True, state="FLYING", **healthy)
    back = ctm.step(t + 1)
    assert [(d.drone, d.plan.kind) for d in back if d.drone == a] == [(a, PlanKind.RETURN)]
    assert ctm.drones[a].role is DroneRole.RETURNING


def test_ctm_more_drones_than_routes_and_two_missions() -> None:
    ctm = make_ctm(4)
    ctm.add_mission(SQUARE, now=0.0)
    ctm.add_mission([Enu(30, 30, 8), Enu(40, 30, 8)], now=0.0, threshold=0.5)
    out = ctm.step(0.0)
    assert len(out) == 2 and len({d.drone for d in out}) == 2
    assert {d.plan.mission for d in out} == {"m1", "m2"}
    idle = [r for r in ctm.drones.values() if r.role is DroneRole.IDLE]
    assert len(idle) == 2
    info = ctm.mission_info("m2")
    assert info["handoff_threshold"] == 0.5 and len(info["route_geo"]) == 2
    status_msg = ctm.fleet_status(0.0)
    assert [d["name"] for d in status_msg["drones"]] == ["uav1", "uav2", "uav3", "uav4"]
    assert {d["role"] for d in status_msg["drones"]} == {"relieving", "idle"}


def test_ctm_bad_missions() -> None:
    ctm = make_ctm(1)
    with pytest.raises(MissionError):
        ctm.add_mission([], now=0.0)
    with pytest.raises(MissionError):
        ctm.add_mission(SQUARE, now=0.0, threshold=0.0)
    with pytest.raises(MissionError, match="marker"):
        ctm.mission_from_request(MissionRequest(markers=[3]), 0.0)  # no world
    with pytest.raises(NotFoundError):
        ctm.mission_info("nope")
    no_gps = CentralTaskManager()
    with pytest.raises(MissionError, match="GPS"):
        no_gps.mission_from_request(MissionRequest(waypoints=[{"lat": 36.0, "lon": 127.0}]), 0)


def test_ctm_leaves_a_manually_flown_drone_alone() -> None:
    """A drone flying without any plan from the CTM is an operator's flight: not sent home."""
    ctm = make_ctm(1)
    for t in range(0, 30):
        fly(ctm, "uav1", float(t), flying=True, z=1.2)
        assert ctm.step(float(t)) == []
    # nor after a link lost or a silence while it flies (the drone was never the CTM's)
    fly(ctm, "uav1", 30.0, flying=True, z=1.2, link_ok=False)
    assert ctm.step(30.0) == [] and ctm.drones["uav1"].role is DroneRole.IDLE  # a blip
    fly(ctm, "uav1", 33.0, flying=True, z=1.2, link_ok=False)
    assert ctm.step(33.0) == [] and ctm.drones["uav1"].role is DroneRole.LOST
    assert ctm.drones["uav1"].lost_reason == "drone link lost"
    fly(ctm, "uav1", 34.0, flying=True, z=1.2, link_ok=True)
    assert ctm.step(34.0) == [] and ctm.drones["uav1"].role is DroneRole.IDLE
    fly(ctm, "uav1", 35.0, flying=True, z=1.2, link_ok=True)
    assert ctm.step(40.0) == [] and ctm.drones["uav1"].role is DroneRole.LOST  # silent
    for t in range(41, 50):
        fly(ctm, "uav1", float(t), flying=True, z=1.2)
        assert ctm.step(float(t)) == []
    assert ctm.drones["uav1"].role is DroneRole.IDLE and ctm.drones["uav1"].plan is None
