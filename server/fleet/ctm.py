"""The central task manager (CTM): missions, roles and battery handoff, sans-I/O.

Inputs: ``on_status(LtmStatus, now)`` from each LTM, ``on_plan_result(...)`` when an LTM
answers a plan, ``add_mission``/``mission_from_request``. Output: ``step(now)`` returns the
``Dispatch`` (drone, flight plan) list to send; ``fleet_status(now)`` is the
``uav_console/FleetStatus`` message. No sockets, no clock of its own: the in-process node, the
rosbridge server and the lockstep experiment all drive the same object.

Per mission: one drone *patrols*; when its battery will reach the mission's threshold
within the lead time of the best idle drone (planner.lead_time_s), that drone is sent
(*relieving*) on the same patrol plan from the route point nearest its station; the moment it
is on the route the tired drone gets a return plan (*returning*), lands at its station
(*charging*, restored by the station) and becomes *idle* when ready. The active drone never
leaves before its relief is on the route unless its battery is down to the reserve it needs to
get home. A drone silent for ``lost_after_s``, in emergency, or not hearing its own drone for
``lost_after_s`` is *lost*, and whatever it did is given to another (a link blip of the drone's
own, its navdata late 0.5 s on a busy machine, is no reason to replace it or to drop its role in
a paused mission).

A mission's state follows the one table of ``server.fleet.states``: *waiting* for a drone on
the route, *running*, *paused* when the operator takes one of its drones (land, hover, stop,
emergency, a jog: any door, reported by the LTM as ``operator``) or pauses it, until the operator
resumes or ends it; a paused mission's drones are sent nothing but a hold.
"""

from __future__ import annotations

import itertools
import math
import re
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from server.fleet.accuracy import GPS_ARRIVAL_RADIUS_M
from server.fleet.continuity import (
    CoverageTracker,
    JoinPoint,
    choose_join,
    entry_on_leg,
    owes_waypoints,
    perimeter_m,
)
from server.fleet.errors import MissionError, NotFoundError
from server.fleet.geo import Enu, Geo, to_enu, to_geo
from server.fleet.ltm import HELD
from server.fleet.messages import (
    MAX_ROUTE_POINTS,
    MISSION_NAME_PATTERN,
    DroneRole,
    FlightPlan,
    Handoff,
    LtmStatus,
    Mission,
    MissionRequest,
    PlanKind,
)
from server.fleet.planner import (
    FlightModel,
    StationModel,
    lead_time_s,
    reserve_pct,
    should_dispatch,
    transit_s,
)
from server.fleet.states import VERBS, MissionEvent, MissionState, transition

ENTRY_GAIN_M = 1.0  # enter mid-leg only when that is at least this much nearer
DRAIN_WINDOW_S = 60.0  # battery is reported in whole percent: estimate slope over a minute
MARKER_STANDOFF_M = 1.0  # a marker-id waypoint lies this far in front of the marker (as "go to")


RETURN_LAYER_M = 2.0  # drones fly home this far above the route (clear of the relief)
STATION_RADIUS_M = 1.5  # a drone this near its station's pad is on it (charges there)


@dataclass(frozen=True)
class Dispatch:
    """Send ``plan`` to drone ``drone``."""

    drone: str
    plan: FlightPlan


@dataclass
class DroneRecord:
    """What the CTM knows about one drone."""

    name: str
    status: LtmStatus | None = None
    last_heard: float = -math.inf
    role: DroneRole = DroneRole.IDLE
    mission: str = ""
    plan: FlightPlan | None = None
    plan_sent_t: float = -math.inf
    lost_reason: str = ""
    lost_from: DroneRole = DroneRole.IDLE  # the role it had when it was lost
    charging_since: float = -math.inf  # when it landed at its station to charge
    link_down_since: float | None = None  # first status of a run saying its drone link is down
    samples: deque[tuple[float, float]] = field(default_factory=lambda: deque(maxlen=400))

    def drain_pct_s(self, default: float) -> float:
        """Observed battery drain in flight (%/s); ``default`` until a window is long enough."""
        if len(self.samples) < 2:
            return default
        t0, b0 = self.samples[0]
        t1, b1 = self.samples[-1]
        if t1 - t0 < DRAIN_WINDOW_S / 2 or b0 <= b1:
            return default
        return max((b0 - b1) / (t1 - t0), default * 0.5)


@dataclass
class MissionRecord:
    """What the CTM holds of one mission: its drones, its state and its coverage."""

    mission: Mission
    active: str | None = None
    relief: str | None = None
    handoffs: int = 0
    replacements: int = 0
    started_t: float | None = None
    state: MissionState = MissionState.WAITING  # server.fleet.states
    detail: str = "waiting for a drone"  # the state in words ("paused by the operator (land)")
    # paused: each drone it held and the role it had ("patrolling"), and what the operator did
    paused: dict[str, str] = field(default_factory=dict)
    paused_by: dict[str, str] = field(default_factory=dict)
    coverage: CoverageTracker | None = None  # live visits of the waypoints (continuity.py)
    join: JoinPoint | None = None  # where the relief in flight joins the route
    join_sent_t: float = 0.0  # when that relief was sent
    relief_on_route_t: float | None = None  # when it reached the route (the handoff's time)
    last_known: Enu | None = None  # the last position of an active drone lost (or paused)
    # the route is empty: who left it and why (handoff, replacement, resume), for the handoff
    # the next drone on the route makes
    gap_from: tuple[str, str] | None = None
    ended_t: float | None = None


