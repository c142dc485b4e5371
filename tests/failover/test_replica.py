"""The CTM's replica (server.fleet.replica): a CTM restored from the JSON of another's snapshot
decides as the first one would have, so a standby resumes a mission where it stands."""

from __future__ import annotations

import json
import math
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from experiments.patrol import LockstepLink, PatrolConfig, PatrolExperiment, PatrolReport
from server.fleet.ctm import CentralTaskManager, DroneRecord
from server.fleet.errors import MessageError
from server.fleet.geo import Enu
from server.fleet.messages import DroneRole, FlightPlan, LtmStatus, PlanKind
from server.fleet.replica import PLAN_ID_MARGIN, restore, snapshot
from tests.support.ltm_status import ltm_status

FAST = {"flight_time_s": 150.0, "swap_s": 20.0}
SWITCH_AT_S = 100.0  # mid-shift: the first drone patrols, its relief is not sent yet


def fresh_like(exp: PatrolExperiment) -> CentralTaskManager:
    old = exp.ctm
    return CentralTaskManager(
        model=old.model,
        stations=old.stations,
        lost_after_s=old.lost_after_s,
        corridor_m=old.corridor_m,
        origin=old.origin,
        world=old.world,
        continuity=old.continuity,
    )


def fly(switch_at: float | None) -> tuple[PatrolExperiment, PatrolReport, list[Any]]:
    """The paper's patrol with 2 drones; at ``switch_at`` the CTM is replaced by a new one
    restored from the JSON of its snapshot (the standby's takeover, without the bus)."""
    exp = PatrolExperiment(PatrolConfig(drones=2, duration_s=260.0, **FAST))
    sent: list[Any] = []
    switched: list[float] = []

    class Recording(LockstepLink):
        """The lockstep link, noting every plan the CTM (whichever) sends, and when."""

        def ctm_step(self, now: float) -> None:
            out = self.ctm.step(now)
            sent.extend((round(now, 1), d.drone, d.plan.kind.value) for d in out)
            for d in out:
                ok, reason = self.ltms[d.drone].apply_plan(d.plan, now)
                self.ctm.on_plan_result(d.drone, d.plan.plan_id, ok, reason, now)
            for ltm in self.ltms.values():
                ltm.heard_ctm(now)

    exp.link = Recording(exp.ctm, exp.ltms)
    start = exp.rig.clock.now()

    def hook(now: float) -> None:
        if switch_at is not None and not switched and now - start >= switch_at:
            data = json.loads(json.dumps(snapshot(exp.ctm, now)))
            new = fresh_like(exp)
            restore(new, data, now)
            exp.ctm = exp.link.ctm = new
            switched.append(now)

    exp.hooks.append(hook)
    report = exp.run()
    assert switched or switch_at is None
    return exp, report, sent


@pytest.fixture(scope="module")
def runs() -> tuple[tuple[Any, PatrolReport, list[Any]], tuple[Any, PatrolReport, list[Any]]]:
    return fly(None), fly(SWITCH_AT_S)


def test_a_restored_ctm_flies_the_patrol_on_as_the_original(runs: Any) -> None:
    (exp_base, base, sent_base), (exp_sw, switched, sent_sw) = runs
    assert switched.handoffs == base.handoffs >= 2  # the handoffs after the switch happen too
    assert switched.max_gap_s == base.max_gap_s
    assert switched.coverage == base.coverage
    assert switched.revisit_s == base.revisit_s
    # the same plans, to the same drones, at the same times, but numbered past the margin
    assert sent_sw == sent_base
    # and the console shows the same coverage: every waypoint's visits, the lap, the handoffs
    end = exp_base.rig.clock.now()
    cov_base = [m.coverage.as_dict(end) for m in exp_base.ctm.missions.values() if m.coverage]
    cov_sw = [m.coverage.as_dict(end) for m in exp_sw.ctm.missions.values() if m.coverage]
    assert cov_sw == cov_base


def test_a_restored_ctm_numbers_its_plans_past_the_snapshots() -> None:
    ctm = CentralTaskManager()
    first = next(ctm._plan_ids)
    data = snapshot(ctm, 0.0)
    assert data["next_plan_id"] == first + 1 and next(ctm._plan_ids) == first + 1  # not consumed
    new = CentralTaskManager()
    restore(new, json.loads(json.dumps(data)), 5.0)
    assert next(new._plan_ids) == first + 1 + PLAN_ID_MARGIN


