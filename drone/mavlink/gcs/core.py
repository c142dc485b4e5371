"""State every microservice of the ground-station protocol shares: the codec, the outgoing
bytes, the events, the telemetry and the pending exchanges (:class:`GcsCore`)."""

from __future__ import annotations

import collections
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from drone.mavlink.codec import Codec, Message, mav, signing_timestamp
from drone.mavlink.gcs.events import MavlinkTelemetry, StatusText

GCS_SYSTEM_ID = 255  # QGroundControl's and MAVProxy's default
GCS_COMPONENT_ID = mav.MAV_COMP_ID_MISSIONPLANNER  # 190
HEARTBEAT_PERIOD_S = 1.0  # MAVLink "Heartbeat/Connection Protocol": 1 Hz


@dataclass
class PendingCommand:
    """A command queued or in flight: its params, attempts so far and what follows it."""

    token: int
    command: int
    params: tuple[float, ...]  # 7 values
    use_int: bool = False
    frame: int = mav.MAV_FRAME_GLOBAL_INT
    attempts: int = 0
    sent_t: float = -math.inf
    progress_t: float | None = None
    then: list[PendingCommand] = field(default_factory=list)  # sent after this one is ACCEPTED


@dataclass
class PendingUpload:
    """A mission upload in progress: the items and when the vehicle last asked."""

    items: list[Message]
    started_t: float
    last_t: float
    tries: int = 0
    sent_count: bool = False


class GcsCore:
    """The shared state and output of :class:`~drone.mavlink.gcs.protocol.GcsProtocol` (its
    constructor arguments are documented there)."""

    def __init__(
        self,
        *,
        target_system: int | None = None,
        system_id: int = GCS_SYSTEM_ID,
        component_id: int = GCS_COMPONENT_ID,
        signing_key: bytes | None = None,
        signing_clock: Callable[[], float] = time.time,
        link_timeout_s: float = 1.5,
        command_timeout_s: float = 1.0,
        retries: int = 3,
        setpoint_hz: float = 10.0,
        request_streams: bool = True,
    ) -> None:
        self.signing_clock = signing_clock
        self.codec = Codec(
            system_id,
            component_id,
            signing_key=signing_key,
            initial_timestamp=signing_timestamp(signing_clock()) if signing_key else None,
        )
        self.m = self.codec.mav
        self.target_system = target_system
        self.target_component = mav.MAV_COMP_ID_AUTOPILOT1
        self.link_timeout_s = link_timeout_s
        self.command_timeout_s = command_timeout_s
        self.retries = retries
        self.setpoint_period_s = 1.0 / setpoint_hz
        self.request_streams = request_streams
        self.telemetry = MavlinkTelemetry()
        self.link_ok = False
        self.params: dict[str, float] = {}
        self.commands_sent = 0  # COMMAND_LONG/INT frames written, retries included
        self._out = bytearray()
        self._events: list[Any] = []
        self._next_hb = -math.inf
        self._token = 0
        self._inflight: dict[int, PendingCommand] = {}
        self._waiting: dict[int, collections.deque[PendingCommand]] = collections.defaultdict(
            collections.deque
        )
        self._others: set[int] = set()
        self._texts: collections.deque[tuple[float, StatusText]] = collections.deque(maxlen=8)
        self._now = 0.0
        self._setpoint: tuple[str, tuple[float, ...]] | None = None  # ("vel"|"pos", values)
        self._next_sp = -math.inf
        self._zero_burst = 0
        self._upload: PendingUpload | None = None
        self._chunks: tuple[int, int, int, str] | None = None  # (id, severity, last seq, text)

    # ------------------------------------------------------------------ plumbing
    def data_to_send(self) -> bytes:
        data = bytes(self._out)
        self._out.clear()
        return data

    def events(self) -> list[Any]:
        ev, self._events = self._events, []
        return ev

    def _send(self, msg: Message) -> None:
        self._out += self.codec.encode(msg)

    @property
    def connected(self) -> bool:
        return self.telemetry.system_id != 0 and self.link_ok