class CentralTaskManager:
    """See the module docstring.

    Args:
        model: flight model for lead times and reserves.
        stations: the station model (restore time) for readiness and the bound.
        lost_after_s: an LTM silent this long, or reporting its drone's link down this long,
            is lost.
        corridor_m: a drone this close (horizontally) to the route, at route height ±1.5 m,
            is on the route.
        origin: GPS origin for lat/lon missions and status.
        world: for marker-id routes (``world.marker(id).position``).
        resend_s: a plan the LTM has not confirmed (status ``plan_id``) is sent again.
        continuity: a relief joins where the patrolling drone is going next
            (``server.fleet.continuity``); False: at the waypoint nearest its station (the
            behaviour before, kept as the benchmark's baseline).
        max_missions: missions held at once (ended ones included until they expire).
        ended_keep_s: an ended mission stays readable this long, then is forgotten.
    """

    def __init__(
        self,
        *,
        model: FlightModel | None = None,
        stations: StationModel | None = None,
        lost_after_s: float = 3.0,
        corridor_m: float = 2.5,
        origin: Geo | None = None,
        world: Any | None = None,
        resend_s: float = 3.0,
        continuity: bool = True,
        max_missions: int = 32,
        ended_keep_s: float = 600.0,
    ) -> None:
        self.model = model or FlightModel()
        self.stations = stations or StationModel()
        self.lost_after_s = lost_after_s
        self.corridor_m = corridor_m
        self.origin = origin
        self.world = world
        self.resend_s = resend_s
        self.continuity = continuity
        self.max_missions = max_missions
        self.ended_keep_s = ended_keep_s
        self.drones: dict[str, DroneRecord] = {}
        self.missions: dict[str, MissionRecord] = {}
        self.events: deque[tuple[float, str]] = deque(maxlen=200)
        # what the operator must hear (a mission stalled, resumed): (t, level, text), drained
        # by the node that runs the CTM onto the console's replies
        self.notices: deque[tuple[float, str, str]] = deque(maxlen=50)
        self._plan_ids = itertools.count(1)
        self._now = 0.0  # the latest step's time (for changes made between steps)
        # silence is counted from here at the earliest (claim: a standby taking the role over)
        self.listening_since = -math.inf
        self._mission_ids = itertools.count(1)
        self.decisions = 0

    # ------------------------------------------------------------------ inputs
    def claim(self, now: float) -> None:
        """This CTM decides from ``now`` on (a standby's, its state restored from the central
        that was: ``server.fleet.failover``). Until the old central's router is gone the
        vehicles on it reach no other console, so a drone not heard since is unheard, not
        silent: its silence (``lost_after_s``) counts from ``now``. A drone already lost stays
        lost until it is heard."""
        self.listening_since = max(self.listening_since, now)
        self.event(now, "central role taken")

    def event(self, now: float, text: str) -> None:
        self.events.append((now, text))

    def notify(self, now: float, level: str, text: str) -> None:
        """Tell the operator (``notices``; ``level`` info, warn or alert)."""
        self.notices.append((now, level, text))

    def on_status(self, status: LtmStatus, now: float) -> None:
        """An LTM report (from any transport)."""
        rec = self.drones.get(status.name)
        if rec is None:
            rec = self.drones[status.name] = DroneRecord(status.name)
            self.event(now, f"{status.name} joined")
        rec.status = status
        rec.last_heard = now
        if status.link_ok:
            rec.link_down_since = None
        elif rec.link_down_since is None:
            rec.link_down_since = now
        if status.flying:
            rec.samples.append((now, status.battery_pct))
            while rec.samples and now - rec.samples[0][0] > DRAIN_WINDOW_S:
                rec.samples.popleft()
        else:
            rec.samples.clear()
        ms = self.missions.get(rec.mission)
        if ms is not None and ms.coverage is not None and ms.state.flying:
            ms.coverage.observe(rec.name, status.position, status.flying, now)

    def on_plan_result(self, name: str, plan_id: int, ok: bool, reason: str, now: float) -> None:
        """An LTM's answer to a plan; a refusal or a transport failure is retried by ``step``."""
        rec = self.drones.get(name)
        if rec is None or rec.plan is None or rec.plan.plan_id != plan_id:
            return
        if not ok:
            self.event(now, f"{name} refused plan {plan_id}: {reason}")
            rec.plan_sent_t = -math.inf if "refused" not in reason else now

    # ------------------------------------------------------------------ missions
    def add_mission(
        self,
        route: Sequence[Enu],
        *,
        now: float,
        loop: bool = True,
        threshold: float = 0.30,
        mission_id: str | None = None,
        headings_deg: Sequence[float] = (),
        handoff: Handoff = Handoff.PREDICTIVE,
    ) -> Mission:
        """Hold a new patrol mission; drones are assigned at the next ``step``.

        Raises:
            MissionError: an empty route, a threshold outside (0, 1), a waypoint outside the
                world's limits (fence, floor, ceiling), or a duplicate id.
        """
        if not route:
            raise MissionError("a mission needs at least one waypoint")
        if not 0.0 < threshold < 1.0:
            raise MissionError(f"handoff threshold must be in (0, 1), got {threshold}")
        if len(route) > MAX_ROUTE_POINTS:
            raise MissionError(f"a route has at most {MAX_ROUTE_POINTS} waypoints")
        if mission_id is not None and not re.match(MISSION_NAME_PATTERN, mission_id):
            raise MissionError(
                "a mission name is 1-64 letters, digits, '_', '.' or '-', starting with a "
                "letter or digit"
            )
        self.expire_ended(now)
        if len(self.missions) >= self.max_missions:
            raise MissionError(
                f"at most {self.max_missions} missions at once; end one (ended missions "
                f"are forgotten {self.ended_keep_s:g} s after they end)"
            )
        self._check_limits(route)  # before an id is taken: a refused mission leaves no trace
        mid = mission_id or f"m{next(self._mission_ids)}"
        while mission_id is None and mid in self.missions:
            mid = f"m{next(self._mission_ids)}"
        if mid in self.missions:
            raise MissionError(f"mission {mid!r} exists")
        geo: tuple[tuple[float, float, float], ...] = ()
        if self.origin is not None:
            gs = [to_geo(p, self.origin) for p in route]
            geo = tuple((g.lat_deg, g.lon_deg, g.alt_m) for g in gs)
        if headings_deg and len(headings_deg) != len(route):
            raise MissionError("give one heading per waypoint, or none")
        m = Mission(mid, tuple(route), loop, threshold, now, geo, tuple(headings_deg), handoff)
        self.missions[mid] = MissionRecord(m, coverage=CoverageTracker(tuple(route), now))
        self.event(
            now,
            f"mission {mid}: {len(route)} waypoints, handoff at {threshold:.0%} ({handoff.value})",
        )
        return m

    def _check_limits(self, route: Sequence[Enu]) -> None:
        """Refuse up front a route outside the world's limits (fence, floor, ceiling): a mission
        is never cut short in mid-air by a limit it was bound to meet. The return
        layer (``RETURN_LAYER_M`` above the route) is kept under the ceiling by ``_send_home``
        (in a room it is the ceiling itself)."""
        if self.world is None or not hasattr(self.world, "bounds"):
            return
        from drone.limits import limits_of

        lim = limits_of(self.world)
        for k, p in enumerate(route):
            why = lim.violation(p.x, p.y, p.z)
            if why is not None:
                raise MissionError(f"waypoint {k + 1}: {why}")

    def mission_from_request(self, req: MissionRequest, now: float) -> Mission:
        """Resolve a REST request (lat/lon/alt or marker ids) to map-frame waypoints.

        Raises:
            MissionError: lat/lon with no GPS origin, or an unknown marker id.
        """
        route: list[Enu] = []
        if req.waypoints:
            if self.origin is None:
                raise MissionError("this world has no GPS origin: give marker ids instead")
            for w in req.waypoints:
                alt = self.origin.alt_m + req.altitude_m if w.alt is None else w.alt
                route.append(to_enu(Geo(w.lat, w.lon, alt), self.origin))
        else:
            if self.world is None:
                raise MissionError("no world is loaded to resolve marker ids")
            for mid in req.markers or ():
                try:
                    marker = self.world.marker(mid)
                except KeyError:
                    raise MissionError(f"unknown marker id {mid}") from None
                # In front of the marker, as "go to marker" flies (GotoMarkerTask.standoff_m):
                # a marker hangs on a wall or a post, so its own position is not flyable (and
                # lies outside the world's limits).
                p = marker.standoff(MARKER_STANDOFF_M)
                route.append(Enu(float(p.x), float(p.y), req.altitude_m))
        return self.add_mission(
            route,
            now=now,
            loop=req.loop,
            threshold=req.handoff_threshold,
            mission_id=req.name,
            handoff=req.handoff,
        )

    def _get(self, mission_id: str) -> MissionRecord:
        ms = self.missions.get(mission_id)
        if ms is None:
            raise NotFoundError(f"no mission {mission_id!r}")
        return ms

    def _set(self, ms: MissionRecord, event: MissionEvent, now: float, detail: str) -> None:
        """Move ``ms`` along the table (``IllegalTransition`` when it may not) and log it."""
        new = transition(ms.state, event)
        if new is not ms.state or detail != ms.detail:
            self.event(now, f"mission {ms.mission.id} {detail}")
        ms.state, ms.detail = new, detail

    def control_mission(self, mission_id: str, verb: str, now: float) -> None:
        """The operator's ``pause``, ``resume`` or ``end`` of a mission (REST, the dialog).

        Raises:
            NotFoundError: no such mission.
            MissionError: ``verb`` is none of those.
            IllegalTransition: not now (resume a mission that is not paused, pause an ended
                one); the message says why.
        """
        event = VERBS.get(verb)
        if event is None:
            raise MissionError(f"unknown action {verb!r} (one of {', '.join(VERBS)})")
        if event is MissionEvent.OPERATOR:
            self.pause_mission(mission_id, now, "pause")
        elif event is MissionEvent.RESUME:
            self.resume_mission(mission_id, now)
        else:
            self.end_mission(mission_id, now)

    def pause_mission(
        self,
        mission_id: str,
        now: float,
        action: str,
        taken: str | None = None,
        detail: str | None = None,
    ) -> None:
        """Pause a mission: the operator did ``action`` (to drone ``taken``, which is left to
        them) or paused it, or a safety monitor holds ``taken`` asking the operator (``detail``
        says so). Its other flying drones hold where they are; nothing is sent to them until it
        is resumed or ended.

        Raises:
            NotFoundError: no such mission.
            IllegalTransition: it has ended.
        """
        ms = self._get(mission_id)
        self._set(ms, MissionEvent.OPERATOR, now, detail or f"paused by the operator ({action})")
        if detail is not None:
            self.notify(now, "warn", f"Patrol {mission_id} is {detail}; resume or end it.")
        if ms.active is not None:
            st = self.drones[ms.active].status
            if st is not None:  # a drone resuming it carries on from there
                ms.last_known, ms.gap_from = st.position, (ms.active, "resume")
        for name in (ms.active, ms.relief):
            if name is None:
                continue
            rec = self.drones[name]
            ms.paused[name] = rec.role.value
            if ms.coverage is not None:
                ms.coverage.forget(name)
            if rec.role is DroneRole.LOST:
                continue
            rec.role = DroneRole.PAUSED
            if name == taken:
                ms.paused_by[name] = action
            elif rec.status is not None and rec.status.flying:
                self._hold(rec, now)
        ms.active = ms.relief = None
        ms.join, ms.relief_on_route_t = None, None

    def resume_mission(self, mission_id: str, now: float) -> None:
        """Resume a paused mission: its drones are free again and the CTM sends the one that
        reaches the route first (a drone still flying, often), the others home.

        Raises:
            NotFoundError: no such mission.
            IllegalTransition: it is not paused.
        """
        ms = self._get(mission_id)
        self._set(ms, MissionEvent.RESUME, now, "resumed by the operator: waiting for a drone")
        for name in ms.paused:
            rec = self.drones.get(name)
            if rec is not None and rec.role is DroneRole.PAUSED:
                self._free(rec)
            if rec is not None and rec.mission == mission_id:
                rec.mission = ""
        ms.paused.clear()
        ms.paused_by.clear()

    def end_mission(self, mission_id: str, now: float) -> None:
        """End a mission: its drones fly home (a landed one stays where it is). Ending an
        ended mission changes nothing.

        Raises:
            NotFoundError: no such mission.
        """
        ms = self._get(mission_id)
        if ms.state is MissionState.ENDED:
            return
        self._set(ms, MissionEvent.END, now, "ended by the operator")
        ms.ended_t = now
        for name in (ms.active, ms.relief, *ms.paused):
            if name is None or name not in self.drones:
                continue
            rec = self.drones[name]
            if rec.role is DroneRole.LOST:
                rec.mission = ""
            elif rec.status is not None and rec.status.flying:
                self._send_home(rec, now, ms.mission)
            else:
                self._free(rec)
        ms.active = ms.relief = None
        ms.paused.clear()
        ms.paused_by.clear()

    def _free(self, rec: DroneRecord) -> None:
        """A drone out of a mission: flying, idle (the next step sends it somewhere or home);
        on the ground, charging until ready."""
        st = rec.status
        rec.mission = ""
        if st is not None and st.flying:
            rec.role = DroneRole.IDLE
        elif st is not None and st.battery_pct < self.stations.ready_pct:
            rec.role = DroneRole.CHARGING
            rec.charging_since = self._now
        else:
            rec.role = DroneRole.IDLE

    def expire_ended(self, now: float) -> None:
        """Forget missions ended more than ``ended_keep_s`` ago."""
        for mid, ms in list(self.missions.items()):
            if ms.ended_t is not None and now - ms.ended_t > self.ended_keep_s:
                del self.missions[mid]
                self.event(now, f"mission {mid} expired")

    def mission_info(self, mission_id: str, now: float | None = None) -> dict[str, Any]:
        """The mission as ``GET /missions/{id}`` returns it (``coverage`` when ``now`` is given:
        time since each waypoint's last visit, the longest wait, revisits at each handoff).

        Raises:
            NotFoundError: no such mission.
        """
        ms = self._get(mission_id)
        m = ms.mission
        return {
            "id": m.id,
            "state": ms.state.value,
            "detail": ms.detail,
            "drones": self._mission_drones(ms),
            "loop": m.loop,
            "handoff_threshold": m.threshold,
            "handoff": m.handoff.value,
            "route": [{"x": p.x, "y": p.y, "z": p.z} for p in m.route],
            "route_geo": [{"lat": a, "lon": b, "alt": c} for a, b, c in m.geo],
            "active": ms.active,
            "relief": ms.relief,
            "handoffs": ms.handoffs,
            "replacements": ms.replacements,
            "coverage": (
                ms.coverage.as_dict(now) if ms.coverage is not None and now is not None else None
            ),
        }

    def _mission_drones(self, ms: MissionRecord) -> list[dict[str, str]]:
        """The mission's drones with their roles; paused, the role each had in it (``was``)
        and what the operator did to it (``operator``)."""
        out = []
        for name, was in ms.paused.items():
            rec = self.drones.get(name)
            role = rec.role.value if rec is not None else DroneRole.LOST.value
            out.append(
                {"name": name, "role": role, "was": was, "operator": ms.paused_by.get(name, "")}
            )
        for slot in (ms.active, ms.relief):
            if slot is not None and slot in self.drones:
                out.append({"name": slot, "role": self.drones[slot].role.value})
        return out

    # ------------------------------------------------------------------ geometry
    def on_route(self, p: Enu, mission: Mission) -> bool:
        """Within ``corridor_m`` of the route polyline (closed if looping), at route height."""
        if abs(p.z - mission.altitude_m) > 1.5:
            return False
        return route_distance(p, mission.route, mission.loop) <= self.corridor_m

    @staticmethod
    def entry_index(station: Enu, route: Sequence[Enu]) -> int:
        return min(range(len(route)), key=lambda i: station.dist_xy(route[i]))

    # ------------------------------------------------------------------ decisions
    def step(self, now: float) -> list[Dispatch]:
        """Decide; returns the plans to send now."""
        self.decisions += 1
        self._now = now
        self.expire_ended(now)
        out: list[Dispatch] = []
        for rec in self.drones.values():
            self._update_role(rec, now, out)
        for ms in self.missions.values():
            if ms.state.flying or ms.state is MissionState.STALLED:
                self._run_mission(ms, now, out)
        self._sample_coverage(now)
        for rec in self.drones.values():
            self._home_if_unused(rec, now, out)
        for rec in self.drones.values():  # resend unconfirmed plans
            st, plan = rec.status, rec.plan
            if (
                plan is not None
                and st is not None
                and rec.role is not DroneRole.LOST
                and st.plan_id != plan.plan_id
                and now - rec.plan_sent_t >= self.resend_s
                and all(d.drone != rec.name for d in out)
            ):
                rec.plan_sent_t = now
                out.append(Dispatch(rec.name, plan))
        return out

    def _sample_coverage(self, now: float) -> None:
        """Route coverage of every live mission: is a drone flying on its route now (any
        drone heard, as the experiment counts any drone on the route)?"""
        flying = [
            r.status.position
            for r in self.drones.values()
            if r.status is not None
            and r.role is not DroneRole.LOST
            and r.status.flying
            and not r.status.emergency
        ]
        for ms in self.missions.values():
            if ms.coverage is None or not ms.state.live:
                continue
            covered = any(self.on_route(p, ms.mission) for p in flying)
            ms.coverage.route_coverage.sample(covered, now)

    def _failure(self, rec: DroneRecord, now: float) -> str:
        st = rec.status
        heard = rec.last_heard
        if rec.role is not DroneRole.LOST:
            heard = max(heard, self.listening_since)  # claim
        if st is None or now - heard > self.lost_after_s:
            return "silent"
        if st.emergency:
            return "emergency"
        down = rec.link_down_since
        if not st.link_ok and (
            rec.role is DroneRole.LOST or (down is not None and now - down >= self.lost_after_s)
        ):
            return "drone link lost"
        return ""

    def _update_role(self, rec: DroneRecord, now: float, out: list[Dispatch]) -> None:
        st = rec.status
        if (
            st is not None
            and st.operator
            and rec.role in (DroneRole.PATROLLING, DroneRole.RELIEVING)
            and rec.plan is not None
            and st.plan_id == rec.plan.plan_id
            and rec.mission in self.missions
        ):
            # the operator took it off the CTM's plan (before the failure check: an emergency
            # the operator pressed pauses the mission, it does not hand it to another drone)
            self.pause_mission(rec.mission, now, st.operator, taken=rec.name)
        elif (
            st is not None
            and st.held
            and rec.role in (DroneRole.PATROLLING, DroneRole.RELIEVING)
            and rec.plan is not None
            and st.plan_id == rec.plan.plan_id
            and rec.mission in self.missions
        ):
            # its safety monitor holds it and asks the operator: the mission waits for them
            why = f"paused: {rec.name} held by its {st.held}"
            self.pause_mission(rec.mission, now, st.held, taken=rec.name, detail=why)
        why = self._failure(rec, now)
        if why:
            if rec.role is not DroneRole.LOST:
                self.event(now, f"{rec.name} lost ({why})")
                rec.lost_from, rec.role, rec.lost_reason = rec.role, DroneRole.LOST, why
            return
        st = rec.status
        assert st is not None
        if rec.role is DroneRole.LOST:
            self.event(now, f"{rec.name} back ({rec.lost_reason} over)")
            rec.lost_reason = ""
            rec.mission = ""
            on_duty = rec.lost_from in (
                DroneRole.PATROLLING,
                DroneRole.RELIEVING,
                DroneRole.RETURNING,
            )
            if st.flying and on_duty:
                self._send_home(rec, now, None, out)  # its post has been given to another
            else:
                # Landed, or someone's manual flight (never the CTM's to end): not taken over.
                rec.role = DroneRole.IDLE if st.flying else DroneRole.CHARGING
                rec.charging_since = now
            return
        if rec.role is DroneRole.RETURNING and not st.flying and st.state in ("LANDED", "DEFAULT"):
            rec.role, rec.charging_since = DroneRole.CHARGING, now
            self.event(now, f"{rec.name} landed at its station ({st.battery_pct:.0f} %)")
        elif rec.role is DroneRole.CHARGING and st.battery_pct >= self.stations.ready_pct:
            rec.role = DroneRole.IDLE
            self.event(now, f"{rec.name} ready ({st.battery_pct:.0f} %)")
        elif (
            rec.role is DroneRole.RETURNING
            and st.flying
            and st.autonomous.startswith(f"{HELD}hover")
            and rec.plan is not None
            and rec.plan.kind is PlanKind.RETURN
            and st.plan_id == rec.plan.plan_id
        ):
            # on its way home, its own safety held it in a hover (the central server's
            # silence): it would hover there until its battery ran out; home again
            self.event(now, f"{rec.name} held on its way home ({st.autonomous}); home again")
            plan = FlightPlan(next(self._plan_ids), PlanKind.RETURN, cruise_z=rec.plan.cruise_z)
            rec.plan, rec.plan_sent_t = plan, now
            out.append(Dispatch(rec.name, plan))
        if (
            st.autonomous
            and rec.role in (DroneRole.PATROLLING, DroneRole.RELIEVING)
            and (rec.plan is None or st.plan_id == rec.plan.plan_id)
        ):
            # the LTM flew home on its own (CTM silent, battery reserve), it was sent home, or
            # its own safety held it (a monitor, the central server's silence): free its post.
            # A held drone is free for a mission again (the same one, once able).
            self.event(now, f"{rec.name} left on its own ({st.autonomous})")
            self._release(rec, now)
            rec.role = DroneRole.IDLE if st.autonomous.startswith(HELD) else DroneRole.RETURNING

    def _home_if_unused(self, rec: DroneRecord, now: float, out: list[Dispatch]) -> None:
        """A fleet drone flying with nothing left to do (its post went to another, its mission
        resumed with another drone or ended): bring it home. After the missions have chosen
        their drones, so a drone still in the air is used before it is sent home. A drone the
        CTM never sent anywhere is someone's manual flight: left alone."""
        st = rec.status
        if st is None or rec.role is not DroneRole.IDLE or not st.flying or rec.mission:
            return
        # held in a hover by its own safety and given no post again: home too (a drone its
        # safety is landing is left to land)
        if st.autonomous and not st.autonomous.startswith(f"{HELD}hover"):
            return
        if rec.plan is not None and rec.plan.kind is not PlanKind.RETURN:
            self._send_home(rec, now, None, out)

    def _release(self, rec: DroneRecord, now: float) -> None:
        for ms in self.missions.values():
            if ms.active == rec.name:
                ms.active = None
                if rec.status is not None:  # whoever takes over carries on from there
                    ms.last_known, ms.gap_from = rec.status.position, (rec.name, "replacement")
                if ms.coverage is not None:
                    ms.coverage.forget(rec.name)
            if ms.relief == rec.name:
                ms.relief = None
        rec.mission = ""

    def _candidates(self) -> list[DroneRecord]:
        """Drones free for a mission: idle, or on the ground charging (how much charge is
        enough is the mission's, ``_need_pct``)."""
        return [
            r
            for r in self.drones.values()
            if r.status is not None
            and (r.role is DroneRole.IDLE or (r.role is DroneRole.CHARGING and not r.status.flying))
        ]

    def _takeoff_s(self, rec: DroneRecord) -> float:
        """Take-off time ``rec`` needs before it can fly anywhere (none in the air)."""
        return 0.0 if rec.status is not None and rec.status.flying else self.model.takeoff_s

    def _lead(self, r: DroneRecord, route: Sequence[Enu]) -> float:
        """Dispatch-to-arrival time of ``r``: from its station's entry point on the ground,
        from the nearest route point in the air (a paused mission's drone, still hovering
        when the operator resumes it)."""
        assert r.status is not None
        here = r.status.position
        if r.status.flying:
            i = min(range(len(route)), key=lambda k: here.dist_xy(route[k]))
            return transit_s(here, route[i], self.model) + self.model.margin_s
        i = self.entry_index(r.status.station, route)
        return lead_time_s(here, route[i], self.model)

    def _need_pct(self, ms: MissionRecord, lead_s: float) -> float:
        """The charge a drone needs to be worth sending: the flight out and ``min_shift_s``
        on the route, above the mission's threshold (the mission's reserve)."""
        m = self.model
        return 100.0 * ms.mission.threshold + (lead_s + m.min_shift_s) * m.drain_pct_s

    def _best(self, ms: MissionRecord, now: float) -> tuple[DroneRecord, float] | None:
        """The drone able to fly ``ms`` now (charged above its reserve) that reaches the route
        first (ties: fuller battery), with its lead; None when no drone is able."""
        best: tuple[float, float, DroneRecord] | None = None
        for r in self._candidates():
            assert r.status is not None
            lead = self._lead(r, ms.mission.route)
            if not r.status.battery_known or r.status.battery_pct < self._need_pct(ms, lead):
                continue
            key = (lead, -r.status.battery_pct)
            if best is None or key < (best[0], best[1]):
                best = (lead, -r.status.battery_pct, r)
        return None if best is None else (best[2], best[0])

    def _soonest_ready(self, ms: MissionRecord, now: float) -> tuple[str, float] | None:
        """The drone that will be able to fly ``ms`` first and in how many seconds, from the
        charge it will have: on its station at the station's rate (or when its swap is done),
        and a drone flying home once it has landed there; None when none will."""
        best: tuple[str, float] | None = None
        m = self.model
        for r in self.drones.values():
            st = r.status
            if st is None or r.role not in (DroneRole.CHARGING, DroneRole.RETURNING):
                continue
            need = self._need_pct(ms, lead_time_s(st.station, ms.mission.route[0], m))
            if r.role is DroneRole.RETURNING:
                home = transit_s(st.position, st.station, m) + m.land_s
                landed = st.battery_pct - home * m.drain_pct_s
                t = home + self.stations.time_to_s(landed, need, 0.0)
            elif st.position.dist_xy(st.station) <= STATION_RADIUS_M:
                t = self.stations.time_to_s(st.battery_pct, need, now - r.charging_since)
            else:
                continue  # landed away from its station: it does not charge
            if best is None or t < best[1]:
                best = (r.name, t)
        return best

    def _run_mission(self, ms: MissionRecord, now: float, out: list[Dispatch]) -> None:
        m = ms.mission
        for slot in ("active", "relief"):
            name = getattr(ms, slot)
            if name is not None and self.drones[name].role is DroneRole.LOST:
                why = self.drones[name].lost_reason
                self.event(now, f"{name} failed on {m.id} ({why}); replacing it")
                self.drones[name].mission = ""
                lost = self.drones[name].status
                if slot == "active" and lost is not None:
                    ms.last_known = lost.position  # the replacement carries on from there
                    ms.gap_from = ("(lost)", "replacement")
                if ms.coverage is not None:
                    ms.coverage.forget(name)
                setattr(ms, slot, None)
                ms.replacements += 1
        # relief on the route: hand over
        if ms.relief is not None:
            self._take_over(ms, now, out)
        # the active drone leaves: at its reserve (relief or not), or at the threshold when the
        # mission hands over reactively (the paper's rule: the relief is sent then)
        if ms.active is not None:
            ar = self.drones[ms.active]
            st = ar.status
            assert st is not None
            reserve = reserve_pct(st.position, st.station, self.model)
            reactive = m.handoff is Handoff.REACTIVE and st.battery_pct <= 100.0 * m.threshold
            if st.battery_pct <= reserve or reactive:
                why = "at the threshold" if reactive else "at reserve"
                self.event(
                    now, f"{ar.name} {why} ({st.battery_pct:.0f} %) leaves {m.id} unrelieved"
                )
                ms.active = None
                ms.last_known, ms.gap_from = st.position, (ar.name, "handoff")
                if ms.coverage is not None:
                    ms.coverage.forget(ar.name)
                self._send_home(ar, now, m, out)
        if ms.active is None and ms.state is MissionState.RUNNING:
            who = f"; {ms.relief} on its way" if ms.relief else ""
            self._set(ms, MissionEvent.OFF_ROUTE, now, f"waiting: no drone on the route{who}")
        if ms.relief is not None:
            return
        # dispatch a relief (or the first drone): reactive missions only once the route is empty
        if ms.active is not None and m.handoff is Handoff.REACTIVE:
            return
        choice = self._best(ms, now)
        if choice is None:
            if ms.active is None:
                self._stall(ms, now)
            return
        rec, lead = choice
        join = self._join(rec, ms) if self.continuity else None
        if join is not None:
            lead = join.relief_eta_s + self.model.margin_s
        if ms.active is not None:
            ast = self.drones[ms.active].status
            assert ast is not None
            drain = self.drones[ms.active].drain_pct_s(self.model.drain_pct_s)
            if not should_dispatch(ast.battery_pct, 100.0 * m.threshold, drain, lead):
                return
        if ms.state is MissionState.STALLED:
            assert rec.status is not None
            b = rec.status.battery_pct
            self._set(ms, MissionEvent.READY, now, f"waiting: {rec.name} ready ({b:.0f} %)")
            self.notify(now, "info", f"{rec.name} is ready at {b:.0f} percent; {m.id} resumes.")
        self._dispatch(rec, ms, now, out, join)

    def _take_over(self, ms: MissionRecord, now: float, out: list[Dispatch]) -> None:
        """The relief in flight takes the route over once it is on it (and the drone it
        relieves has flown the waypoints it still owed)."""
        m = ms.mission
        assert ms.relief is not None
        rr = self.drones[ms.relief]
        assert rr.status is not None
        on_route = rr.status.flying and self.on_route(rr.status.position, m)
        if on_route and ms.relief_on_route_t is None:
            ms.relief_on_route_t = now  # the relief covers the route from now on
        if ms.relief_on_route_t is None or self._owed(ms, now):
            return
        took_over = ms.relief_on_route_t
        old = ms.active
        ms.active, ms.relief = ms.relief, None
        rr.role = DroneRole.PATROLLING
        if ms.started_t is None:
            ms.started_t = now
        if ms.state is MissionState.WAITING:
            self._set(ms, MissionEvent.ON_ROUTE, now, f"running: {rr.name} patrolling")
        else:  # a handoff: the event below says so
            ms.detail = f"running: {rr.name} patrolling"
        joined_at = ms.join.index if ms.join is not None else -1
        if old is not None:
            ms.handoffs += 1
            orec = self.drones[old]
            b = orec.status.battery_pct if orec.status else float("nan")
            self.event(now, f"handoff on {m.id}: {rr.name} relieves {old} ({b:.0f} %)")
            self._send_home(orec, now, m, out)
            if ms.coverage is not None:
                ms.coverage.forget(old)
                ms.coverage.handoff(took_over, old, rr.name, joined_at, "handoff")
        else:
            self.event(now, f"{rr.name} patrolling {m.id}")
            if ms.gap_from is not None:
                left, kind = ms.gap_from
                ms.handoffs += kind == "handoff"  # it left, the relief came after a gap
                if ms.coverage is not None:
                    ms.coverage.handoff(took_over, left, rr.name, joined_at, kind)
        ms.join, ms.last_known, ms.relief_on_route_t, ms.gap_from = None, None, None, None

    def _stall(self, ms: MissionRecord, now: float) -> None:
        """Nobody on the route and no drone able to fly it: say so (once), with when the
        first charging drone will be ready; ``_run_mission`` resumes it when one is."""
        if not self.drones:
            return  # no drone has joined yet: still waiting
        if any(
            r.status is not None and not r.status.battery_known and r.role is not DroneRole.LOST
            for r in self.drones.values()
        ):
            return  # a drone's first battery reading is still to come: still waiting
        soonest = self._soonest_ready(ms, now)
        lost = [r.name for r in self.drones.values() if r.role is DroneRole.LOST]
        if soonest is None and len(lost) == len(self.drones):
            # nobody low on charge: every drone is lost (silent, in emergency, no link)
            detail = f"stalled: no drone able to fly ({', '.join(sorted(lost))} lost)"
        else:
            detail = "stalled: no drone above the reserve"
        if soonest is not None:
            detail += f" ({soonest[0]} ready in {soonest[1]:.0f} s)"
        if ms.state is MissionState.STALLED:
            ms.detail = detail  # the countdown, without an event a step
            return
        self._set(ms, MissionEvent.STALL, now, detail)
        when = f"; {soonest[0]} is ready in about {soonest[1]:.0f} seconds" if soonest else ""
        why = (
            "no drone is charged above the reserve"
            if "reserve" in detail
            else "no drone is able to fly"
        )
        self.notify(
            now, "warn", f"Patrol {ms.mission.id} has stalled: {why}{when}. It resumes by itself."
        )

    def _join(self, rec: DroneRecord, ms: MissionRecord) -> JoinPoint:
        """Where ``rec`` would join ``ms``'s route if dispatched now (continuity.py)."""
        assert rec.status is not None
        m = ms.mission
        here = rec.status.position
        up = self._takeoff_s(rec)
        eta = [up + transit_s(here, wp, self.model) for wp in m.route]
        active = None
        if ms.active is not None:
            st = self.drones[ms.active].status
            active = st.position if st is not None else None
        lap = ms.coverage.lap_s() if ms.coverage is not None else None
        if lap is None:  # no lap seen yet: the model's speed plus a second's dwell a waypoint
            lap = perimeter_m(m.route, m.loop) / self.model.speed_m_s + len(m.route)
        join = choose_join(m.route, m.loop, eta, active, lap, last_known=ms.last_known)
        if active is None and ms.last_known is not None:
            # a replacement: enter on the lost drone's leg where it is nearest, then carry on
            # from the waypoint the lost drone was flying to (the one that has waited longest)
            q = entry_on_leg(m.route, m.loop, join.index, here)
            if here.dist_xy(q) < here.dist_xy(m.route[join.index]) - ENTRY_GAIN_M:
                t = up + transit_s(here, q, self.model)
                join = JoinPoint(join.index, t, None, q)
        return join

    def _owed(self, ms: MissionRecord, now: float) -> bool:
        """Whether the patrolling drone still has waypoints to fly before the relief's join
        (``continuity.owes_waypoints``): it goes on patrolling, the relief already on the
        route, until it has flown them. Not past the time it was predicted to reach the join
        plus the model's margin (a drone that stalls hands over anyway; one at its reserve
        goes home regardless)."""
        if ms.active is None or ms.join is None or ms.join.active_eta_s is None:
            return False
        st = self.drones[ms.active].status
        if st is None or now - ms.join_sent_t > ms.join.active_eta_s + self.model.margin_s:
            return False
        cov = ms.coverage
        visited = (
            {k for k, v in enumerate(cov.visits) if v and v[-1] >= ms.join_sent_t}
            if cov is not None
            else set()
        )
        return owes_waypoints(ms.mission.route, ms.mission.loop, ms.join, st.position, visited)

    def _dispatch(
        self,
        rec: DroneRecord,
        ms: MissionRecord,
        now: float,
        out: list[Dispatch],
        join: JoinPoint | None = None,
    ) -> None:
        assert rec.status is not None
        m = ms.mission
        start = join.index if join is not None else self.entry_index(rec.status.station, m.route)
        ms.join = join if join is not None else JoinPoint(start, 0.0, None)
        ms.join_sent_t, ms.relief_on_route_t = now, None
        plan = FlightPlan(
            next(self._plan_ids),
            PlanKind.PATROL,
            mission=m.id,
            route=m.route,
            loop=m.loop,
            start_index=start,
            cruise_z=m.altitude_m,
            headings_deg=m.headings_deg,
            join=join.point if join is not None else None,
            # GPS-guided: the arrival radius comes from the GPS noise (server/fleet/accuracy.py)
            tolerance_m=GPS_ARRIVAL_RADIUS_M if self.origin is not None else 1.0,
        )
        rec.plan, rec.plan_sent_t, rec.role, rec.mission = plan, now, DroneRole.RELIEVING, m.id
        ms.relief = rec.name
        who = f"to relieve {ms.active}" if ms.active else "to patrol"
        self.event(
            now,
            f"{rec.name} dispatched {who} on {m.id} ({rec.status.battery_pct:.0f} %), "
            f"joining at waypoint {start + 1}",
        )
        out.append(Dispatch(rec.name, plan))

    def _hold(self, rec: DroneRecord, now: float) -> None:
        """Hover where it is (a paused mission's drone); sent by the next step."""
        plan = FlightPlan(next(self._plan_ids), PlanKind.HOLD)
        rec.plan, rec.plan_sent_t, rec.role = plan, -math.inf, DroneRole.PAUSED

    def _send_home(
        self,
        rec: DroneRecord,
        now: float,
        mission: Mission | None,
        out: list[Dispatch] | None = None,
    ) -> None:
        # Return one layer above the route so it does not meet the relief climbing to it.
        z = (mission.altitude_m if mission else (rec.status.z if rec.status else 5.0)) + 2.0
        if self.world is not None and hasattr(self.world, "bounds"):
            from drone.limits import limits_of

            z = min(z, limits_of(self.world).ceiling_m)  # a mission's layer was checked
        plan = FlightPlan(next(self._plan_ids), PlanKind.RETURN, cruise_z=max(z, 1.0))
        rec.plan, rec.plan_sent_t, rec.role, rec.mission = plan, now, DroneRole.RETURNING, ""
        if out is not None:
            out.append(Dispatch(rec.name, plan))
        else:
            rec.plan_sent_t = -math.inf  # sent by the next step's resend pass

    # ------------------------------------------------------------------ output
    def fleet_status(self, now: float, stamp: dict[str, Any] | None = None) -> dict[str, Any]:
        """The ``uav_console/FleetStatus`` message (``/fleet/status``)."""
        drones = []
        for rec in sorted(self.drones.values(), key=lambda r: r.name):
            st = rec.status
            p = st.position if st else Enu(0.0, 0.0, 0.0)
            drones.append(
                {
                    "name": rec.name,
                    "role": rec.role.value,
                    "position": {"x": p.x, "y": p.y, "z": p.z},
                    "yaw_deg": st.yaw_deg if st else 0.0,
                    "latitude": st.lat if st else 0.0,
                    "longitude": st.lon if st else 0.0,
                    "battery": st.battery_pct if st else 0.0,
                    "state": st.state if st else "UNKNOWN",
                    "mission": rec.mission,
                    "link": rec.role is not DroneRole.LOST,
                }
            )
        header = {"stamp": stamp or {"sec": int(now), "nanosec": 0}, "frame_id": "map"}
        events = [f"{t:.1f} {text}" for t, text in list(self.events)[-20:]]
        return {"header": header, "drones": drones, "events": events}

    def missions_status(self, now: float) -> list[dict[str, Any]]:
        """Every mission not ended, with live coverage (``/fleet/missions``)."""
        live = [mid for mid, ms in self.missions.items() if ms.state.live]
        return [self.mission_info(mid, now) for mid in live]


def segment_distance(p: Enu, a: Enu, b: Enu) -> float:
    """Horizontal distance from ``p`` to segment ``ab``."""
    dx, dy = b.x - a.x, b.y - a.y
    L2 = dx * dx + dy * dy
    t = 0.0 if L2 == 0 else max(0.0, min(1.0, ((p.x - a.x) * dx + (p.y - a.y) * dy) / L2))
    return math.hypot(p.x - (a.x + t * dx), p.y - (a.y + t * dy))


def route_distance(p: Enu, route: Sequence[Enu], loop: bool) -> float:
    """Horizontal distance from ``p`` to the route polyline (closed when ``loop``)."""
    if len(route) == 1:
        return p.dist_xy(route[0])
    n = len(route) if loop else len(route) - 1
    return min(segment_distance(p, route[i], route[(i + 1) % len(route)]) for i in range(n))