@given(st.floats(-1e6, 1e6), st.floats(-1e6, 1e6))
@settings(max_examples=50, deadline=None)
def test_times_keep_their_meaning_on_another_clock(now: float, there: float) -> None:
    ctm = CentralTaskManager()

    ctm.add_mission([Enu(0, 0, 2), Enu(5, 0, 2)], now=now - 30.0, mission_id="m")
    ctm.missions["m"].coverage.visits[1].append(now - 7.5)  # type: ignore[union-attr]
    rec = ctm.drones["uav1"] = DroneRecord("uav1", last_heard=now - 0.5)
    rec.plan = FlightPlan(3, PlanKind.HOLD)
    restored = CentralTaskManager()
    restore(restored, json.loads(json.dumps(snapshot(ctm, now))), there)
    r = restored.drones["uav1"]
    assert r.last_heard == pytest.approx(there - 0.5, abs=1e-6)
    assert r.plan_sent_t == -math.inf and r.plan == rec.plan
    cov = restored.missions["m"].coverage
    assert cov is not None
    assert cov.since_last_s(1, there) == pytest.approx(7.5, abs=1e-6)
    assert cov.since_last_s(0, there) == pytest.approx(30.0, abs=1e-6)


@given(
    st.recursive(
        st.none() | st.booleans() | st.integers() | st.text(max_size=5),
        lambda c: st.lists(c, max_size=3) | st.dictionaries(st.text(max_size=8), c, max_size=4),
        max_leaves=12,
    )
)
@settings(max_examples=300, deadline=None)
def test_anything_else_is_refused_with_a_reason_and_changes_nothing(junk: Any) -> None:
    ctm = CentralTaskManager()
    ctm.add_mission([Enu(0, 0, 2)], now=0.0)
    before = snapshot(ctm, 0.0)
    with pytest.raises(MessageError):
        restore(ctm, junk, 1.0)
    assert snapshot(ctm, 0.0) == before


def test_a_snapshot_with_one_field_wrong_is_refused() -> None:
    ctm = CentralTaskManager()

    ctm.add_mission([Enu(0, 0, 2), Enu(5, 0, 2)], now=0.0, mission_id="m")
    good = json.loads(json.dumps(snapshot(ctm, 0.0)))
    for path, value in [
        (("missions", 0, "state"), "flying"),
        (("missions", 0, "mission", "route"), [[0, 0]]),
        (("missions", 0, "coverage", "visits"), [[1.0]]),
        (("next_plan_id",), "7"),
    ]:
        bad = json.loads(json.dumps(good))
        node = bad
        for k in path[:-1]:
            node = node[k]
        node[path[-1]] = value
        with pytest.raises(MessageError):
            restore(CentralTaskManager(), bad, 0.0)


def flying(seq: int, x: float, plan_id: int = 1) -> LtmStatus:
    """Drone ``uav1``'s ``seq``-th status, flying at ``x`` on the line y = 0 at route height."""
    return ltm_status(
        t=float(seq),
        seq=seq,
        x=x,
        z=1.5,
        battery_pct=90.0,
        flying=True,
        state="FLYING",
        station=Enu(0.0, -2.0, 0.0),
        plan_id=plan_id,
    )


def patrolling(route: list[Enu]) -> CentralTaskManager:
    """A central CTM with mission ``m`` on ``route``, ``uav1`` patrolling it."""
    central = CentralTaskManager()
    central.add_mission(route, now=0.0, mission_id="m")
    central.drones["uav1"] = DroneRecord("uav1", mission="m", role=DroneRole.PATROLLING)
    return central


