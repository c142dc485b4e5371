"""The mission protocol, upload side: MISSION_COUNT → MISSION_REQUEST_INT → MISSION_ITEM_INT …
→ MISSION_ACK, with retransmission on timeout (MissionResult at the end)."""

from __future__ import annotations

import math

from drone.mavlink.codec import Message, mav
from drone.mavlink.gcs.core import GcsCore, PendingUpload
from drone.mavlink.gcs.events import MissionResult

_MISSION_RESULTS = {
    k: v.name.removeprefix("MAV_MISSION_") for k, v in mav.enums["MAV_MISSION_RESULT"].items()
}


class MissionService(GcsCore):
    """Upload a mission item by item as the vehicle asks for them."""

    def upload_mission(
        self,
        waypoints: list[tuple[float, float, float]],
        now: float | None = None,
        *,
        takeoff_alt_m: float | None = None,
        rtl: bool = False,
    ) -> None:
        """Upload waypoints (lat°, lon°, alt m above home) as a mission; MissionResult follows."""
        now = self._now if now is None else now
        ts, tc = self.telemetry.system_id, self.target_component
        items: list[Message] = []
        rel = mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
        if takeoff_alt_m is not None:
            items.append(
                self.m.mission_item_int_encode(
                    ts,
                    tc,
                    0,
                    rel,
                    mav.MAV_CMD_NAV_TAKEOFF,
                    0,
                    1,
                    0,
                    0,
                    0,
                    math.nan,
                    0,
                    0,
                    takeoff_alt_m,
                )
            )
        for lat, lon, alt in waypoints:
            items.append(
                self.m.mission_item_int_encode(
                    ts,
                    tc,
                    len(items),
                    rel,
                    mav.MAV_CMD_NAV_WAYPOINT,
                    0,
                    1,
                    0.0,
                    1.0,
                    0.0,
                    math.nan,
                    round(lat * 1e7),
                    round(lon * 1e7),
                    alt,
                )
            )
        if rtl:
            items.append(
                self.m.mission_item_int_encode(
                    ts,
                    tc,
                    len(items),
                    rel,
                    mav.MAV_CMD_NAV_RETURN_TO_LAUNCH,
                    0,
                    1,
                    0,
                    0,
                    0,
                    0,
                    0,
                    0,
                    0,
                )
            )
        self._upload = PendingUpload(items, now, now)
        self._send(self.m.mission_count_encode(ts, tc, len(items)))

    def _on_mission_request(self, msg: Message, now: float) -> None:
        up = self._upload
        if up is None:
            return
        if not 0 <= msg.seq < len(up.items):
            self._upload = None
            self._events.append(MissionResult(False, len(up.items), f"bad item request {msg.seq}"))
            return
        up.last_t, up.tries = now, 0
        self._send(up.items[msg.seq])

    def _on_mission_ack(self, msg: Message) -> None:
        up = self._upload
        if up is None:
            return
        self._upload = None
        name = _MISSION_RESULTS.get(msg.type, f"result {msg.type}")
        ok = msg.type == mav.MAV_MISSION_ACCEPTED
        recent = [st.text for t, st in self._texts if self._now - t <= 1.0]
        detail = name if ok or not recent else f"{name}: {recent[-1]}"
        self._events.append(MissionResult(ok, len(up.items), detail))

    def _check_upload(self, now: float) -> None:
        up = self._upload
        if up is None or now - up.last_t < 1.5:
            return
        if up.tries >= 3:
            self._upload = None
            self._events.append(MissionResult(False, len(up.items), "no answer from the vehicle"))
            return
        up.tries += 1
        up.last_t = now
        ts, tc = self.telemetry.system_id, self.target_component
        self._send(self.m.mission_count_encode(ts, tc, len(up.items)))
