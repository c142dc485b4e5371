"""Vehicle snapshots for supervisor tests, and a supervisor over the dialog tests' fake flight."""

from __future__ import annotations

from typing import Any

from drone.supervisor import (
    Alarm,
    AlarmAction,
    Phase,
    Supervisor,
    SupervisorParams,
    default_monitors,
)
from drone.supervisor.phase import phase_of
from drone.vehicle import MarkerSeen, VehicleSnapshot


def snap(**kw: Any) -> VehicleSnapshot:
    """A flying, localised drone at 1 m with 80 % battery, changed by ``kw`` (``x``, ``y``,
    ``battery_pct``, ``flying``, ``link_ok``, ``markers`` as ids, …)."""
    seen = kw.pop("markers", ())
    markers = tuple(MarkerSeen(i, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0) for i in seen)
    base: dict[str, Any] = {
        "name": "uav1",
        "t": 0.0,
        "ctrl_state": "HOVERING",
        "flying": True,
        "emergency": False,
        "battery_pct": 80.0,
        "altitude_m": 1.0,
        "x": 0.0,
        "y": 0.0,
        "z": 1.0,
        "yaw_rad": 0.0,
        "vx": 0.0,
        "vy": 0.0,
        "vz": 0.0,
        "position_sigma_m": 0.05,
        "yaw_sigma_rad": 0.01,
        "localised": True,
        "markers": markers,
        "last_marker_t": None,
        "link_ok": True,
        "navdata_age_s": 0.0,
        "mode": "POSITION",
        "setpoint": None,
        "controller": None,
        "battery_known": True,
    }
    base.update(kw)
    return VehicleSnapshot(**base)


def cmd(alarm: Alarm | None) -> dict[str, Any] | None:
    """The command an alarm's action ran (None: no alarm, or an alarm without an action)."""
    return alarm.action.command() if alarm is not None and alarm.action is not None else None


def fake_flight_supervisor(flight: Any, world: Any = None) -> Supervisor:
    """The default monitors over ``tests.dialog.fakes.FakeFlight``: its snapshot as the
    vehicle's, its running command as the task, its ``preempt`` as the supervisor's hands."""

    def snapshot() -> VehicleSnapshot:
        v = flight.snapshot()
        return snap(
            battery_pct=v.battery_pct,
            altitude_m=v.altitude_m,
            flying=v.flying,
            link_ok=v.link_ok,
            emergency=v.emergency,
            ctrl_state=v.ctrl_state,
            battery_known=v.battery_known,
            navdata_doubt=v.navdata_doubt,
            markers=v.visible_markers,
        )

    def phase(s: VehicleSnapshot) -> Phase:
        running = flight.running or {}
        return phase_of(s, str(running.get("action", "")), "running" if running else "idle")

    def act(action: AlarmAction, by: str) -> None:
        flight.preempt(action.command(), by)

    return Supervisor(default_monitors(SupervisorParams(), world), snapshot, phase, act)


def supervised(
    rig: Any, tm: Any, world: Any, dm: Any, settings: Any = None, *, keep_away: Any = None
) -> Supervisor:
    """The vehicle's supervisor for a lockstep rig's drone and task manager, stepped by the rig
    after the dialog (as the dialog stepped its monitors), its alarms spoken by ``dm``."""
    from drone.supervisor import supervise

    sup = supervise(rig.vehicle, tm, world, settings, keep_away=keep_away)
    sup.on_alarm(dm.hear)
    rig.add_stepper(lambda now, dt: sup.step(now))
    return sup