def test_a_standby_keeps_the_statuses_a_late_replica_lacks() -> None:
    """The central's snapshot is taken before its loop has handled an LTM status that the
    standby has already heard (here: the drone reaching waypoint 2); the replica comes after
    that status. The standby keeps the status and the visit it makes, so that if the central
    dies before its next snapshot the standby resumes from where the drone is, not from a
    second before."""
    from drone.sim.world import load_world
    from server.fleet.failover import CentralRole
    from server.fleet.service import FleetService
    from server.graph import Graph

    central = patrolling([Enu(0.0, 0.0, 1.5), Enu(6.0, 0.0, 1.5), Enu(6.0, 4.0, 1.5)])
    central.on_status(flying(1, 0.0), 1.0)  # at waypoint 1
    central.on_status(flying(2, 3.0), 2.0)  # between waypoints 1 and 2
    replica = json.dumps({"console": "console-a", "ctm": snapshot(central, 2.9)}).encode()

    now = [0.0]
    service = FleetService(Graph(), load_world("indoor"), clock=lambda: now[0])
    standby = CentralRole(service, None, "f", "console-b", clock=lambda: now[0])
    for seq, x, t in [(1, 0.0, 101.0), (2, 3.0, 102.0), (3, 6.0, 103.0)]:  # its own clock
        now[0] = t
        standby._on_ltm("uav1", json.dumps(flying(seq, x).to_dict()).encode())
    now[0] = 103.1
    standby._on_replica(replica)  # snapshot at 2.9: before the status at waypoint 2

    rec = service.ctm.drones["uav1"]
    assert rec.status == flying(3, 6.0)
    assert rec.last_heard == 103.0
    cov = service.ctm.missions["m"].coverage
    assert cov is not None
    assert [list(v) for v in cov.visits] == [[pytest.approx(101.2)], [103.0], []]
    assert standby.replicas_in == 1


def test_a_status_the_snapshot_has_is_not_applied_again() -> None:
    central = patrolling([Enu(0.0, 0.0, 1.5), Enu(6.0, 0.0, 1.5)])
    for seq, x in [(1, 0.0), (2, 3.0), (3, 6.0)]:
        central.on_status(flying(seq, x, plan_id=7), float(seq))
    data = json.loads(json.dumps(snapshot(central, 3.5)))
    standby = CentralTaskManager()
    heard = [(flying(2, 3.0, plan_id=7), 12.0), (flying(3, 6.0, plan_id=7), 13.0)]
    restore(standby, data, 13.5, heard)
    rec = standby.drones["uav1"]
    assert rec.status == flying(3, 6.0, plan_id=7)
    assert rec.last_heard == pytest.approx(13.0)  # the snapshot's, on the standby's clock
    cov = standby.missions["m"].coverage
    assert cov is not None and [len(v) for v in cov.visits] == [1, 1]  # no visit twice


def test_plans_are_numbered_past_a_replayed_status_too() -> None:
    central = patrolling([Enu(0.0, 0.0, 1.5), Enu(6.0, 0.0, 1.5)])
    central.on_status(flying(1, 0.0, plan_id=3), 1.0)
    data = json.loads(json.dumps(snapshot(central, 1.5)))
    standby = CentralTaskManager()
    restore(standby, data, 11.5, [(flying(2, 3.0, plan_id=40), 11.6)])  # a plan after it
    assert next(standby._plan_ids) == 40 + 1 + PLAN_ID_MARGIN


def test_a_vehicle_started_again_is_not_taken_back_to_its_old_statuses() -> None:
    """Its LTM numbers its statuses from 1 again: the standby forgets the ones it kept from
    before (their numbers are higher), so a replica with the new ones stands."""
    from drone.sim.world import load_world
    from server.fleet.failover import CentralRole
    from server.fleet.service import FleetService
    from server.graph import Graph

    now = [0.0]
    service = FleetService(Graph(), load_world("indoor"), clock=lambda: now[0])
    standby = CentralRole(service, None, "f", "console-b", clock=lambda: now[0])
    for seq, x, t in [(500, 0.0, 10.0), (501, 3.0, 11.0), (1, 6.0, 12.0)]:  # started again
        now[0] = t
        standby._on_ltm("uav1", json.dumps(flying(seq, x).to_dict()).encode())
    central = patrolling([Enu(0.0, 0.0, 1.5), Enu(6.0, 0.0, 1.5)])
    central.on_status(flying(1, 6.0), 2.0)
    now[0] = 12.2
    standby._on_replica(json.dumps({"console": "a", "ctm": snapshot(central, 2.1)}).encode())
    rec = service.ctm.drones["uav1"]
    assert rec.status == flying(1, 6.0)
    assert rec.last_heard == pytest.approx(12.1)
