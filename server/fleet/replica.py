"""The central task manager's state as JSON, for a standby console to keep and resume from.

:func:`snapshot` writes everything the CTM decides with: each drone's record (its last status,
role, mission, plan, battery samples) and each mission's (state, active drone and relief, the
join in flight, coverage: every waypoint's visits), and the next plan and mission ids.
:func:`restore` puts such a snapshot into another CTM, which then decides as the first would
have: the mission goes on where it stands, it does not start again.

Times: a CTM reads its own clock (monotonic, so each process's own). A snapshot stores every time
as its offset from the snapshot's ``now``; :func:`restore` adds the receiver's ``now``, so the
times keep their meaning across clocks (the bus's delay, milliseconds, is the error).

Plan ids: the central that wrote a snapshot may have sent plans after it (a snapshot is at most
a publication old); the restored CTM numbers its plans from ``PLAN_ID_MARGIN`` past the
snapshot's, and past any plan id its drones report, so that no LTM takes a new plan for one it
already flies (an LTM ignores a plan whose id it flies: ``LocalTaskManager.apply_plan``).

Statuses the snapshot lacks: a standby hears the LTMs' statuses itself, and one may reach it
before a snapshot that was taken before the central had it (the central's loop had not yet
handled it). :func:`restore` applies such statuses again (``heard``: a status whose ``seq`` is
past the one its drone's record holds), so that a replica never takes the standby back to an
older position, an older ``last_heard`` or a waypoint visit fewer; were the central to die
before its next snapshot, the standby would otherwise resume from them.
"""

from __future__ import annotations

import itertools
import math
from collections import deque
from collections.abc import Iterable, Mapping
from typing import Any

from server.fleet.continuity import (
    MAX_VISITS,
    CoverageTracker,
    HandoffRecord,
    JoinPoint,
    RouteCoverage,
)
from server.fleet.ctm import CentralTaskManager, DroneRecord, MissionRecord
from server.fleet.errors import MessageError
from server.fleet.geo import Enu
from server.fleet.messages import DroneRole, FlightPlan, Handoff, LtmStatus, Mission
from server.fleet.states import MissionState

VERSION = 1
PLAN_ID_MARGIN = 1000  # plans a central may send between two snapshots, and then some
SAMPLES_MAXLEN = 400  # DroneRecord.samples


def snapshot(ctm: CentralTaskManager, now: float) -> dict[str, Any]:
    """The CTM's state at ``now`` (its clock), JSON-ready (see the module docstring)."""
    next_plan = next(ctm._plan_ids)
    ctm._plan_ids = itertools.count(next_plan)  # reading the counter must not consume an id
    next_mission = next(ctm._mission_ids)
    ctm._mission_ids = itertools.count(next_mission)
    return {
        "v": VERSION,
        "next_plan_id": next_plan,
        "next_mission_id": next_mission,
        "drones": [_drone(r, now) for r in ctm.drones.values()],
        "missions": [_mission_record(m, now) for m in ctm.missions.values()],
    }


def restore(
    ctm: CentralTaskManager,
    data: Any,
    now: float,
    heard: Iterable[tuple[LtmStatus, float]] = (),
) -> None:
    """Replace ``ctm``'s drones and missions with those of ``data`` (a :func:`snapshot`),
    its times moved onto ``now``; then apply again each status of ``heard`` (a status and when
    this CTM heard it, on its clock) that the snapshot's drone record does not include yet
    (see the module docstring).

    Raises:
        MessageError: ``data`` is not a snapshot of this version (nothing is changed then).
    """
    d = _obj(data, "replica")
    if d.get("v") != VERSION:
        raise MessageError(f"replica version {d.get('v')!r} (this console reads {VERSION})")
    try:
        drones = {r.name: r for r in (_drone_of(x, now) for x in _list(d, "drones"))}
        missions = {
            m.mission.id: m for m in (_mission_record_of(x, now) for x in _list(d, "missions"))
        }
        next_plan = _int(d, "next_plan_id")
        next_mission = _int(d, "next_mission_id")
    except (KeyError, TypeError, ValueError) as exc:  # MessageError is a ValueError
        raise MessageError(f"replica: {exc}") from exc
    ctm.drones = drones
    ctm.missions = missions
    _replay(ctm, heard)
    reported = max((r.status.plan_id for r in ctm.drones.values() if r.status), default=0)
    ctm._plan_ids = itertools.count(max(next_plan, reported + 1) + PLAN_ID_MARGIN)
    ctm._mission_ids = itertools.count(next_mission)
    ctm._now = now


def _replay(ctm: CentralTaskManager, heard: Iterable[tuple[LtmStatus, float]]) -> None:
    """The statuses of ``heard`` newer than their drones' records (a higher ``seq``: an LTM
    numbers its statuses), in the order they were heard, at the times they were heard."""
    for status, t in sorted(heard, key=lambda h: h[1]):
        rec = ctm.drones.get(status.name)
        if rec is not None and rec.status is not None and status.seq <= rec.status.seq:
            continue  # the snapshot has it, or a later one of that drone
        ctm.on_status(status, t)


