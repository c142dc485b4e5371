"""Tokens, roles, the pilot lease and Origin checks (first security layer, DESIGN §5).

- Two roles: ``pilot`` may command; ``observer`` may only watch (subscribe, read-only services).
- :class:`TokenStore` makes a pilot and an observer token on first start and keeps them in
  ``<data_dir>/tokens.json`` with mode 0600 (as Jupyter keeps its token); ``--token`` overrides.
- :class:`PilotLease`: one pilot connection commands at a time; another pilot takes over only
  explicitly, and the previous holder is told (its revoke callback runs).
- Origin: a browser always sends ``Origin``; a WebSocket whose Origin is neither the served
  origin (the request's ``Host``) nor in ``allow_origins`` is refused (cross-site WebSocket
  hijacking). Clients that send no Origin (roslibpy, Node) are not browsers and pass.
"""

from __future__ import annotations

import enum
import hmac
import json
import os
import re
import secrets
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from fastapi import HTTPException, Request

from server.settings import Settings

TOKEN_FILE = "tokens.json"

# Control topics (DESIGN §4): pilot only, and only for the lease holder. Fleet form: /uavN/...
CONTROL_TOPIC_RE = re.compile(r"^(/uav\d+)?(/cmd_vel|/ardrone/.+|/console/utterance)$")
# Services an observer may call: introspection and ones that change nothing.
READ_ONLY_SERVICE_RE = re.compile(
    r"^(/uav\d+)?(/rosapi/(?!set_param$|delete_param$).+|/console/interpret|/console/describe"
    r"|/console/lease)$"
)
LEASE_SERVICE = "/console/lease"


class Role(enum.StrEnum):
    PILOT = "pilot"
    OBSERVER = "observer"


def _canonical(name: str) -> str:
    return "/" + name.strip().lstrip("/")


def new_token() -> str:
    """A random URL-safe token (192 bits) that does not start with "-".

    A leading dash would make ``--token <token>`` look like an option to a command line.
    """
    while True:
        token = secrets.token_urlsafe(24)
        if not token.startswith("-"):
            return token


class TokenStore:
    """The pilot and observer tokens, created on first start and stored 0600 in ``data_dir``."""

    def __init__(
        self,
        data_dir: Path,
        *,
        pilot_token: str | None = None,
        observer_token: str | None = None,
    ) -> None:
        self.path = Path(data_dir) / TOKEN_FILE
        stored = self._load_or_create()
        self.pilot_token = pilot_token or stored["pilot"]
        self.observer_token = observer_token or stored["observer"]
        if hmac.compare_digest(self.pilot_token, self.observer_token):
            raise ValueError("the pilot and observer tokens must differ")

    def _load_or_create(self) -> dict[str, str]:
        try:
            data = json.loads(self.path.read_text())
            if isinstance(data.get("pilot"), str) and isinstance(data.get("observer"), str):
                return {"pilot": data["pilot"], "observer": data["observer"]}
        except (OSError, ValueError):
            pass  # missing or unreadable: make new tokens below
        data = {"pilot": new_token(), "observer": new_token()}
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        with os.fdopen(fd, "w") as fh:
            json.dump(data, fh)
        os.chmod(self.path, 0o600)
        return data

    def role_for(self, token: str | None) -> Role | None:
        """The role a token grants (constant-time comparison), or None."""
        if not token:
            return None
        if hmac.compare_digest(token.encode(), self.pilot_token.encode()):
            return Role.PILOT
        if hmac.compare_digest(token.encode(), self.observer_token.encode()):
            return Role.OBSERVER
        return None


class LeaseHeld(Exception):
    """Another pilot holds the lease; take over explicitly to command."""


@dataclass(frozen=True)
class LeaseState:
    holder: str | None
    since: float | None


