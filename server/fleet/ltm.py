"""The local task manager (LTM): one drone's end of the fleet, on the drone's host computer.

It reports ``LtmStatus`` every ``period_s``, turns the CTM's flight plans into task-manager
commands (take off, fly the route from its start index, loop; or fly to the station at cruise
height and land), and keeps the drone safe on its own: if it hears nothing from the CTM for
``ctm_timeout_s`` while flying, or its battery falls to the reserve it needs to get home, it
flies home and lands (``autonomous`` in the status says why). Sans-I/O: ``step(now)`` returns
the status to publish when one is due; the transport (in-process graph, rosbridge client,
lockstep link) does the sending.

The operator may take the drone off the CTM's patrol at any time, through any door (the page's
buttons, REST, speech, rosbridge topics, the vehicle's safety door): every one of them ends in
the task manager, which drops the plan's task with a reason. The LTM hears that and reports what
the operator did (``operator`` in the status: land, hover, emergency, cancel, jog…) until the
next plan, so the CTM pauses the mission instead of believing it still runs. What the drone's
own safety does is not the operator's (the reason names it, ``TaskManager.preempt(by=…)``): a
safety monitor's hover holds the drone and asks the operator what to do (navdata in doubt,
outside the geofence), reported as ``held = "navdata monitor (hover)"`` and the CTM pauses the
mission for the operator too; any other (a monitor's landing or climb-down, the hover or landing
of the vehicle's watch of a silent central server) as ``autonomous = "held: hover (central
server silent)"``, and a return home (the operator's or the battery monitor's) as ``autonomous =
"sent home"``: the drone has left its post, and the CTM gives the post to a drone able to fly it
(the same one again, once it may). A drone flying home that the central server's silence holds
in a hover says so the same way, and the CTM sends it home again.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from typing import Any

from pydantic import ValidationError

from drone.commands import Command, Hover, Land, Takeoff, Waypoint, Waypoints
from drone.vehicle import Vehicle
from server.fleet.accuracy import GPS_SIGMA_M
from server.fleet.geo import Enu, Geo, to_enu, to_geo
from server.fleet.messages import FlightPlan, LtmStatus, PlanKind
from server.fleet.planner import FlightModel, reserve_pct

log = logging.getLogger(__name__)

HOME_CEILING_CLEARANCE_M = 0.5
"""How far under the world's ceiling the flight home cruises: at the ceiling itself the
controller's overshoot trips the supervisor's altitude monitor (drone/supervisor/altitude.py),
whose hover would end the flight home above the station instead of on it."""

ALTITUDE_MAX_MM = 20000  # control:altitude_max for outdoor flight (firmware default 3000 mm)
# general:navdata_options: demo (tag 0) + raw pressure (tag 21, the barometer the console shows)
# + GPS (tag 27, firmware 2.4 flight recorder); drone.ardrone.vehicle.navdata_options asks the same
NAVDATA_OPTIONS = (1 << 0) | (1 << 21) | (1 << 27)
GPS_PERIOD_S = 1.0  # fuse one GPS fix a second (the flight recorder's rate)
SENT_HOME = "sent home"  # ``autonomous``: someone sent it home (return_home) off its patrol
HELD = "held: "  # ``autonomous`` prefix: its own safety acted ("held: hover (…)")


def interruption(reason: str) -> tuple[str, str]:
    """What dropped the plan's task and who did it, from the reason the task manager gives
    (``server.tasks.manager``: "preempted by land", "preempted by hover (central server
    silent)", "manual control took over", "take-off requested", "cancelled"…): (action, by),
    ``by`` "" when it was the operator."""
    if reason.startswith("preempted by "):
        what, _, by = reason.removeprefix("preempted by ").partition(" (")
        return what.replace("_", " "), by.removesuffix(")")
    if reason == "manual control took over":
        return "jog", ""
    if reason.endswith(" requested"):
        return reason.removesuffix(" requested"), ""
    if reason == "cancelled":
        return "cancel", ""
    if reason == "replaced by a new command":  # only the safety monitors replace the LTM's
        return "move", "altitude monitor"
    return reason, ""


def operator_action(reason: str) -> str:
    """The action of :func:`interruption`, in the operator's words."""
    return interruption(reason)[0]


