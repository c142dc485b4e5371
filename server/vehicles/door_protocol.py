"""The safety door's protocol, sans-I/O: JSON text frames to typed messages and back.

The door is a vehicle's own WebSocket for stops (docs/safety-door.md). Every frame is one JSON
object with an ``op``; these names are an interface (the console page and scripts speak them):

client → door
  ``{"op":"auth","token":T}``                     first frame, within ``AUTH_DEADLINE_S`` of accept
  ``{"op":"stop","action":A,"id":ID,"issued":S}`` A: emergency | land | hover; S: server clock
  ``{"op":"supersede","ids":[ID, …]}``            these stops must not run if they arrive later
door → client
  ``{"op":"hello","drone":N,"t":S,"heartbeat_s":0.25}``            after a good ``auth``
  ``{"op":"heartbeat","t":S,"state":F,"link_ok":B}``                every ``heartbeat_s``
  ``{"op":"ack","id":…,"action":…,"accepted":B,"detail":…,"delivered":S,"road":R,"late_s":L}``
  ``{"op":"superseded","ids":[…],"too_late":[…]}``                  answers ``supersede``
  ``{"op":"error","detail":…}``                                     a refused frame

``road`` in an ack is the road that brought the stop to the vehicle first (``door`` or
``server``): the vehicle runs each stop id once, and a copy that arrives by the other road is
answered with the first delivery. :func:`parse_client` and :func:`parse_door` turn text into
messages (or raise :class:`DoorProtocolError`); :func:`encode` turns a message into text.
:class:`DoorSession` is one connection's state: ``AWAITING_AUTH`` until a good ``auth``, then
``OPEN``; what may arrive in each state is the table :data:`ACCEPTS`.
"""

from __future__ import annotations

import enum
import json
import math
import re
from dataclasses import dataclass
from typing import Any

from server.vehicles.errors import DoorProtocolError

MAX_FRAME_BYTES = 4096  # a stop is ~120 bytes; anything larger is not a door message
AUTH_DEADLINE_S = 1.0  # from TCP accept (TLS and WebSocket handshakes included) to ``auth``
HEARTBEAT_S = 0.25  # 4 Hz: a page calls a road dead after 1 s, so 4 beats are missed first
STOP_ACTIONS = ("emergency", "land", "hover")
ROADS = ("door", "server")
MAX_IDS = 32  # in one supersede
MAX_TOKEN_CHARS = 512
ID_RE = re.compile(r"^[A-Za-z0-9_.:-]{1,64}$")


@dataclass(frozen=True)
class Auth:
    """The pilot token or a door ticket (server.vehicles.tickets)."""

    token: str


@dataclass(frozen=True)
class Stop:
    action: str  # one of STOP_ACTIONS
    id: str  # the operator's stop id: the same on both roads
    issued: float | None  # unix seconds on the console's clock; None: not said


@dataclass(frozen=True)
class Supersede:
    ids: tuple[str, ...]


ClientMessage = Auth | Stop | Supersede


@dataclass(frozen=True)
class Hello:
    drone: str
    t: float  # unix seconds, the vehicle's clock
    heartbeat_s: float = HEARTBEAT_S


@dataclass(frozen=True)
class Heartbeat:
    t: float
    state: str  # the drone's flight state (ctrl_state: LANDED, FLYING, HOVERING, …)
    link_ok: bool  # the vehicle hears its drone


@dataclass(frozen=True)
class Ack:
    id: str
    action: str
    accepted: bool
    detail: str
    delivered: float | None  # unix seconds the vehicle ran the stop (None: it did not)
    road: str = "door"  # the road that delivered it first
    late_s: float | None = None  # delivered - issued, when issued was given


@dataclass(frozen=True)
class Superseded:
    ids: tuple[str, ...]  # will not run, whichever road brings them
    too_late: tuple[str, ...] = ()  # had already run


@dataclass(frozen=True)
class Error:
    detail: str


DoorMessage = Hello | Heartbeat | Ack | Superseded | Error


def _object(text: str | bytes) -> dict[str, Any]:
    if isinstance(text, bytes | bytearray):
        if len(text) > MAX_FRAME_BYTES:
            raise DoorProtocolError(f"frame over {MAX_FRAME_BYTES} bytes")
        try:
            text = bytes(text).decode("utf-8")
        except UnicodeDecodeError as exc:
            raise DoorProtocolError("frame is not UTF-8") from exc
    if len(text) > MAX_FRAME_BYTES:
        raise DoorProtocolError(f"frame over {MAX_FRAME_BYTES} bytes")
    try:
        obj = json.loads(text, parse_constant=_no_constant)
    except (ValueError, RecursionError) as exc:
        raise DoorProtocolError(f"frame is not JSON: {str(exc)[:80]}") from exc
    if not isinstance(obj, dict):
        raise DoorProtocolError("frame is not a JSON object")
    return obj