class PilotLease:
    """Who may command right now. Holders are opaque ids (a connection, a REST token…)."""

    def __init__(self) -> None:
        self._holder: str | None = None
        self._since: float | None = None
        self._on_revoke: dict[str, Callable[[str], None]] = {}

    @property
    def state(self) -> LeaseState:
        return LeaseState(self._holder, self._since)

    def acquire(
        self,
        holder: str,
        now: float,
        *,
        take_over: bool = False,
        on_revoke: Callable[[str], None] | None = None,
    ) -> bool:
        """Take the lease if free (or ``take_over``); True if ``holder`` now holds it.

        Raises:
            LeaseHeld: another holder has it and ``take_over`` is False.
        """
        if on_revoke is not None:
            self._on_revoke[holder] = on_revoke
        if self._holder in (None, holder):
            if self._holder is None:
                self._since = now
            self._holder = holder
            return True
        if not take_over:
            raise LeaseHeld(
                f"another pilot ({self._holder}) holds the pilot lease; "
                f"take over explicitly (call {LEASE_SERVICE} with take_over: true)"
            )
        previous = self._holder
        self._holder, self._since = holder, now
        cb = self._on_revoke.get(previous)
        if cb is not None:
            cb(holder)
        return True

    def release(self, holder: str) -> None:
        self._on_revoke.pop(holder, None)
        if self._holder == holder:
            self._holder = self._since = None

    def holds(self, holder: str) -> bool:
        return self._holder == holder


class Security:
    """Role checks and Origin checks for every door (rosbridge, REST)."""

    def __init__(self, settings: Settings, tokens: TokenStore) -> None:
        self.settings = settings
        self.tokens = tokens
        self.lease = PilotLease()

    def role_for(self, token: str | None) -> Role | None:
        return self.tokens.role_for(token)

    @staticmethod
    def is_control_topic(topic: str) -> bool:
        return bool(CONTROL_TOPIC_RE.match(_canonical(topic)))

    @staticmethod
    def is_read_only_service(service: str) -> bool:
        return bool(READ_ONLY_SERVICE_RE.match(_canonical(service)))

    def can_publish(self, role: Role | None, topic: str) -> bool:
        return role is Role.PILOT

    def can_call(self, role: Role | None, service: str) -> bool:
        if role is Role.PILOT:
            return True
        return role is Role.OBSERVER and self.is_read_only_service(service)

    def needs_lease(self, service_or_topic: str, *, service: bool) -> bool:
        """Whether a pilot must hold the lease for this (control topics, non-read-only calls)."""
        if service:
            name = _canonical(service_or_topic)
            return not self.is_read_only_service(name) and not name.startswith("/rosapi/")
        return self.is_control_topic(service_or_topic)

    @staticmethod
    def refusal(role: Role | None, action: str, name: str) -> str:
        """The message for a refused action, naming the role ("observer may not publish to …")."""
        who = role.value if role is not None else "an unauthenticated client"
        return f"{who} may not {action} {name}"

    def origin_allowed(self, origin: str | None, host_header: str | None) -> bool:
        """Whether a WebSocket with this ``Origin`` may connect (None: not a browser)."""
        if origin is None:
            return True
        allowed = set(self.settings.allow_origins)
        if "*" in allowed or origin.rstrip("/") in {a.rstrip("/") for a in allowed}:
            return True
        parts = urlsplit(origin)
        if parts.scheme not in ("http", "https") or not parts.hostname:
            return False
        default = 443 if parts.scheme == "https" else 80
        netloc = f"{parts.hostname.lower()}:{parts.port or default}"
        served = {f"{self.settings.host.lower()}:{self.settings.port}"}
        if host_header:
            h = urlsplit("//" + host_header.strip())
            if h.hostname:
                served.add(f"{h.hostname.lower()}:{h.port or default}")
        return netloc in served


def token_from(headers: Mapping[str, str], query: Mapping[str, str]) -> str | None:
    """The token of a request: ``?token=`` or ``Authorization: Bearer …``."""
    token = query.get("token")
    if token:
        return token
    auth = headers.get("authorization") or headers.get("Authorization") or ""
    scheme, _, value = auth.partition(" ")
    if scheme.lower() == "bearer" and value.strip():
        return value.strip()
    return None


def require_role(security: Security, *roles: Role | str) -> Callable[..., Any]:
    """A FastAPI dependency: the request's role, if it is one of ``roles`` (default: any).

    401 without a valid token, 403 when the role is not allowed; the detail names the role.
    """
    wanted: Iterable[Role] = [Role(r) for r in roles] or list(Role)
    wanted_set = set(wanted)

    async def dependency(request: Request) -> Role:
        role = security.role_for(token_from(request.headers, request.query_params))
        if role is None:
            raise HTTPException(
                status_code=401,
                detail="a valid token is required (Authorization: Bearer … or ?token=…)",
                headers={"WWW-Authenticate": "Bearer"},
            )
        if role not in wanted_set:
            raise HTTPException(
                status_code=403,
                detail=f"{role.value} may not {request.method} {request.url.path}",
            )
        return role

    return dependency
