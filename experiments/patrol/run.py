"""The patrol experiment's rig: the lockstep simulators, task managers, LTMs, CTM and home
stations, stepped together; ``PatrolExperiment.run`` flies the mission and measures it."""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from typing import Any

from experiments.patrol.config import MAX_DRONES, PatrolConfig
from experiments.patrol.metrics import CoverageMeter, TrackLog, handoff_revisits, revisit_table
from experiments.patrol.report import PatrolReport
from server.fleet.ctm import CentralTaskManager
from server.fleet.geo import Enu, origin_of, to_geo
from server.fleet.ltm import LocalTaskManager
from server.fleet.messages import DroneRole, GeoWaypoint, Handoff, Mission, MissionRequest
from server.fleet.planner import FlightModel, StationModel, coverage_bound
from server.fleet.stations import station_positions


def charging_world(world: Any, pads: Sequence[Enu], charge_pct_s: float | None) -> Any:
    """``world`` with one station per pad, each charging at ``charge_pct_s`` (None: plain
    pads, the experiment's stations swap batteries instead)."""
    import dataclasses

    from drone.sim.world import Station

    stations = tuple(
        Station(f"home{k + 1}", (p.x, p.y, p.z), charge_pct_s=charge_pct_s or 0.0)
        for k, p in enumerate(pads)
    )
    return dataclasses.replace(world, stations=stations)


class StationService:
    """A home station: restores a drone that lands on it, with a battery swap after ``swap_s``
    or by charging (the AR.Drone simulator charges on the world's pads itself; a simulator
    without pads of its own, MAVLink's, is charged here)."""

    def __init__(self, sim: Any, position: Enu, model: StationModel) -> None:
        self.sim = sim
        self.position = position
        self.model = model
        self.landed_since: float | None = None
        self.restores = 0

    def step(self, now: float, dt: float) -> None:
        t = self.sim.truth
        here = math.hypot(t.x - self.position.x, t.y - self.position.y) < 1.5
        if t.flying or t.emergency or not here:
            self.landed_since = None
            return
        if self.landed_since is None:
            self.landed_since = now
        bat = self.sim.physics.battery
        if self.model.charge_pct_s is not None:
            if not hasattr(self.sim, "charging") and bat.pct < 100.0:
                bat.drain_to(bat.pct + self.model.charge_pct_s * dt)
        elif bat.pct < self.model.ready_pct and now - self.landed_since >= self.model.swap_s:
            bat.drain_to(100.0)
            self.restores += 1


class LockstepLink:
    """The CTM ↔ LTM transport in lockstep: direct calls, per-drone ``connected`` switch."""

    def __init__(self, ctm: CentralTaskManager, ltms: Sequence[LocalTaskManager]) -> None:
        self.ctm = ctm
        self.ltms = {x.name: x for x in ltms}
        self.connected = {x.name: True for x in ltms}
        self.sent = 0

    def status(self, ltm: LocalTaskManager, now: float) -> None:
        st = ltm.step(now)
        if st is not None and self.connected[ltm.name]:
            self.ctm.on_status(st, now)

    def ctm_step(self, now: float) -> None:
        for d in self.ctm.step(now):
            if not self.connected.get(d.drone, False):
                continue
            self.sent += 1
            ok, reason = self.ltms[d.drone].apply_plan(d.plan, now)
            self.ctm.on_plan_result(d.drone, d.plan.plan_id, ok, reason, now)
        for name, ltm in self.ltms.items():
            if self.connected[name]:
                ltm.heard_ctm(now)  # the /fleet/status heartbeat


