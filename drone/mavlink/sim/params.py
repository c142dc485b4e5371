"""The parameter protocol of the simulated autopilot (PARAM_REQUEST_LIST/READ, PARAM_SET,
PARAM_VALUE) over :class:`~drone.mavlink.sim.core.AutopilotParams`."""

from __future__ import annotations

import math

from drone.mavlink.codec import Message, mav
from drone.mavlink.sim.core import AutopilotCore


class ParamsService(AutopilotCore):
    """Parameters read and set by name or index, all as REAL32 (as PX4's MAVLink parameters)."""

    def _param_value(self, cid: object, name: str) -> None:
        names = self.params.names()
        m = self.links[cid].codec.mav
        value = float(getattr(self.params, name))
        msg = m.param_value_encode(
            name.encode(), value, mav.MAV_PARAM_TYPE_REAL32, len(names), names.index(name)
        )
        self._send(cid, msg)

    def _on_param_list(self, cid: object, msg: Message) -> None:
        for name in self.params.names():
            self._param_value(cid, name)

    def _on_param_read(self, cid: object, msg: Message) -> None:
        names = self.params.names()
        pid = msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode()
        if pid in names:
            self._param_value(cid, pid)
        elif 0 <= msg.param_index < len(names):
            self._param_value(cid, names[msg.param_index])

    def _on_param_set(self, cid: object, msg: Message) -> None:
        pid = msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode()
        if pid in self.params.names() and math.isfinite(msg.param_value):
            setattr(self.params, pid, float(msg.param_value))
            self._param_value(cid, pid)
