"""Flight modes: PX4 custom modes and ArduCopter modes, to and from the heartbeat's custom_mode.

PX4 packs its mode into ``custom_mode`` as ``main_mode << 16 | sub_mode << 24``
(PX4-Autopilot ``src/modules/commander/px4_custom_mode.h``). ArduCopter's custom_mode is the
plain mode number (ArduPilot ``ArduCopter/mode.h`` ``enum class Number``). The console speaks of
modes by the names QGroundControl shows (``POSCTL``, ``AUTO.LOITER``, ``GUIDED``…).
"""

from __future__ import annotations

from pymavlink.dialects.v20 import common as mav

# px4_custom_mode.h: PX4_CUSTOM_MAIN_MODE_*
PX4_MAIN = {
    "MANUAL": 1,
    "ALTCTL": 2,
    "POSCTL": 3,
    "AUTO": 4,
    "ACRO": 5,
    "OFFBOARD": 6,
    "STABILIZED": 7,
    "RATTITUDE": 8,
}
# px4_custom_mode.h: PX4_CUSTOM_SUB_MODE_AUTO_*
PX4_AUTO_SUB = {
    "READY": 1,
    "TAKEOFF": 2,
    "LOITER": 3,
    "MISSION": 4,
    "RTL": 5,
    "LAND": 6,
    "FOLLOW_TARGET": 8,
    "PRECLAND": 9,
}

# ArduCopter/mode.h enum class Number
ARDUCOPTER = {
    "STABILIZE": 0,
    "ACRO": 1,
    "ALT_HOLD": 2,
    "AUTO": 3,
    "GUIDED": 4,
    "LOITER": 5,
    "RTL": 6,
    "CIRCLE": 7,
    "LAND": 9,
    "DRIFT": 11,
    "SPORT": 13,
    "FLIP": 14,
    "AUTOTUNE": 15,
    "POSHOLD": 16,
    "BRAKE": 17,
    "THROW": 18,
    "SMART_RTL": 21,
}
_ARDUCOPTER_NAMES = {v: k for k, v in ARDUCOPTER.items()}

# What each console intent means on each autopilot.
INTENT_MODES = {
    mav.MAV_AUTOPILOT_PX4: {
        "hold": "AUTO.LOITER",
        "rtl": "AUTO.RTL",
        "land": "AUTO.LAND",
        "mission": "AUTO.MISSION",
        "offboard": "OFFBOARD",
        "takeoff": "AUTO.TAKEOFF",
    },
    mav.MAV_AUTOPILOT_ARDUPILOTMEGA: {
        "hold": "LOITER",
        "rtl": "RTL",
        "land": "LAND",
        "mission": "AUTO",
        "offboard": "GUIDED",
        "takeoff": "GUIDED",
    },
}


def px4_custom_mode(name: str) -> int:
    """``"AUTO.LOITER"`` → custom_mode. Raises ``KeyError`` for an unknown name."""
    main, _, sub = name.upper().partition(".")
    value = PX4_MAIN[main] << 16
    if sub:
        value |= PX4_AUTO_SUB[sub] << 24
    return value


def px4_mode_name(custom_mode: int) -> str:
    """custom_mode → ``"AUTO.RTL"``; unknown numbers as ``"PX4(main.sub)"``."""
    main = (custom_mode >> 16) & 0xFF
    sub = (custom_mode >> 24) & 0xFF
    names = {v: k for k, v in PX4_MAIN.items()}
    if main not in names:
        return f"PX4({main}.{sub})"
    if names[main] == "AUTO":
        subs = {v: k for k, v in PX4_AUTO_SUB.items()}
        return f"AUTO.{subs.get(sub, str(sub))}"
    return names[main]


def mode_name(autopilot: int, custom_mode: int) -> str:
    """The mode's name for a heartbeat from ``autopilot`` (MAV_AUTOPILOT)."""
    if autopilot == mav.MAV_AUTOPILOT_PX4:
        return px4_mode_name(custom_mode)
    if autopilot == mav.MAV_AUTOPILOT_ARDUPILOTMEGA:
        return _ARDUCOPTER_NAMES.get(custom_mode, f"MODE({custom_mode})")
    return f"MODE({custom_mode})"


def custom_mode(autopilot: int, name: str) -> int:
    """A mode name → custom_mode for ``autopilot``. Raises ``KeyError`` if it has no such mode."""
    if autopilot == mav.MAV_AUTOPILOT_ARDUPILOTMEGA:
        return ARDUCOPTER[name.upper()]
    return px4_custom_mode(name)


def intent_mode(autopilot: int, intent: str) -> str:
    """The mode that does ``intent`` (hold, rtl, land, mission, offboard) on ``autopilot``."""
    table = INTENT_MODES.get(autopilot, INTENT_MODES[mav.MAV_AUTOPILOT_PX4])
    return table[intent]
