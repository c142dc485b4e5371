"""A standby taking the central role over, in lockstep: its central role on a fake bus (the
election's view set by the test), its fleet service real, every clock injected. The central
console that was froze before it died (its process stopped, or its host gone): its router kept
the vehicles' links, so no console heard their LTMs until the standby saw it go."""

from __future__ import annotations

import json
from dataclasses import dataclass, field

from drone.sim.world import load_world
from server.fleet.ctm import CentralTaskManager
from server.fleet.failover import CentralRole
from server.fleet.geo import Enu
from server.fleet.messages import DroneRole, LtmStatus
from server.fleet.replica import snapshot
from server.fleet.service import FleetService
from server.fleet.states import MissionState
from server.graph import Graph
from tests.support.ltm_status import ltm_status

ROUTE = [Enu(1.5, 1.0, 1.5), Enu(6.5, 1.0, 1.5), Enu(6.5, 5.0, 1.5), Enu(1.5, 5.0, 1.5)]
STATIONS = {"uav1": Enu(1.5, 0.0, 0.0), "uav2": Enu(3.0, 0.0, 0.0)}
FROZEN_S = 10.0  # the old central's router silent before its links closed (Zenoh's lease)


@dataclass
class FakeCentralBus:
    """What :class:`~server.fleet.failover.CentralRole` uses of ``drone.bus.central.CentralBus``:
    the consoles and holders the test says are on the bus, and what the role declares."""

    consoles: set[str]
    holders: set[str]
    claimed: bool = False
    replicas: list[bytes] = field(default_factory=list)

    def view(self) -> tuple[set[str], set[str]]:
        return set(self.consoles), set(self.holders)

    def claim(self) -> None:
        self.claimed = True

    def release(self) -> None:
        self.claimed = False

    def publish_replica(self, payload: bytes) -> None:
        self.replicas.append(payload)

    def publish_missions(self, payload: bytes) -> None:
        pass


def status(name: str, seq: int, p: Enu, *, flying: bool, plan_id: int = 0) -> LtmStatus:
    return ltm_status(
        name,
        t=float(seq),
        seq=seq,
        x=p.x,
        y=p.y,
        z=p.z,
        battery_pct=95.0,
        flying=flying,
        state="FLYING" if flying else "LANDED",
        station=STATIONS[name],
        plan_id=plan_id,
    )


def hear(role: CentralRole, st: LtmStatus) -> None:
    """``st`` on the bus, as the standby's CentralBus hands it over."""
    role._on_ltm(st.name, json.dumps(st.to_dict()).encode())


def central_patrolling() -> tuple[CentralTaskManager, str, bytes]:
    """Console-a's CTM with one drone patrolling the route (its relief not due for long);
    the drone's name and console-a's last replica, taken at 10.0 on its clock."""
    ctm = CentralTaskManager()
    for name, pad in STATIONS.items():
        ctm.on_status(status(name, 1, pad, flying=False), 0.0)
    ctm.add_mission(ROUTE, now=0.0, mission_id="m")
    (sent,) = ctm.step(0.0)
    on_route = ROUTE[sent.plan.start_index]
    for seq, t in enumerate((4.0, 6.0, 8.0, 9.8), start=2):
        ctm.on_status(status(sent.drone, seq, on_route, flying=True, plan_id=sent.plan.plan_id), t)
        other = next(n for n in STATIONS if n != sent.drone)
        ctm.on_status(status(other, seq, STATIONS[other], flying=False), t)
        assert ctm.step(t) == []
    ms = ctm.missions["m"]
    assert ms.state is MissionState.RUNNING and ms.active == sent.drone
    replica = json.dumps({"console": "console-a", "ctm": snapshot(ctm, 10.0)}).encode()
    return ctm, sent.drone, replica


def standby(now: list[float]) -> tuple[CentralRole, FakeCentralBus]:
    service = FleetService(Graph(), load_world("indoor"), clock=lambda: now[0])
    role = CentralRole(service, None, "f", "console-b", clock=lambda: now[0])
    bus = FakeCentralBus({"console-a", "console-b"}, {"console-a"})
    role.bus = bus  # type: ignore[assignment]
    return role, bus


def take_over_after_a_freeze() -> tuple[CentralRole, FakeCentralBus, str, list[float]]:
    """console-b stands by with console-a's replica; console-a freezes, and after FROZEN_S
    (nothing heard from anyone meanwhile) its links close and console-b claims the role."""
    _, active, replica = central_patrolling()
    now = [100.0]
    role, bus = standby(now)
    now[0] = 100.6  # past the election's settling
    role.step(now[0])
    assert not role.central
    role._on_replica(replica)  # console-a's last, just before it froze
    now[0] = 100.2 + FROZEN_S
    bus.consoles, bus.holders = {"console-b"}, set()
    role.step(now[0])
    assert role.central and bus.claimed
    return role, bus, active, now


def test_a_drone_unheard_while_the_old_central_froze_is_not_lost_to_the_new_one() -> None:
    role, _, active, now = take_over_after_a_freeze()
    ctm = role.ctm
    out = ctm.step(now[0] + 0.1)  # the CtmNode's first round after the claim
    assert out == []  # nobody sent anywhere: the patrol flies on as it was
    assert ctm.drones[active].role is DroneRole.PATROLLING
    ms = ctm.missions["m"]
    assert ms.state is MissionState.RUNNING and ms.active == active and ms.replacements == 0
    # its statuses come again (its vehicle on console-b's router): nothing changes
    plan = ctm.drones[active].plan
    assert plan is not None
    p = ROUTE[(plan.start_index + 1) % len(ROUTE)]
    now[0] += 0.4
    hear(role, status(active, 9, p, flying=True, plan_id=plan.plan_id))
    assert ctm.step(now[0]) == []
    assert ctm.drones[active].role is DroneRole.PATROLLING and ms.active == active


def test_a_drone_still_silent_after_the_claim_is_lost_after_the_usual_silence() -> None:
    role, _, active, now = take_over_after_a_freeze()
    ctm = role.ctm
    claimed = now[0]
    other = next(n for n in STATIONS if n != active)
    for seq, t in enumerate((0.5, 1.5, 2.5), start=9):  # the other one is heard again
        now[0] = claimed + t
        hear(role, status(other, seq, STATIONS[other], flying=False))
    assert ctm.step(claimed + ctm.lost_after_s - 0.1) == []
    assert ctm.drones[active].role is DroneRole.PATROLLING
    out = ctm.step(claimed + ctm.lost_after_s + 0.1)
    assert ctm.drones[active].role is DroneRole.LOST
    assert [d.drone for d in out] == [other]  # replaced, as by any central
    assert ctm.missions["m"].replacements == 1
