"""Reading the vehicle's word: the plausibility check on decoded telemetry, landed-state
names, and STATUSTEXT (chunked texts reassembled)."""

from __future__ import annotations

import math

from drone.mavlink.codec import Message, mav
from drone.mavlink.gcs.core import GcsCore
from drone.mavlink.gcs.events import StatusText

LANDED_STATES = {
    mav.MAV_LANDED_STATE_UNDEFINED: "UNDEFINED",
    mav.MAV_LANDED_STATE_ON_GROUND: "ON_GROUND",
    mav.MAV_LANDED_STATE_IN_AIR: "IN_AIR",
    mav.MAV_LANDED_STATE_TAKEOFF: "TAKEOFF",
    mav.MAV_LANDED_STATE_LANDING: "LANDING",
}
# The float fields the telemetry (or the failsafe text) takes from each message. None of them
# has a "NaN means unknown" meaning in the MAVLink definitions, so a non-finite value is damage
# or forgery, and the message is dropped (see "Plausibility" in the
# ``drone.mavlink.gcs.protocol`` docstring).
_FLOAT_FIELDS = {
    "LOCAL_POSITION_NED": ("x", "y", "z", "vx", "vy", "vz"),
    "ATTITUDE": ("roll", "pitch", "yaw"),
    "HOME_POSITION": ("x", "y", "z"),
    "PARAM_VALUE": ("param_value",),
}
# The degE7 latitude/longitude fields of each message: on the globe or dropped.
_LAT_LON_FIELDS = {
    "GLOBAL_POSITION_INT": ("lat", "lon"),
    "HOME_POSITION": ("latitude", "longitude"),
}


def implausible(msg: Message) -> str | None:
    """Why a decoded message cannot be telemetry (a non-finite value, a point off the globe),
    or None when it can."""
    kind = msg.get_type()
    for name in _FLOAT_FIELDS.get(kind, ()):
        value = getattr(msg, name)
        if not math.isfinite(value):
            return f"{kind}.{name} is {value}"
    lat_lon = _LAT_LON_FIELDS.get(kind)
    if lat_lon is not None:
        lat, lon = (getattr(msg, name) for name in lat_lon)
        if not (-90e7 <= lat <= 90e7 and -180e7 <= lon <= 180e7):
            return f"{kind} at {lat / 1e7}°, {lon / 1e7}° is off the globe"
    return None


class TelemetryService(GcsCore):
    """STATUSTEXT: single texts and chunked ones, kept a moment to explain refusals."""

    def _on_statustext(self, msg: Message, now: float) -> None:
        """One STATUSTEXT, or a chunk of a longer one: MAVLink 2 splits texts over 50 characters
        into chunks with the same ``id`` and rising ``chunk_seq``; the last is shorter than 50
        (null-terminated). A chunk of another id, or a gap, flushes what was gathered."""
        raw = msg.text if isinstance(msg.text, str) else msg.text.decode(errors="replace")
        text = raw.split("\x00", 1)[0]
        ended = len(raw.rstrip("\x00")) < 50 or "\x00" in raw
        text_id = getattr(msg, "id", 0)
        if text_id == 0:
            self._emit_text(msg.severity, text, now)
            return
        pending = self._chunks
        if pending is not None and (pending[0] != text_id or msg.chunk_seq != pending[2] + 1):
            self._emit_text(pending[1], pending[3], now)  # incomplete: say what arrived
            pending = None
        if pending is None:
            pending = (text_id, msg.severity, msg.chunk_seq - 1, "")
        pending = (text_id, pending[1], msg.chunk_seq, pending[3] + text)
        if ended:
            self._chunks = None
            self._emit_text(pending[1], pending[3], now)
        else:
            self._chunks = pending

    def _emit_text(self, severity: int, text: str, now: float) -> None:
        st = StatusText(severity, text)
        self._texts.append((now, st))
        self._events.append(st)