class PatrolExperiment:
    """Build the rig, CTM, LTMs and stations; ``run`` flies the mission and measures it."""

    def __init__(self, cfg: PatrolConfig) -> None:
        from drone.lockstep import LockstepRig
        from drone.sim.battery import FLIGHT_TIME_S
        from drone.sim.world import load_world
        from server.tasks.manager import TaskManager

        if not 1 <= cfg.drones <= MAX_DRONES:
            raise ValueError(f"--drones must be in 1..{MAX_DRONES}, got {cfg.drones}")
        if not cfg.duration_s > 0:
            raise ValueError(f"--duration must be > 0, got {cfg.duration_s}")
        try:
            self.handoff = Handoff(cfg.handoff)
        except ValueError:
            raise ValueError(
                f"--handoff must be reactive or predictive, got {cfg.handoff!r}"
            ) from None
        self.cfg = cfg
        pads = station_positions(load_world("outdoor"), cfg.drones)
        self.world = charging_world(load_world("outdoor"), pads, cfg.charge_pct_s)
        yaw = self.world.start.yaw_rad
        self.rig: Any
        if cfg.protocol == "mavlink":
            from drone.mavlink.lockstep import MavlinkLockstepRig

            self.rig = MavlinkLockstepRig(
                self.world, cfg.drones, dt=cfg.dt, starts=[(p.x, p.y, yaw) for p in pads]
            )
        else:
            self.rig = LockstepRig(
                self.world,
                n_drones=cfg.drones,
                seed=cfg.seed,
                camera=False,
                dt=cfg.dt,
                starts=[(p.x, p.y, yaw) for p in pads],
            )
        flight = cfg.flight_time_s or FLIGHT_TIME_S
        for sim in self.rig.sims:
            sim.physics.battery.flight_time_s = flight
        self.model = FlightModel.for_flight_time(flight)
        self.station_model = StationModel(swap_s=cfg.swap_s, charge_pct_s=cfg.charge_pct_s)
        self.origin = origin_of(self.world)
        self.ctm = CentralTaskManager(
            model=self.model,
            stations=self.station_model,
            lost_after_s=cfg.lost_after_s,
            corridor_m=cfg.corridor_m,
            origin=self.origin,
            world=self.world,
            continuity=cfg.continuity,
        )
        self.tasks = []
        self.ltms: list[LocalTaskManager] = []
        self.stations: list[StationService] = []
        for i, v in enumerate(self.rig.vehicles):
            tm = TaskManager(v, self.world, self.rig.clock)
            st = pads[i]
            ltm = LocalTaskManager(
                v.name,
                v,
                tm,
                st,
                origin=self.origin,
                period_s=cfg.status_period_s,
                ctm_timeout_s=cfg.ctm_timeout_s,
                model=self.model,
            )
            self.tasks.append(tm)
            self.ltms.append(ltm)
            self.stations.append(StationService(self.rig.sims[i], st, self.station_model))
        self.link = LockstepLink(self.ctm, self.ltms)
        self.hooks: list[Callable[[float], None]] = []  # tests: f(now) after each tick
        self._failed = False
        self._next_ctm = 0.0
        self._next_ltm = 0.0

    def mission_request(self) -> MissionRequest:
        """The paper's mission as ``POST /missions`` gets it: the world's waypoints in lat/lon."""
        assert self.origin is not None
        wps = []
        for w in self.world.waypoints:
            g = to_geo(Enu(*map(float, w.position)), self.origin)
            wps.append(GeoWaypoint(lat=g.lat_deg, lon=g.lon_deg, alt=g.alt_m))
        return MissionRequest(
            waypoints=wps, loop=True, handoff_threshold=self.cfg.threshold, handoff=self.handoff
        )

    def _tick(self, now: float, dt: float) -> None:
        for tm in self.tasks:
            tm.step(now)
        for s in self.stations:
            s.step(now, dt)
        if now + 1e-9 >= self._next_ltm:
            self._next_ltm += 0.2
            for ltm in self.ltms:
                self.link.status(ltm, now)
        if now + 1e-9 >= self._next_ctm:
            self._next_ctm += self.cfg.ctm_period_s
            self.link.ctm_step(now)
        cfg = self.cfg
        if cfg.fail_at_s is not None and not self._failed and now >= cfg.fail_at_s:
            self.fail_active(now)
        for h in self.hooks:
            h(now)

    def fail_active(self, now: float) -> str | None:
        """Make the patrolling drone fail (``fail_kind``); returns its name."""
        self._failed = True
        for ms in self.ctm.missions.values():
            if ms.active is not None:
                i = int(ms.active.removeprefix("uav")) - 1
                if self.cfg.fail_kind == "link":
                    self.rig.sims[i].inject_fault("link_loss", duration_s=60.0)
                else:
                    self.rig.sims[i].physics.cut_motors()
                self.ctm.event(now, f"[experiment] {ms.active} fails ({self.cfg.fail_kind})")
                return ms.active
        return None

    def run(self) -> PatrolReport:
        """Fly the mission for ``duration_s`` simulated seconds and measure it."""
        wall0, cpu0 = time.perf_counter(), time.process_time()
        mission, t0 = self._start()
        rig = self.rig
        names = [v.name for v in rig.vehicles]
        meter = CoverageMeter(
            names, mission.route, t0, rig.dt, lambda p: self.ctm.on_route(p, mission)
        )
        tracks = TrackLog(names, t0)
        end = t0 + self.cfg.duration_s
        while rig.clock.now() < end - 1e-9:
            rig.step()
            now = rig.clock.now()
            truths = [sim.truth for sim in rig.sims]
            meter.observe(now, truths)
            tracks.observe(now, truths, self._role)
        meter.close(rig.clock.now())
        wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
        return self._report(mission, t0, end, meter, tracks, wall, cpu)

    def _start(self) -> tuple[Mission, float]:
        """Link and configure the drones, then give the CTM the mission; returns it and its
        start time."""
        rig = self.rig
        rig.wait_link()
        for ltm in self.ltms:
            ltm.configure_drone()
        rig.run(0.5)  # the config write reaches the drones
        t0 = rig.clock.now()
        mission = self.ctm.mission_from_request(self.mission_request(), t0)
        rig.add_stepper(self._tick)
        return mission, t0

    def _role(self, name: str) -> str:
        """The CTM's role for drone ``name`` (idle before it knows the drone)."""
        return self.ctm.drones[name].role.value if name in self.ctm.drones else DroneRole.IDLE.value

    def _report(
        self,
        mission: Mission,
        t0: float,
        end: float,
        meter: CoverageMeter,
        tracks: TrackLog,
        wall: float,
        cpu: float,
    ) -> PatrolReport:
        cfg = self.cfg
        route = mission.route
        entry = route[self.ctm.entry_index(self.ltms[0].station, route)]
        bound = coverage_bound(
            self.ltms[0].station, entry, cfg.threshold, self.model, self.station_model
        ).as_dict()
        ms = self.ctm.missions[mission.id]
        return PatrolReport(
            config=cfg,
            duration_s=cfg.duration_s,
            first_on_route_s=meter.first_on_route_s,
            coverage=meter.coverage(end),
            max_gap_s=meter.max_gap_s,
            gaps=meter.gaps,
            handoffs=ms.handoffs,
            replacements=ms.replacements,
            revisit_s=revisit_table(meter.visits, self.world, mission.geo),
            handoff_revisit=handoff_revisits(meter.visits, ms, t0),
            battery_min=tracks.battery_min(),
            bound=bound,
            wall_s=wall,
            cpu_s=cpu,
            events=[f"{t - t0:8.1f} {text}" for t, text in self.ctm.events],
            tracks=tracks.rows,
            route=[(p.x, p.y, p.z) for p in route],
        )


def run_patrol(cfg: PatrolConfig) -> PatrolReport:
    """Build and run one experiment."""
    return PatrolExperiment(cfg).run()