# GPS_SIGMA_M: horizontal σ of a fix at HDOP 1 (server/fleet/accuracy.py)


class LocalTaskManager:
    """See the module docstring.

    Args:
        name: the drone's name (``uav2``).
        vehicle: ``drone.vehicle.Vehicle``.
        tasks: its ``server.tasks.manager.TaskManager`` (stepped by its owner).
        station: the home station (map frame) it lands on.
        origin: GPS origin, for lat/lon in the status when navdata carries no GPS.
        period_s: status period.
        ctm_timeout_s: silence from the CTM after which a flying drone goes home.
    """

    def __init__(
        self,
        name: str,
        vehicle: Vehicle,
        tasks: Any,
        station: Enu,
        *,
        origin: Geo | None = None,
        period_s: float = 1.0,
        ctm_timeout_s: float = 15.0,
        model: FlightModel | None = None,
        home_cruise_z: float = 5.0,
    ) -> None:
        self.name = name
        self.vehicle = vehicle
        self.tasks = tasks
        self.station = station
        self.origin = origin
        self.period_s = period_s
        self.ctm_timeout_s = ctm_timeout_s
        self.model = model or FlightModel()
        self.home_cruise_z = home_cruise_z
        self.plan: FlightPlan | None = None
        self.autonomous = ""
        self.last_ctm: float | None = None
        self._next_status = -math.inf
        self._seq = 0
        self._configured = False
        self._next_gps = -math.inf
        self.gps_fixes = 0
        self._last_gps: Any | None = None
        self.operator = ""  # what the operator did to the CTM's plan (module docstring)
        self.held = ""  # what its safety monitor holds it for, asking the operator
        self._plan_tasks: frozenset[int] = frozenset()  # the tasks the plan is flown with
        self._own = False  # the LTM itself is replacing tasks (not the operator)
        on_event = getattr(tasks, "on_event", None)
        if callable(on_event):
            on_event(self._on_task)
        if origin is not None and hasattr(vehicle, "add_navdata_listener"):
            vehicle.add_navdata_listener(self._on_navdata)

    # ------------------------------------------------------------------ inputs
    def heard_ctm(self, now: float) -> None:
        """Anything from the CTM (a plan, a ``/fleet/status`` message) counts as a heartbeat."""
        self.last_ctm = now
        if self.autonomous == "ctm_silent":
            self.autonomous = ""  # back in touch: the CTM decides again

    def configure_drone(self) -> None:
        """Raise ``control:altitude_max`` so outdoor routes above 3 m can be flown."""
        # an AR.Drone's driver takes AT*CONFIG; an autopilot (MAVLink) has no such commander
        config = getattr(getattr(self.vehicle, "commander", None), "config", None)
        if config is not None and not self._configured:
            config("control:altitude_max", str(ALTITUDE_MAX_MM))
            if self.origin is not None:
                config("general:navdata_options", str(NAVDATA_OPTIONS))
            self._configured = True

    def _on_navdata(self, nav: Any, now: float) -> None:
        """GPS aiding: dead reckoning on optical-flow speeds drifts (~0.5 m/min); a GPS fix a
        second, fused as a position-only measurement (yaw σ huge), holds the estimate."""
        gps = getattr(nav, "gps", None)
        if gps is None or not gps.data_available:
            return
        self._last_gps = gps
        if now < self._next_gps or self.origin is None:
            return
        self._next_gps = now + GPS_PERIOD_S
        import numpy as np

        from drone.perception.ekf import MarkerFix

        ekf = getattr(self.vehicle, "ekf", None)  # the AR.Drone's own estimator (navdata)
        if ekf is None:
            return
        p = to_enu(Geo(gps.latitude_deg, gps.longitude_deg, gps.elevation_m), self.origin)
        est = ekf.latest
        sig = GPS_SIGMA_M * max(float(gps.hdop), 1.0)
        R = np.diag([sig**2, sig**2, 25.0, 1e4])  # height: the ultrasound rules; yaw: unknown
        fix = MarkerFix(now, p.x, p.y, p.z, est.yaw_rad, R, marker_id=-27)
        if ekf.update_marker(fix):
            self.gps_fixes += 1

    def apply_plan(self, plan: FlightPlan, now: float) -> tuple[bool, str]:
        """Execute ``plan`` (replacing what runs). Returns (accepted, reason)."""
        self.heard_ctm(now)
        if self.plan is not None and plan.plan_id == self.plan.plan_id:
            return True, "already flying this plan"
        self.configure_drone()
        try:
            commands = self._commands(plan)
        except ValidationError as exc:  # e.g. an estimate gone NaN: refused, never raised
            return False, f"refused: {exc.errors(include_url=False)[0]['msg']}"
        if plan.kind is PlanKind.NONE:
            self._submit(None)
            self._applied(plan, ())
            return True, "cancelled"
        if not commands:
            self._applied(plan, ())
            return True, "nothing to do"
        decisions = self._submit(commands)
        refused = [d for d in decisions if not d.accepted]
        if refused:
            return False, f"refused: {refused[0].reason}"
        self._applied(plan, decisions)
        return True, f"flying plan {plan.plan_id} ({plan.kind.value})"

    def _submit(self, commands: list[Command] | None) -> list[Any]:
        """Replace what the task manager runs with ``commands`` (None: cancel), as the LTM:
        the tasks this drops were the LTM's, not taken by the operator."""
        self._own = True
        try:
            if commands is None:
                self.tasks.cancel("plan cancelled by the central task manager")
                return []
            return list(self.tasks.submit(commands, replace=True))
        finally:
            self._own = False

    def _applied(self, plan: FlightPlan, decisions: Any) -> None:
        self.plan, self.autonomous, self.operator, self.held = plan, "", "", ""
        ids = (getattr(d, "task_id", None) for d in decisions)
        self._plan_tasks = frozenset(i for i in ids if i is not None)

    def _on_task(self, notice: Any) -> None:
        """A task-manager event: the plan's task dropped by someone else is the operator's
        doing (module docstring); the first such event counts until the next plan."""
        if self._own or notice.kind not in ("preempted", "cancelled"):
            return
        if notice.task_id not in self._plan_tasks:
            return
        if self.operator or self.autonomous or self.held:
            return
        if self.plan is None:
            return
        action, by = interruption(self._reason(notice))
        if self.plan.kind is PlanKind.RETURN:
            # on its way home, held in a hover by its own safety (the central server's
            # silence): said, so the CTM sends it home again once it hears it
            if action == "hover" and by and not by.endswith(" monitor"):
                self.autonomous = f"{HELD}{action} ({by})"
            return
        if self.plan.kind is not PlanKind.PATROL:
            return
        if action == "return home":
            self.autonomous = SENT_HOME
        elif action == "hover" and by.endswith(" monitor"):
            self.held = f"{by} ({action})"  # the monitor asks the operator what to do
        elif by:
            self.autonomous = f"{HELD}{action} ({by})"
        else:
            self.operator = action

    def _reason(self, notice: Any) -> str:
        """Why the task manager dropped the notice's task (its history), else the notice's
        text after the task's description."""
        for task, reason in reversed(getattr(self.tasks, "history", ())):
            if getattr(task, "id", None) == notice.task_id:
                return str(reason)
        return str(notice.text).rpartition(": ")[2]

    def apply_plan_dict(self, obj: Mapping[str, Any], now: float) -> dict[str, Any]:
        """Service handler body: parse (``MessageError`` propagates) and apply."""
        plan = FlightPlan.from_dict(obj)
        ok, reason = self.apply_plan(plan, now)
        return {"accepted": ok, "reason": reason, "plan_id": plan.plan_id}

    def _commands(self, plan: FlightPlan) -> list[Command]:
        s = self.vehicle.snapshot()
        cmds: list[Command] = []
        if plan.kind is PlanKind.PATROL:
            if not s.flying:
                cmds.append(Takeoff())
            n = len(plan.route)
            idx = [(plan.start_index + k) % n for k in range(n)]
            heads = plan.headings_deg
            if plan.join is not None:  # enter the route here first, then go round from there
                j = plan.join
                cmds.append(
                    Waypoints(
                        waypoints=[Waypoint(x=j.x, y=j.y, z=j.z)], tolerance_m=plan.tolerance_m
                    )
                )
            route = [plan.route[i] for i in idx]
            cmds.append(
                Waypoints(
                    waypoints=[
                        Waypoint(x=p.x, y=p.y, z=p.z, yaw_deg=heads[i] if heads else None)
                        for i, p in zip(idx, route, strict=True)
                    ],
                    loop=plan.loop,
                    tolerance_m=plan.tolerance_m,
                )
            )
        elif plan.kind is PlanKind.RETURN:
            if s.flying:
                cmds.extend(self._home_commands(plan.cruise_z, s))
        elif plan.kind is PlanKind.HOLD and s.flying:
            cmds.append(Hover())
        return cmds

    def _home_commands(self, cruise_z: float, s: Any) -> list[Command]:
        st = self.station
        z = max(cruise_z, 1.0)
        limits = getattr(self.vehicle, "limits", None)
        if limits is not None:  # the world's ceiling (drone/limits.py), e.g. a room's 2.7 m
            z = min(z, limits.ceiling_m - HOME_CEILING_CLEARANCE_M)
        return [
            Waypoints(
                # climb (or descend) in place to the transit layer, then over the station
                waypoints=[Waypoint(x=s.x, y=s.y, z=z), Waypoint(x=st.x, y=st.y, z=z)],
                tolerance_m=0.5,
            ),
            Land(),
        ]

    # ------------------------------------------------------------------ step
    def step(self, now: float) -> LtmStatus | None:
        """Safety checks; returns a status when one is due."""
        s = self.vehicle.snapshot()
        # Only a drone flying for the fleet (a plan from the CTM) acts on its own: a drone the
        # operator flies by hand in a single-drone console is never taken over.
        if s.flying and self.autonomous == "" and self.plan is not None:
            silent = self.last_ctm is None or now - self.last_ctm > self.ctm_timeout_s
            here = Enu(s.x, s.y, s.z)
            low = s.battery_pct <= reserve_pct(here, self.station, self.model, extra_pct=0.0)
            going_home = self.plan is not None and self.plan.kind is PlanKind.RETURN
            if (silent or low) and not going_home:
                self.autonomous = "ctm_silent" if silent else "battery_reserve"
                try:
                    self._submit(self._home_commands(self.home_cruise_z, s))
                except ValidationError as exc:  # no finite position to fly home from
                    log.warning("%s: cannot fly home: %s", self.name, exc)
        if now < self._next_status:
            return None
        self._next_status = now + self.period_s
        return self.status(now)

    def status(self, now: float) -> LtmStatus:
        s = self.vehicle.snapshot()
        lat = lon = 0.0
        gps = self._last_gps
        if gps is not None:
            lat, lon = float(gps.latitude_deg), float(gps.longitude_deg)
        elif self.origin is not None:
            g = to_geo(Enu(s.x, s.y, s.z), self.origin)
            lat, lon = g.lat_deg, g.lon_deg
        ts = self.tasks.status
        self._seq += 1
        return LtmStatus(
            name=self.name,
            t=now,
            seq=self._seq,
            x=s.x,
            y=s.y,
            z=s.z,
            yaw_deg=math.degrees(s.yaw_rad),
            lat=lat,
            lon=lon,
            battery_pct=float(s.battery_pct),
            flying=bool(s.flying),
            state="EMERGENCY" if s.emergency else s.ctrl_state,
            link_ok=bool(s.link_ok),
            emergency=bool(s.emergency),
            station=self.station,
            plan_id=self.plan.plan_id if self.plan else 0,
            task=ts.name,
            task_state=ts.state,
            progress=float(ts.progress),
            autonomous=self.autonomous,
            operator=self.operator,
            held=self.held,
            battery_known=bool(getattr(s, "battery_known", True)),
        )
