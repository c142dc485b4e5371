"""Altitude frames of the simulated PX4, in lockstep against the console's protocol: NAV_TAKEOFF
read as PX4's navigator reads it (param7 AMSL; NaN: MIS_TAKEOFF_ALT above the vehicle; never
down), GLOBAL_POSITION_INT's ``alt`` (AMSL) and ``relative_alt`` (above home) agreeing with
HOME_POSITION, a take-off above the room's ceiling or the geofence refused with its reason
instead of flown to the ceiling and never finished, and the local NED frame staying at its
origin when home moves."""

from __future__ import annotations

import math
from typing import Any

import pytest

from drone.mavlink.codec import mav
from drone.mavlink.gcs.events import CommandResult, MissionResult, StatusText
from drone.mavlink.gcs.protocol import GcsProtocol
from drone.mavlink.link import MavlinkMemoryLink
from drone.mavlink.sim.autopilot import SimAutopilot
from drone.sim.world import load_world

DT = 0.02
TAKEOFF = mav.MAV_CMD_NAV_TAKEOFF


class Rig:
    """The console's protocol and the simulated PX4 joined in memory, on a virtual clock."""

    def __init__(self, world: Any) -> None:
        self.ap = SimAutopilot(world)
        self.p = GcsProtocol()
        self.link = MavlinkMemoryLink(self.p, self.ap)
        self.t = 0.0
        self.events: list[Any] = []
        assert self.until(
            lambda: self.p.connected and self.p.telemetry.home and not self.p.pending_commands(),
            5.0,
        )

    def until(self, pred: Any, timeout: float) -> bool:
        end = self.t + timeout
        while self.t < end:
            self.events += self.link.step(self.t, DT)
            self.t += DT
            if pred():
                return True
        return False

    def run(self, seconds: float) -> None:
        self.until(lambda: False, seconds)

    def command(self, command: int, *params: float) -> CommandResult:
        token = self.p.command(command, *params, now=self.t)
        found: list[CommandResult] = []

        def answered() -> bool:
            found[:] = [e for e in self.events if isinstance(e, CommandResult) and e.token == token]
            return bool(found)

        assert self.until(answered, 5.0), f"no answer to command {command}"
        return found[0]

    def texts(self) -> list[str]:
        return [e.text for e in self.events if isinstance(e, StatusText)]

    @property
    def home_amsl(self) -> float:
        home = self.p.telemetry.home
        assert home is not None
        return home[2]

    def arm(self) -> None:
        assert self.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1.0).ok

    def settled(self, rel_alt_m: float) -> bool:
        t = self.p.telemetry
        return abs(t.rel_alt_m - rel_alt_m) < 0.1 and t.mode == "AUTO.LOITER"


@pytest.fixture(scope="module")
def outdoor() -> Any:
    return load_world("outdoor")


@pytest.fixture(scope="module")
def indoor() -> Any:
    return load_world("indoor")


def test_takeoff_without_an_altitude_climbs_mis_takeoff_alt_and_frames_agree(
    outdoor: Any,
) -> None:
    """MAVSDK's takeoff on PX4: param7 NaN after set_takeoff_altitude (MIS_TAKEOFF_ALT)."""
    r = Rig(outdoor)
    r.ap.params.MIS_TAKEOFF_ALT = 5.0
    r.arm()
    nan = math.nan
    assert r.command(TAKEOFF, -1.0, 0.0, 0.0, nan, nan, nan, nan).ok
    assert r.until(lambda: r.settled(5.0), 20.0), r.p.telemetry
    assert "Using default takeoff altitude: 5.0 m" in r.texts()
    t = r.p.telemetry
    # AMSL, above home, and the local frame tell one height
    assert t.alt_amsl_m - r.home_amsl == pytest.approx(t.rel_alt_m, abs=0.01)
    assert t.local_ned is not None and -t.local_ned[2] == pytest.approx(t.rel_alt_m, abs=0.05)
    assert r.ap.physics.body.z == pytest.approx(5.0, abs=0.1)


def test_takeoff_param7_is_amsl_and_never_brings_the_vehicle_down(outdoor: Any) -> None:
    r = Rig(outdoor)
    r.arm()
    assert r.command(TAKEOFF, -1.0, 0, 0, math.nan, math.nan, math.nan, r.home_amsl + 4.0).ok
    assert r.until(lambda: r.settled(4.0), 20.0), r.p.telemetry
    # in the air, a take-off to a lower altitude keeps the vehicle where it is (PX4 takeoff.cpp)
    assert r.command(TAKEOFF, -1.0, 0, 0, math.nan, math.nan, math.nan, r.home_amsl + 1.0).ok
    assert "Already higher than takeoff altitude" in r.texts()
    r.run(5.0)
    assert r.p.telemetry.rel_alt_m == pytest.approx(4.0, abs=0.1)


