"""Navdata in doubt (DESIGN §5: "implausible sensor data raises an alarm and hovers; it never
lands a drone blind"): the driver doubts the navdata stream (drone/ardrone/plausibility.py:
packets off the drone's numbering, battery readings no discharge explains) → alert, hover, and
ask the operator. Hover because it needs none of the doubted data: with PCMD's progressive flag
cleared the AR.Drone holds its position with its own onboard sensors (Developer Guide §6.6),
while the position loop, a return home or a landing decided on a battery reading would all act
on data that may be forged. The operator, who can see the drone, decides; the drone's own
firmware still guards its battery."""

from __future__ import annotations

from dataclasses import dataclass

from drone.supervisor.alarms import ActionKind, Alarm, AlarmAction, Severity
from drone.supervisor.phase import FLYING, Phase
from drone.vehicle import VehicleSnapshot

DOUBT_TEXT = "Navdata inconsistent: sensor fault or spoofing"


@dataclass
class NavdataMonitor:
    """The driver doubts the navdata: alert, hover while flying, ask the operator; tell when the
    stream is consistent again (the drone stays where it is until the operator says). Told once
    per episode, and once more if the drone takes off while the doubt lasts."""

    period_s: float = 0.25
    name: str = "navdata"
    _told: str = ""  # "", "ground" (told, not flying) or "air" (told and hovered)

    def check(self, snap: VehicleSnapshot, phase: Phase, now: float) -> Alarm | None:
        doubt = snap.navdata_doubt
        flying = phase in FLYING and snap.flying
        if doubt and flying and self._told != "air":
            self._told = "air"
            return Alarm(
                self.name,
                Severity.ALERT,
                f"{DOUBT_TEXT}: {doubt}. I am hovering and will not act on these readings. "
                "Say land to bring me down here, or tell me what to do.",
                AlarmAction(ActionKind.HOVER),
            )
        if doubt and not self._told:
            self._told = "ground"
            return Alarm(
                self.name, Severity.ALERT, f"{DOUBT_TEXT}: {doubt}. Check the drone before flying."
            )
        if not doubt and self._told:
            self._told = ""
            return Alarm(self.name, Severity.INFO, "The navdata is consistent again.")
        return None