# ---------------------------------------------------------------------- times
def _age(t: float | None, now: float) -> float | None:
    """``t`` as an offset from ``now``; JSON has no infinity, so "never" is None."""
    if t is None or not math.isfinite(t):
        return None
    return t - now


def _at(v: Any, now: float, never: float | None = -math.inf) -> float | None:
    if v is None:
        return never
    return _float(v) + now


def _at_f(v: Any, now: float) -> float:
    t = _at(v, now)
    assert t is not None
    return t


# ---------------------------------------------------------------------- drones
def _drone(r: DroneRecord, now: float) -> dict[str, Any]:
    return {
        "name": r.name,
        "status": None if r.status is None else r.status.to_dict(),
        "last_heard": _age(r.last_heard, now),
        "role": r.role.value,
        "mission": r.mission,
        "plan": None if r.plan is None else r.plan.to_dict(),
        "plan_sent_t": _age(r.plan_sent_t, now),
        "lost_reason": r.lost_reason,
        "lost_from": r.lost_from.value,
        "charging_since": _age(r.charging_since, now),
        "samples": [[_age(t, now), b] for t, b in r.samples],
    }


def _drone_of(x: Any, now: float) -> DroneRecord:
    d = _obj(x, "drone")
    samples: deque[tuple[float, float]] = deque(maxlen=SAMPLES_MAXLEN)
    for t, b in _list(d, "samples"):
        samples.append((_at_f(t, now), _float(b)))
    return DroneRecord(
        name=_str(d, "name"),
        status=None if d.get("status") is None else LtmStatus.from_dict(d["status"]),
        last_heard=_at_f(d.get("last_heard"), now),
        role=DroneRole(d["role"]),
        mission=_str(d, "mission"),
        plan=None if d.get("plan") is None else FlightPlan.from_dict(d["plan"]),
        plan_sent_t=_at_f(d.get("plan_sent_t"), now),
        lost_reason=_str(d, "lost_reason"),
        lost_from=DroneRole(d["lost_from"]),
        charging_since=_at_f(d.get("charging_since"), now),
        samples=samples,
    )


# ---------------------------------------------------------------------- missions
def _enu(p: Enu | None) -> list[float] | None:
    return None if p is None else [p.x, p.y, p.z]


def _enu_of(v: Any) -> Enu | None:
    if v is None:
        return None
    x, y, z = v
    return Enu(_float(x), _float(y), _float(z))


def _enu_f(v: Any) -> Enu:
    p = _enu_of(v)
    if p is None:
        raise MessageError("a point is missing")
    return p


def _mission(m: Mission, now: float) -> dict[str, Any]:
    return {
        "id": m.id,
        "route": [_enu(p) for p in m.route],
        "loop": m.loop,
        "threshold": m.threshold,
        "created_t": _age(m.created_t, now),
        "geo": [list(g) for g in m.geo],
        "headings_deg": list(m.headings_deg),
        "handoff": m.handoff.value,
    }


def _mission_of(x: Any, now: float) -> Mission:
    d = _obj(x, "mission")
    geo = tuple((_float(a), _float(b), _float(c)) for a, b, c in _list(d, "geo"))
    return Mission(
        id=_str(d, "id"),
        route=tuple(_enu_f(p) for p in _list(d, "route")),
        loop=bool(d["loop"]),
        threshold=_float(d["threshold"]),
        created_t=_at_f(d.get("created_t"), now),
        geo=geo,
        headings_deg=tuple(_float(h) for h in _list(d, "headings_deg")),
        handoff=Handoff(d["handoff"]),
    )


def _coverage(c: CoverageTracker, now: float) -> dict[str, Any]:
    return {
        "route": [_enu(p) for p in c.route],
        "started_t": _age(c.started_t, now),
        "visit_radius_m": c.visit_radius_m,
        "visits": [[_age(t, now) for t in v] for v in c.visits],
        "handoffs": [
            {
                "t": _age(h.t, now),
                "relieved": h.relieved,
                "relief": h.relief,
                "join_index": h.join_index,
                "kind": h.kind,
            }
            for h in c.handoffs
        ],
        "inside": [[name, k, inside] for (name, k), inside in c._inside.items()],
        "route_coverage": _route_coverage(c.route_coverage, now),
    }


def _route_coverage(r: RouteCoverage, now: float) -> dict[str, Any]:
    return {
        "first_t": _age(r.first_t, now),
        "last_t": _age(r.last_t, now),
        "covered_s": r.covered_s,
        "gap_start": _age(r.gap_start, now),
        "gaps": r.gaps,
        "longest_gap_s": r.longest_gap_s,
    }


def _route_coverage_of(x: Any, now: float) -> RouteCoverage:
    if x is None:  # a replica from a console without route coverage
        return RouteCoverage()
    d = _obj(x, "route_coverage")
    return RouteCoverage(
        first_t=_at(d.get("first_t"), now, never=None),
        last_t=_at(d.get("last_t"), now, never=None),
        covered_s=_float(d["covered_s"]),
        gap_start=_at(d.get("gap_start"), now, never=None),
        gaps=int(d["gaps"]),
        longest_gap_s=_float(d["longest_gap_s"]),
    )