def test_takeoff_above_the_ceiling_is_refused_with_the_reason(indoor: Any) -> None:
    """A 3 m room: a take-off to 5 m would stop at the ceiling (2.88 m) and stay in AUTO.TAKEOFF
    for good, a ground station seeing 2.88 m and no reason; it is refused, and says why."""
    r = Rig(indoor)
    r.ap.params.MIS_TAKEOFF_ALT = 5.0
    r.arm()
    result = r.command(TAKEOFF, -1.0, 0, 0, math.nan, math.nan, math.nan, math.nan)
    assert result.result == "DENIED"
    assert result.reason == "Takeoff denied: 5.0 m above ceiling (2.9 m)"
    assert r.ap.mode != "AUTO.TAKEOFF" and r.ap.physics.body.z == pytest.approx(0.0)
    r.ap.params.MIS_TAKEOFF_ALT = 2.0
    assert r.command(TAKEOFF, -1.0, 0, 0, math.nan, math.nan, math.nan, math.nan).ok
    assert r.until(lambda: r.settled(2.0), 20.0), r.p.telemetry


def test_geofence_max_vertical_distance_refuses_what_would_breach_it(outdoor: Any) -> None:
    r = Rig(outdoor)
    r.ap.params.GF_MAX_VER_DIST = 4.0
    r.arm()
    high = r.command(TAKEOFF, -1.0, 0, 0, math.nan, math.nan, math.nan, r.home_amsl + 6.0)
    assert (high.result, high.reason) == ("DENIED", "Takeoff denied: 6.0 m above geofence (4.0 m)")
    assert r.command(TAKEOFF, -1.0, 0, 0, math.nan, math.nan, math.nan, r.home_amsl + 3.0).ok
    assert r.until(lambda: r.settled(3.0), 20.0)
    lat, lon = r.p.telemetry.lat_deg, r.p.telemetry.lon_deg
    token = r.p.goto(lat, lon, r.home_amsl + 8.0, now=r.t)
    assert r.until(lambda: any(getattr(e, "token", None) == token for e in r.events), 5.0)
    goto = next(e for e in r.events if isinstance(e, CommandResult) and e.token == token)
    assert (goto.result, goto.reason) == ("DENIED", "Reposition is outside geofence")
    r.p.upload_mission([(lat, lon, 3.5), (lat, lon, 9.0)], r.t)
    assert r.until(lambda: any(isinstance(e, MissionResult) for e in r.events), 10.0)
    mission = next(e for e in r.events if isinstance(e, MissionResult))
    assert not mission.ok and "Mission item 1 too high" in r.texts()
    assert r.p.telemetry.rel_alt_m == pytest.approx(3.0, abs=0.1)


def test_local_frame_stays_at_its_origin_when_home_moves(outdoor: Any) -> None:
    """PX4's local NED origin is where its estimator started; home is where it last armed."""
    r = Rig(outdoor)
    r.arm()
    assert r.command(TAKEOFF, -1.0, 0, 0, math.nan, math.nan, math.nan, r.home_amsl + 3.0).ok
    assert r.until(lambda: r.settled(3.0), 20.0)
    lat, lon, _ = r.ap.origin.to_geo(10.0, 0.0, 0.0)  # 10 m east of the start
    assert r.command(
        mav.MAV_CMD_DO_REPOSITION, -1.0, 1.0, 0.0, math.nan, lat, lon, r.home_amsl + 3.0
    ).ok
    assert r.until(lambda: math.hypot(r.ap.physics.body.x - 10.0, r.ap.physics.body.y) < 0.2, 30)
    r.p.intent("land", r.t)
    assert r.until(lambda: not r.p.telemetry.armed, 30.0)  # landed, auto-disarmed
    before = r.p.telemetry.local_ned
    r.arm()  # home moves here
    r.run(3.0)  # HOME_POSITION at 0.5 Hz
    t = r.p.telemetry
    assert before is not None and t.local_ned is not None
    assert t.local_ned[1] == pytest.approx(before[1], abs=0.05) == pytest.approx(10.0, abs=0.3)
    assert t.home_local is not None and t.home_local[1] == pytest.approx(10.0, abs=0.3)
    assert t.home is not None and t.home[1] == pytest.approx(lon, abs=3e-6)