def _no_constant(name: str) -> float:
    raise ValueError(f"{name} is not a number the door takes")


def _str(obj: dict[str, Any], key: str, limit: int = MAX_TOKEN_CHARS) -> str:
    value = obj.get(key)
    if not isinstance(value, str) or not value or len(value) > limit:
        raise DoorProtocolError(f"{key!r} must be a non-empty string of at most {limit} chars")
    return value


def _id(value: Any) -> str:
    if not isinstance(value, str) or not ID_RE.match(value):
        raise DoorProtocolError("a stop id is 1-64 characters of A-Z a-z 0-9 _ . : -")
    return value


def _time(obj: dict[str, Any], key: str, *, required: bool) -> float | None:
    value = obj.get(key)
    if value is None and not required:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise DoorProtocolError(f"{key!r} must be a finite number of seconds")
    if not 0.0 <= float(value) < 1e11:
        raise DoorProtocolError(f"{key!r} is not a unix time")
    return float(value)


def _action(obj: dict[str, Any]) -> str:
    action = obj.get("action")
    if action not in STOP_ACTIONS:
        raise DoorProtocolError(f"'action' must be one of {', '.join(STOP_ACTIONS)}")
    return str(action)


def stop_message(action: Any, stop_id: Any, issued: Any) -> Stop:
    """A :class:`Stop` from its fields as any road carries them (a door frame, the console's
    ``direct`` call).

    Raises:
        DoorProtocolError: an unknown action, a bad id or a bad ``issued``.
    """
    obj = {"action": action, "issued": issued}
    return Stop(_action(obj), _id(stop_id), _time(obj, "issued", required=False))


def parse_client(text: str | bytes) -> ClientMessage:
    """One frame a client sent.

    Raises:
        DoorProtocolError: not JSON, not an object, an unknown ``op`` or a bad field.
    """
    obj = _object(text)
    op = obj.get("op")
    if op == "auth":
        return Auth(_str(obj, "token"))
    if op == "stop":
        return stop_message(obj.get("action"), obj.get("id"), obj.get("issued"))
    if op == "supersede":
        ids = obj.get("ids")
        if not isinstance(ids, list) or len(ids) > MAX_IDS:
            raise DoorProtocolError(f"'ids' must be a list of at most {MAX_IDS} stop ids")
        return Supersede(tuple(_id(i) for i in ids))
    raise DoorProtocolError(f"unknown op {str(op)[:40]!r} (auth, stop, supersede)")


def parse_door(text: str | bytes) -> DoorMessage:
    """One frame the door sent (for clients: tests, benchmarks, tools).

    Raises:
        DoorProtocolError: not a door message.
    """
    obj = _object(text)
    op = obj.get("op")
    try:
        if op == "hello":
            return Hello(_str(obj, "drone"), _num(obj["t"]), _num(obj["heartbeat_s"]))
        if op == "heartbeat":
            return Heartbeat(_num(obj["t"]), str(obj["state"]), _bool(obj["link_ok"]))
        if op == "ack":
            return Ack(
                _id(obj["id"]),
                _action(obj),
                _bool(obj["accepted"]),
                str(obj["detail"]),
                None if obj.get("delivered") is None else _num(obj["delivered"]),
                _road(obj["road"]),
                None if obj.get("late_s") is None else _num(obj["late_s"]),
            )
        if op == "superseded":
            return Superseded(_ids(obj["ids"]), _ids(obj.get("too_late", [])))
        if op == "error":
            return Error(str(obj["detail"]))
    except KeyError as exc:
        raise DoorProtocolError(f"{op!r} without {exc.args[0]!r}") from exc
    raise DoorProtocolError(f"unknown op {str(op)[:40]!r}")