def _coverage_of(x: Any, now: float) -> CoverageTracker:
    d = _obj(x, "coverage")
    route = tuple(_enu_f(p) for p in _list(d, "route"))
    visits = [deque((_at_f(t, now) for t in v), maxlen=MAX_VISITS) for v in _list(d, "visits")]
    if len(visits) != len(route):
        raise MessageError("coverage: one list of visits a waypoint")
    handoffs = [
        HandoffRecord(
            _at_f(h["t"], now),
            str(h["relieved"]),
            str(h["relief"]),
            int(h["join_index"]),
            str(h["kind"]),
        )
        for h in (_obj(h, "handoff") for h in _list(d, "handoffs"))
    ]
    inside = {(str(n), int(k)): bool(v) for n, k, v in _list(d, "inside")}
    return CoverageTracker(
        route,
        _at_f(d.get("started_t"), now),
        _float(d["visit_radius_m"]),
        visits,
        handoffs,
        _route_coverage_of(d.get("route_coverage"), now),
        _inside=inside,
    )


def _join(j: JoinPoint | None) -> dict[str, Any] | None:
    if j is None:
        return None
    return {
        "index": j.index,
        "relief_eta_s": j.relief_eta_s,
        "active_eta_s": j.active_eta_s,
        "point": _enu(j.point),
        "after": j.after,
    }


def _join_of(x: Any) -> JoinPoint | None:
    if x is None:
        return None
    d = _obj(x, "join")
    eta = d.get("active_eta_s")
    after = d.get("after")
    return JoinPoint(
        _int(d, "index"),
        _float(d["relief_eta_s"]),
        None if eta is None else _float(eta),
        _enu_of(d.get("point")),
        None if after is None else int(after),
    )


def _mission_record(m: MissionRecord, now: float) -> dict[str, Any]:
    return {
        "mission": _mission(m.mission, now),
        "active": m.active,
        "relief": m.relief,
        "handoffs": m.handoffs,
        "replacements": m.replacements,
        "started_t": _age(m.started_t, now),
        "state": m.state.value,
        "detail": m.detail,
        "paused": dict(m.paused),
        "paused_by": dict(m.paused_by),
        "coverage": None if m.coverage is None else _coverage(m.coverage, now),
        "join": _join(m.join),
        "join_sent_t": _age(m.join_sent_t, now),
        "relief_on_route_t": _age(m.relief_on_route_t, now),
        "last_known": _enu(m.last_known),
        "gap_from": None if m.gap_from is None else list(m.gap_from),
        "ended_t": _age(m.ended_t, now),
    }


def _mission_record_of(x: Any, now: float) -> MissionRecord:
    d = _obj(x, "mission record")
    gap = d.get("gap_from")
    return MissionRecord(
        mission=_mission_of(d["mission"], now),
        active=_opt_str(d, "active"),
        relief=_opt_str(d, "relief"),
        handoffs=_int(d, "handoffs"),
        replacements=_int(d, "replacements"),
        started_t=_at(d.get("started_t"), now, never=None),
        state=MissionState(d["state"]),
        detail=_str(d, "detail"),
        paused={str(k): str(v) for k, v in _obj(d["paused"], "paused").items()},
        paused_by={str(k): str(v) for k, v in _obj(d["paused_by"], "paused_by").items()},
        coverage=None if d.get("coverage") is None else _coverage_of(d["coverage"], now),
        join=_join_of(d.get("join")),
        join_sent_t=_at(d.get("join_sent_t"), now, never=0.0) or 0.0,
        relief_on_route_t=_at(d.get("relief_on_route_t"), now, never=None),
        last_known=_enu_of(d.get("last_known")),
        gap_from=None if gap is None else (str(gap[0]), str(gap[1])),
        ended_t=_at(d.get("ended_t"), now, never=None),
    )


# ---------------------------------------------------------------------- checks
def _obj(x: Any, what: str) -> Mapping[str, Any]:
    if not isinstance(x, Mapping):
        raise MessageError(f"{what} must be a JSON object")
    return x


def _list(d: Mapping[str, Any], key: str) -> list[Any]:
    v = d.get(key)
    if not isinstance(v, list):
        raise MessageError(f"field {key!r} must be a list")
    return v


def _float(v: Any) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise MessageError(f"{v!r} is not a finite number")
    return float(v)


def _int(d: Mapping[str, Any], key: str) -> int:
    v = d.get(key)
    if isinstance(v, bool) or not isinstance(v, int):
        raise MessageError(f"field {key!r} must be an integer")
    return v


def _str(d: Mapping[str, Any], key: str) -> str:
    v = d.get(key)
    if not isinstance(v, str):
        raise MessageError(f"field {key!r} must be a string")
    return v


def _opt_str(d: Mapping[str, Any], key: str) -> str | None:
    v = d.get(key)
    return None if v is None else _str(d, key)
