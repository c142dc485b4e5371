"""Why an action cannot run now, said with the way out — one answer for buttons, keys and speech.

The take-off button, the T key, ``POST /drones/{id}/takeoff`` and a typed "take off" all ask
the same question; they must get the same answer, before anything is sent to the drone and
before anything is said to be happening ("Taking off." followed by "…reset it first" is the
failure this module exists to prevent). Pure function of the drone's state: no I/O.

Stops (land, emergency, hover) are never refused here (DESIGN §5: they always get through).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class DroneFacts:
    """What the checks read about the drone (from the vehicle's snapshot)."""

    emergency: bool
    battery_pct: float
    link_ok: bool
    flying: bool
    # False until navdata has carried a battery reading: the 0 % before it is no reading, and
    # the drone refuses a take-off on a low battery itself (the VBAT_LOW state bit).
    battery_known: bool = True
    # Why the driver doubts the navdata ("" while it trusts it): a drone whose battery and
    # state may be forged does not take off (docs/navdata-trust.md).
    navdata_doubt: str = ""


def refusal(action: str, facts: DroneFacts, battery_low_pct: float) -> str | None:
    """The reason, with the way out, that ``action`` cannot run now; None when it can.

    Args:
        action: takeoff, land, hover, emergency, reset (or any command action).
        facts: the drone's state now.
        battery_low_pct: Settings.battery_low_pct; below it the ANS would send the drone home
            at once, so a take-off is refused up front.
    """
    if action == "takeoff":
        if not facts.link_ok:
            return (
                "I cannot take off: there is no link to the drone. "
                "Check the drone's Wi-Fi and that it is switched on."
            )
        if facts.navdata_doubt:
            return (
                "I cannot take off: the drone's navdata is inconsistent (sensor fault or "
                f"spoofing: {facts.navdata_doubt}). Check the drone and its network; I take off "
                "again once its data is consistent for a few seconds."
            )
        if facts.emergency:
            return (
                "I cannot take off: the drone is in emergency (motors cut). "
                "Press Reset first, then take off."
            )
        if not facts.flying and facts.battery_known and facts.battery_pct < battery_low_pct:
            return (
                f"I cannot take off: the battery is at {facts.battery_pct:.0f} %, below the "
                f"{battery_low_pct:.0f} % needed to fly. Charge or replace the battery first."
            )
        return None
    if action == "reset" and facts.flying and not facts.emergency:
        return "Reset is only for leaving an emergency; the drone is flying normally."
    return None


EMERGENCY_DOWN = (
    "Motors cut: the drone is down and in emergency. Press Reset before the next take-off."
)