def _num(value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise DoorProtocolError("expected a finite number")
    return float(value)


def _bool(value: Any) -> bool:
    if not isinstance(value, bool):
        raise DoorProtocolError("expected true or false")
    return value


def _road(value: Any) -> str:
    if value not in ROADS:
        raise DoorProtocolError(f"'road' must be one of {', '.join(ROADS)}")
    return str(value)


def _ids(value: Any) -> tuple[str, ...]:
    if not isinstance(value, list):
        raise DoorProtocolError("expected a list of stop ids")
    return tuple(_id(i) for i in value)


def encode(msg: ClientMessage | DoorMessage) -> str:
    """The frame of one message (compact JSON)."""
    if isinstance(msg, Auth):
        obj: dict[str, Any] = {"op": "auth", "token": msg.token}
    elif isinstance(msg, Stop):
        obj = {"op": "stop", "action": msg.action, "id": msg.id, "issued": msg.issued}
    elif isinstance(msg, Supersede):
        obj = {"op": "supersede", "ids": list(msg.ids)}
    elif isinstance(msg, Hello):
        obj = {"op": "hello", "drone": msg.drone, "t": msg.t, "heartbeat_s": msg.heartbeat_s}
    elif isinstance(msg, Heartbeat):
        obj = {"op": "heartbeat", "t": msg.t, "state": msg.state, "link_ok": msg.link_ok}
    elif isinstance(msg, Ack):
        obj = {
            "op": "ack",
            "id": msg.id,
            "action": msg.action,
            "accepted": msg.accepted,
            "detail": msg.detail,
            "delivered": msg.delivered,
            "road": msg.road,
            "late_s": msg.late_s,
        }
    elif isinstance(msg, Superseded):
        obj = {"op": "superseded", "ids": list(msg.ids), "too_late": list(msg.too_late)}
    else:
        obj = {"op": "error", "detail": msg.detail}
    return json.dumps(obj, separators=(",", ":"), allow_nan=False)


class DoorPhase(enum.Enum):
    AWAITING_AUTH = "awaiting_auth"
    OPEN = "open"
    CLOSED = "closed"


# What each phase takes, and the phase it leads to (anything else closes the connection).
ACCEPTS: dict[DoorPhase, dict[type, DoorPhase]] = {
    DoorPhase.AWAITING_AUTH: {Auth: DoorPhase.OPEN},
    DoorPhase.OPEN: {Stop: DoorPhase.OPEN, Supersede: DoorPhase.OPEN},
    DoorPhase.CLOSED: {},
}


class DoorSession:
    """One connection's protocol state; time is passed in.

    Args:
        accepted_at: when the TCP connection was accepted (the auth deadline runs from it).
        auth_deadline_s: how long it may take to authenticate.
    """

    def __init__(self, accepted_at: float, auth_deadline_s: float = AUTH_DEADLINE_S) -> None:
        self.phase = DoorPhase.AWAITING_AUTH
        self.auth_deadline = accepted_at + auth_deadline_s
        self.next_heartbeat: float | None = None
        self.role: str | None = None

    def receive(self, text: str | bytes) -> ClientMessage:
        """Decode a frame and check it may come now.

        Raises:
            DoorProtocolError: a bad frame (the connection stays as it is), or a message this
                phase does not take (then the phase is CLOSED: before ``auth`` nothing else is
                read, and a second ``auth`` is refused).
        """
        if self.phase is DoorPhase.CLOSED:
            raise DoorProtocolError("the connection is closed")
        try:
            msg = parse_client(text)
        except DoorProtocolError:
            if self.phase is DoorPhase.AWAITING_AUTH:
                self.phase = DoorPhase.CLOSED
            raise
        if type(msg) not in ACCEPTS[self.phase]:
            closing = self.phase is DoorPhase.AWAITING_AUTH
            self.phase = DoorPhase.CLOSED
            if closing:
                raise DoorProtocolError("authenticate first: {'op': 'auth', 'token': …}")
            raise DoorProtocolError("already authenticated")
        return msg

    def authenticated(self, role: str, now: float) -> None:
        """The token of the ``auth`` just received was good for ``role``; heartbeats start."""
        self.phase = ACCEPTS[DoorPhase.AWAITING_AUTH][Auth]
        self.role = role
        self.next_heartbeat = now + HEARTBEAT_S

    def refuse(self) -> None:
        self.phase = DoorPhase.CLOSED

    @property
    def closed(self) -> bool:
        return self.phase is DoorPhase.CLOSED

    def overdue(self, now: float) -> bool:
        """Whether the connection is still unauthenticated past its deadline."""
        return self.phase is DoorPhase.AWAITING_AUTH and now >= self.auth_deadline

    def heartbeat_due(self, now: float) -> bool:
        """Whether a heartbeat is due now (and the next one is scheduled if so)."""
        if self.phase is not DoorPhase.OPEN or self.next_heartbeat is None:
            return False
        if now < self.next_heartbeat:
            return False
        # Keep the cadence; after a stall, the next beat is one period from now, not a burst.
        late = now - self.next_heartbeat > HEARTBEAT_S
        self.next_heartbeat = (now if late else self.next_heartbeat) + HEARTBEAT_S
        return True
