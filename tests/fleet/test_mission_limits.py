"""Missions are bounded (issue 14): names are URL-safe, routes and counts capped, stopped
missions expire. A mission named ``a/b`` or 100 KB long could not be stopped before."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from server.fleet.ctm import CentralTaskManager
from server.fleet.errors import MissionError, NotFoundError
from server.fleet.geo import Enu
from server.fleet.messages import MAX_ROUTE_POINTS, MissionRequest

ROUTE = [Enu(0, 0, 5), Enu(10, 0, 5)]


@pytest.mark.parametrize("name", ["a/b", "x" * 65, "", "-dash", "sp ace", "\u00e9t\u00e9", ".."])
def test_bad_mission_names_are_refused(name: str) -> None:
    with pytest.raises(ValidationError):
        MissionRequest(markers=[1], name=name)
    with pytest.raises(MissionError, match="mission name"):
        CentralTaskManager().add_mission(ROUTE, now=0.0, mission_id=name)


def test_good_names_and_route_cap() -> None:
    assert MissionRequest(markers=[1], name="north-loop_2.b").name == "north-loop_2.b"
    with pytest.raises(ValidationError):
        MissionRequest(markers=[1] * (MAX_ROUTE_POINTS + 1))
    with pytest.raises(ValidationError):
        MissionRequest(waypoints=[{"lat": float("nan"), "lon": 0.0}])
    with pytest.raises(MissionError, match="at most"):
        CentralTaskManager().add_mission([ROUTE[0]] * (MAX_ROUTE_POINTS + 1), now=0.0)


def test_mission_count_is_capped_and_ended_missions_expire() -> None:
    ctm = CentralTaskManager(max_missions=3, ended_keep_s=60.0)
    ids = [ctm.add_mission(ROUTE, now=0.0).id for _ in range(3)]
    with pytest.raises(MissionError, match="at most 3 missions"):
        ctm.add_mission(ROUTE, now=1.0)
    ctm.end_mission(ids[0], now=10.0)
    # ended but still readable for a while, and still counted
    assert ctm.mission_info(ids[0])["state"] == "ended"
    with pytest.raises(MissionError):
        ctm.add_mission(ROUTE, now=20.0)
    ctm.step(71.0)  # 61 s after it ended: forgotten
    with pytest.raises(NotFoundError):
        ctm.mission_info(ids[0])
    new = ctm.add_mission(ROUTE, now=72.0)
    assert new.id not in ids  # generated ids never repeat a live one
    # ending again does not restart its clock
    ctm.end_mission(ids[1], now=80.0)
    ctm.end_mission(ids[1], now=130.0)
    ctm.step(141.0)
    assert ids[1] not in ctm.missions
