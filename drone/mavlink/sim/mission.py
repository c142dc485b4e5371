"""The mission protocol of the simulated autopilot (upload and download, MISSION_ITEM_INT,
MISSION_ACK, CLEAR_ALL, SET_CURRENT) and flying the mission item by item
(MISSION_ITEM_REACHED)."""

from __future__ import annotations

import math

from drone.mavlink.codec import Message, mav
from drone.mavlink.sim.core import AutopilotCore, MissionItem

_FLOWN_TO = (mav.MAV_CMD_NAV_WAYPOINT, mav.MAV_CMD_NAV_TAKEOFF, mav.MAV_CMD_NAV_LOITER_UNLIM)


class AutopilotMissionService(AutopilotCore):
    """Mission upload/download and the AUTO.MISSION item sequencer."""

    def _on_mission_count(self, cid: object, msg: Message) -> None:
        if msg.mission_type != mav.MAV_MISSION_TYPE_MISSION:
            self._mission_ack(cid, msg, mav.MAV_MISSION_UNSUPPORTED)
            return
        if msg.count == 0:
            self.mission = []
            self._mission_ack(cid, msg, mav.MAV_MISSION_ACCEPTED)
            return
        if msg.count > 500:
            self._mission_ack(cid, msg, mav.MAV_MISSION_NO_SPACE)
            return
        self.links[cid].mission_up = (msg.get_srcSystem(), msg.count, [])
        self._request_item(cid, msg, 0)

    def _request_item(self, cid: object, msg: Message, seq: int) -> None:
        m = self.links[cid].codec.mav
        req = m.mission_request_int_encode(msg.get_srcSystem(), msg.get_srcComponent(), seq)
        self._send(cid, req)

    def _on_mission_item(self, cid: object, msg: Message) -> None:
        up = self.links[cid].mission_up
        if up is None:
            return
        _, count, items = up
        if msg.seq != len(items):
            self._request_item(cid, msg, len(items))  # out of order: ask again (PX4 does)
            return
        if msg.command not in (
            mav.MAV_CMD_NAV_WAYPOINT,
            mav.MAV_CMD_NAV_TAKEOFF,
            mav.MAV_CMD_NAV_LAND,
            mav.MAV_CMD_NAV_RETURN_TO_LAUNCH,
            mav.MAV_CMD_NAV_LOITER_UNLIM,
            mav.MAV_CMD_DO_CHANGE_SPEED,
        ):
            self.links[cid].mission_up = None
            self._mission_ack(cid, msg, mav.MAV_MISSION_UNSUPPORTED)
            return
        items.append(msg)
        if len(items) < count:
            self._request_item(cid, msg, len(items))
            return
        self.links[cid].mission_up = None
        parsed: list[MissionItem] = []
        for it in items:
            x, y, z = self.physics.body.x, self.physics.body.y, self.physics.body.z
            if it.x or it.y:
                x, y, _ = self.origin.to_map(it.x / 1e7, it.y / 1e7, self.origin.alt_m)
            if it.frame in (
                mav.MAV_FRAME_GLOBAL_RELATIVE_ALT,
                mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
            ):
                z = self.home[2] + it.z
            else:
                z = it.z - self.origin.alt_m
            b = self.physics.bounds
            if not (b[0] <= x <= b[1] and b[2] <= y <= b[3]):
                self.statustext(mav.MAV_SEVERITY_CRITICAL, f"Mission item {it.seq} outside")
                self._mission_ack(cid, msg, mav.MAV_MISSION_ERROR)
                return
            if it.command in _FLOWN_TO and z > self.ceiling_z + 1e-6:
                # PX4's feasibility check refuses items above the geofence (GF_MAX_VER_DIST)
                self.statustext(mav.MAV_SEVERITY_CRITICAL, f"Mission item {it.seq} too high")
                self._mission_ack(cid, msg, mav.MAV_MISSION_ERROR)
                return
            parsed.append(MissionItem(it.seq, it.command, x, y, z, it))
        self.mission = parsed
        self.mission_current = 0
        self._mission_ack(cid, msg, mav.MAV_MISSION_ACCEPTED)
        self.statustext(mav.MAV_SEVERITY_INFO, f"Mission accepted: {len(parsed)} items")

    def _mission_ack(self, cid: object, msg: Message, result: int) -> None:
        m = self.links[cid].codec.mav
        self._send(cid, m.mission_ack_encode(msg.get_srcSystem(), msg.get_srcComponent(), result))

    def _on_mission_request_list(self, cid: object, msg: Message) -> None:
        m = self.links[cid].codec.mav
        count = m.mission_count_encode(
            msg.get_srcSystem(), msg.get_srcComponent(), len(self.mission)
        )
        self._send(cid, count)

    def _on_mission_request(self, cid: object, msg: Message) -> None:
        if not 0 <= msg.seq < len(self.mission):
            self._mission_ack(cid, msg, mav.MAV_MISSION_INVALID_SEQUENCE)
            return
        raw = self.mission[msg.seq].raw
        m = self.links[cid].codec.mav
        item = m.mission_item_int_encode(
            msg.get_srcSystem(),
            msg.get_srcComponent(),
            raw.seq,
            raw.frame,
            raw.command,
            int(raw.seq == self.mission_current),
            raw.autocontinue,
            raw.param1,
            raw.param2,
            raw.param3,
            raw.param4,
            raw.x,
            raw.y,
            raw.z,
        )
        self._send(cid, item)

    def _on_mission_clear(self, cid: object, msg: Message) -> None:
        self.mission = []
        self.mission_current = 0
        if self.mode == "AUTO.MISSION":
            self._hold_here()
            self._set_mode("AUTO.LOITER")
        self._mission_ack(cid, msg, mav.MAV_MISSION_ACCEPTED)

    def _on_mission_set_current(self, cid: object, msg: Message) -> None:
        if 0 <= msg.seq < len(self.mission):
            self.mission_current = msg.seq

    def _mission_step(self) -> tuple[float, float, float]:
        b = self.physics.body
        if self.mission_current >= len(self.mission):
            self._hold_here()
            self._set_mode("AUTO.LOITER")
            return self._target[:3]
        item = self.mission[self.mission_current]
        if item.command == mav.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            self._set_mode("AUTO.RTL")
            return b.x, b.y, b.z
        if item.command == mav.MAV_CMD_NAV_LAND:
            self._target = (item.x, item.y, b.z, self._target[3])
            if math.hypot(b.x - item.x, b.y - item.y) < self.params.NAV_ACC_RAD:
                self._set_mode("AUTO.LAND")
            return item.x, item.y, b.z
        if item.command == mav.MAV_CMD_DO_CHANGE_SPEED:
            if item.raw.param2 > 0:
                self._speed = min(float(item.raw.param2), self.params.MPC_XY_CRUISE)
            self._advance_mission()
            return b.x, b.y, b.z
        if item.command == mav.MAV_CMD_NAV_TAKEOFF:
            target = (b.x, b.y, item.z)
            done = abs(b.z - item.z) < 0.3
        else:
            target = (item.x, item.y, item.z)
            done = math.dist((b.x, b.y, b.z), target) < self.params.NAV_ACC_RAD
        if done:
            self._advance_mission()
        return target

    def _advance_mission(self) -> None:
        seq = self.mission_current
        m = next(iter(self.links.values())).codec.mav if self.links else None
        if m is not None:
            self._broadcast(m.mission_item_reached_encode(seq))
        self.mission_current += 1
        if self.mission_current >= len(self.mission):
            self.statustext(mav.MAV_SEVERITY_INFO, "Mission finished, loitering")
            last = self.mission[seq]
            self._set_mode("AUTO.LOITER")
            if last.command == mav.MAV_CMD_NAV_WAYPOINT:  # PX4 loiters at the last waypoint
                self._target = (last.x, last.y, last.z, self._target[3])
            else:
                self._hold_here()
