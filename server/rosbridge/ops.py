"""The rosbridge v2 operations a client sends, decoded (ROSBRIDGE_PROTOCOL.md §3.4).

Only ``op`` is required by the protocol; every other field has the protocol's default here.
``id`` is the client's name for the interaction and is echoed in replies and status messages.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class Advertise:
    topic: str
    type: str
    id: str | None = None
    latch: bool = False
    queue_size: int = 100


@dataclass(frozen=True)
class Unadvertise:
    topic: str
    id: str | None = None


@dataclass(frozen=True)
class Publish:
    """``issued`` (ours, beside the protocol's fields): when the operator gave the command,
    Unix seconds of the server's clock (drone/deadline.py); None: when it arrives.
    ``issued_error``: why the frame's ``issued`` is not Unix seconds (the session refuses a
    motion command for it, but never holds a stop back)."""

    topic: str
    msg: dict[str, Any]
    id: str | None = None
    latch: bool = False
    issued: float | None = None
    issued_error: str | None = None


@dataclass(frozen=True)
class Subscribe:
    topic: str
    id: str | None = None
    type: str | None = None
    throttle_rate_ms: int = 0
    queue_length: int = 0
    fragment_size: int | None = None
    compression: str = "none"


@dataclass(frozen=True)
class Unsubscribe:
    topic: str
    id: str | None = None


@dataclass(frozen=True)
class CallService:
    service: str
    args: dict[str, Any] | list[Any] = field(default_factory=dict)
    id: str | None = None
    timeout_s: float | None = None
    fragment_size: int | None = None
    compression: str = "none"


@dataclass(frozen=True)
class ServiceResponse:
    service: str
    id: str | None = None
    values: Any = None
    result: bool = True


@dataclass(frozen=True)
class AdvertiseService:
    service: str
    type: str
    id: str | None = None


@dataclass(frozen=True)
class UnadvertiseService:
    service: str
    id: str | None = None


@dataclass(frozen=True)
class SetLevel:
    level: str
    id: str | None = None


@dataclass(frozen=True)
class Auth:
    """Our ``auth``: ``token`` (or rosauth's ``mac`` carrying the token) and optional takeover."""

    token: str
    id: str | None = None


@dataclass(frozen=True)
class StatusIn:
    """A ``status`` a client sent us; accepted and ignored (the protocol allows both ways)."""

    level: str
    msg: str
    id: str | None = None


Op = (
    Advertise
    | Unadvertise
    | Publish
    | Subscribe
    | Unsubscribe
    | CallService
    | ServiceResponse
    | AdvertiseService
    | UnadvertiseService
    | SetLevel
    | Auth
    | StatusIn
)
