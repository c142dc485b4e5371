"""Tokens, roles, the pilot lease and Origin checks (first security layer, DESIGN §5).

- Two roles: ``pilot`` may command; ``observer`` may only watch (subscribe, read-only services).
- :class:`TokenStore` makes a pilot and an observer token on first start and keeps them in
  ``<data_dir>/tokens.json`` with mode 0600 (as Jupyter keeps its token); ``--token`` overrides.
- :class:`PilotLease`: one pilot connection commands at a time; another pilot takes over only
  explicitly, and the previous holder is told (its revoke callback runs). Holder ids are not
  secret (rosapi lists connections); each holding gets a secret ``key``, told only to the
  holder, which REST callers name in ``X-Pilot-Lease`` (an id alone would do for anyone:
  observers can read it).
- Only the server publishes ``/console/*`` and ``/fleet/*`` (replies, state, fleet status), but
  for ``/console/utterance``, which a pilot sends; a fake "battery critical" reply is refused.
- The lease judges what a pilot sends, not where it enters: land, a zero ``/cmd_vel`` (hover) and
  an utterance that asks only land, hover or emergency need no lease (:meth:`Security.
  lease_exempt`), as at REST (``server.api.deps.check_lease``).
- Origin: a browser always sends ``Origin``; a WebSocket whose Origin is neither the served
  origin (the request's ``Host``) nor in ``allow_origins`` is refused (cross-site WebSocket
  hijacking). Clients that send no Origin (roslibpy, Node) are not browsers and pass.
"""

from __future__ import annotations

import contextlib
import enum
import hmac
import ipaddress
import json
import os
import re
import secrets
import tempfile
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any
from urllib.parse import urlsplit

from server.settings import Settings

if TYPE_CHECKING:  # FastAPI is the web process's: a vehicle process uses the rest without it
    from fastapi import Request

TOKEN_FILE = "tokens.json"

# Control topics (DESIGN §4): pilot only, and only for the lease holder. Fleet form: /uavN/...
CONTROL_TOPIC_RE = re.compile(r"^(/uav\d+)?(/cmd_vel|/ardrone/.+|/console/utterance)$")
# Server-only topics: the console's replies/state and the fleet's status (DESIGN §4).
SERVER_TOPIC_RE = re.compile(r"^(/fleet(/.*)?|(/[^/]+)?/console(/.*)?)$")
PILOT_CONSOLE_TOPIC_RE = re.compile(r"^(/[^/]+)?/console/utterance$")
# A drone's own names: its vehicle process's (server.vehicles.names: info, telemetry, reply,
# state, control, interpret) and its LTM's (``/NAME/fleet/ltm_status``, the flight-plan service
# ``/NAME/fleet/flight_plan``): only that vehicle, over the bus, or the console's own LTM of an
# in-process drone has them, never a client here (a pilot's "reply" there would be re-published
# on /console/reply as the drone's; a pilot's LTM status would put a drone in the CTM's plans).
VEHICLE_NAME_RE = re.compile(r"^/[^/]+/(vehicle|fleet)(/.*)?$")
# Safety commands any pilot may publish without the lease (DESIGN §5: any pilot may land).
ANY_PILOT_TOPIC_RE = re.compile(r"^(/uav\d+)?/ardrone/land$")
CMD_VEL_RE = re.compile(r"^(/uav\d+)?/cmd_vel$")
# What any pilot may ask, lease or not (DESIGN §5), whatever door it comes through.
SAFETY_ACTIONS = frozenset({"land", "emergency", "hover"})
TOKEN_COOKIE = "uavc_token"  # set on the first load of the console (tokens out of URLs)
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
        secure_dir(self.path.parent)
        try:
            data = json.loads(self.path.read_text())
            if isinstance(data.get("pilot"), str) and isinstance(data.get("observer"), str):
                return {"pilot": data["pilot"], "observer": data["observer"]}
        except (OSError, ValueError, AttributeError):
            pass  # missing or unreadable: make new tokens below
        data = {"pilot": new_token(), "observer": new_token()}
        write_private_atomically(self.path, json.dumps(data))
        return data

    def role_for(self, token: str | None) -> Role | None:
        """The role a token grants (constant-time comparison), or None.

        Any string is answered, never raised on: a lone surrogate (``"\\ud800"`` from JSON)
        cannot be UTF-8 and simply matches no token.
        """
        if not token or not isinstance(token, str):
            return None
        raw = token.encode("utf-8", "surrogatepass")
        if hmac.compare_digest(raw, self.pilot_token.encode()):
            return Role.PILOT
        if hmac.compare_digest(raw, self.observer_token.encode()):
            return Role.OBSERVER
        return None


def secure_dir(path: Path) -> None:
    """Create ``path`` (and parents) and make it 0700: tokens and the audit log live there."""
    path.mkdir(parents=True, exist_ok=True, mode=0o700)
    os.chmod(path, 0o700)


def write_private_atomically(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` (mode 0600) so a reader sees the old file or the new one,
    never a half-written one: a temporary file in the same directory, fsynced, renamed."""
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        os.fchmod(fd, 0o600)
        with os.fdopen(fd, "w") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def is_zero_twist(msg: Any) -> bool:
    """Whether ``msg`` is an all-zero ``geometry_msgs/Twist`` (missing fields count as 0):
    a hover, in ardrone_autonomy's semantics of ``/cmd_vel``."""
    if not isinstance(msg, Mapping):
        return False
    for part in ("linear", "angular"):
        vec = msg.get(part, {})
        if vec is None:
            continue
        if not isinstance(vec, Mapping):
            return False
        for axis in ("x", "y", "z"):
            v = vec.get(axis, 0)
            if isinstance(v, bool) or not isinstance(v, int | float) or v != 0:
                return False
    return True


class LeaseHeld(Exception):
    """Another pilot holds the lease; take over explicitly to command."""


@dataclass(frozen=True)
class LeaseState:
    holder: str | None
    since: float | None


class PilotLease:
    """Who may command right now. Holders are ids (a connection, ``rest:…``), which are not
    secret; the holding's secret is :meth:`key_of`, told only to the holder."""

    PUBLIC_NAME = "another pilot"  # what non-holders are told about the holder

    def __init__(self) -> None:
        self._holder: str | None = None
        self._since: float | None = None
        self._key: str | None = None
        self._on_revoke: dict[str, Callable[[str], None]] = {}
        # called (previous, new holder, how) whenever the holder changes: the audit trail
        self.on_change: Callable[[str | None, str | None, str], None] | None = None

    def _changed(self, previous: str | None, holder: str | None, how: str) -> None:
        if self.on_change is not None and previous != holder:
            self.on_change(previous, holder, how)

    def key_of(self, holder: str) -> str | None:
        """The secret of the current holding, if ``holder`` holds the lease."""
        return self._key if self._holder == holder else None

    def key_matches(self, key: str | None) -> bool:
        """Whether ``key`` is the current holding's secret (constant time)."""
        if not key or self._key is None:
            return False
        return hmac.compare_digest(key.encode("utf-8", "surrogatepass"), self._key.encode())

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
                self._key = secrets.token_urlsafe(18)
                self._changed(None, holder, "acquire")
            self._holder = holder
            return True
        if not take_over:
            raise LeaseHeld(
                "another pilot holds the pilot lease; "
                f"take over explicitly (call {LEASE_SERVICE} with take_over: true)"
            )
        previous = self._holder
        self._holder, self._since = holder, now
        self._key = secrets.token_urlsafe(18)
        self._changed(previous, holder, "take_over")
        cb = self._on_revoke.get(previous)
        if cb is not None:
            cb(holder)
        return True

    def release(self, holder: str) -> None:
        self._on_revoke.pop(holder, None)
        if self._holder == holder:
            self._holder = self._since = self._key = None
            self._changed(holder, None, "release")

    def holds(self, holder: str) -> bool:
        return self._holder == holder


class Security:
    """Role checks and Origin checks for every door (rosbridge, REST)."""

    def __init__(self, settings: Settings, tokens: TokenStore) -> None:
        self.settings = settings
        self.tokens = tokens
        self.lease = PilotLease()
        # The actions a typed or spoken text asks (the runtime sets it to its NLU), so an
        # utterance that asks only land, hover or emergency needs no lease at any door.
        self.actions_of: Callable[[str], set[str]] | None = None

    def role_for(self, token: str | None) -> Role | None:
        return self.tokens.role_for(token)

    def identify(self, token: str | None) -> str | None:
        """Who holds ``token`` beyond its role (a vehicle's name); None here: tokens are roles."""
        return None

    @staticmethod
    def is_control_topic(topic: str) -> bool:
        return bool(CONTROL_TOPIC_RE.match(_canonical(topic)))

    @staticmethod
    def is_read_only_service(service: str) -> bool:
        return bool(READ_ONLY_SERVICE_RE.match(_canonical(service)))

    def can_publish(self, role: Role | None, topic: str, who: str | None = None) -> bool:
        """Pilots publish, but not on the server's own ``/console/*`` and ``/fleet/*``, nor
        on a drone's own ``/NAME/vehicle/*`` and ``/NAME/fleet/*``."""
        name = _canonical(topic)
        if SERVER_TOPIC_RE.match(name) and not PILOT_CONSOLE_TOPIC_RE.match(name):
            return False
        if VEHICLE_NAME_RE.match(name):
            return False
        return role is Role.PILOT

    def can_call(self, role: Role | None, service: str, who: str | None = None) -> bool:
        if role is Role.PILOT:
            return True
        return role is Role.OBSERVER and self.is_read_only_service(service)

    def can_provide(self, role: Role | None, service: str, who: str | None = None) -> bool:
        """Whether a client may provide ``service`` (``advertise_service``): pilots only, and
        not a drone's own ``/NAME/vehicle/*`` (the console's commands to the drone go there) nor
        ``/NAME/fleet/*`` (the CTM's plans to its LTM)."""
        return role is Role.PILOT and not VEHICLE_NAME_RE.match(_canonical(service))

    def needs_lease(self, service_or_topic: str, *, service: bool) -> bool:
        """Whether a pilot must hold the lease for this (control topics, non-read-only calls)."""
        if service:
            name = _canonical(service_or_topic)
            return not self.is_read_only_service(name) and not name.startswith("/rosapi/")
        if ANY_PILOT_TOPIC_RE.match(_canonical(service_or_topic)):
            return False  # any pilot may land (DESIGN §5), lease or not
        return self.is_control_topic(service_or_topic)

    def lease_exempt(self, topic: str, msg: Any) -> bool:
        """Whether this message on a control topic needs no lease though its topic does: any
        pilot may land or hover (DESIGN §5). A zero ``/cmd_vel`` is a hover (ardrone_autonomy:
        all zeros hover); an utterance is judged by what it asks, as ``POST /command`` is."""
        name = _canonical(topic)
        if CMD_VEL_RE.match(name):
            return is_zero_twist(msg)
        if PILOT_CONSOLE_TOPIC_RE.match(name) and self.actions_of is not None:
            text = msg.get("text") if isinstance(msg, Mapping) else None
            if not isinstance(text, str):
                return False
            actions = self.actions_of(text)
            return bool(actions) and actions <= SAFETY_ACTIONS
        return False

    def refusal(self, role: Role | None, action: str, name: str, who: str | None = None) -> str:
        """The message for a refused action, naming the role ("observer may not publish to …")
        and, when ``who`` is given, who it is."""
        party = role.value if role is not None else "an unauthenticated client"
        if who:
            party = f"{party} {who}"
        return f"{party} may not {action} {name}"

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
        try:  # ``.port`` raises on "127.0.0.1:8123.evil.example": not an origin we serve
            netloc = f"{parts.hostname.lower()}:{parts.port or default}"
        except ValueError:
            return False
        served = {f"{self.settings.host.lower()}:{self.settings.port}"}
        if host_header:
            parsed = parse_host(host_header, default)
            if parsed is not None and self.host_allowed(parsed[0]):
                served.add(f"{parsed[0]}:{parsed[1]}")
        return netloc in served

    def host_allowed(self, hostname: str) -> bool:
        """Whether a request naming ``hostname`` in ``Host`` is for us (DNS rebinding guard).

        An IP literal, ``localhost``, the served host, ``allow_hosts`` and single-label names
        (``testserver``, a machine's bare hostname: only local resolution can answer those, not
        an attacker's DNS) pass; any other name may be an attacker's domain re-pointed at
        127.0.0.1, so the request is refused.
        """
        name = hostname.lower().rstrip(".")
        allowed = {a.lower() for a in self.settings.allow_hosts}
        if "*" in allowed or name in allowed or name == self.settings.host.lower():
            return True
        if name == "localhost" or name.endswith(".localhost") or "." not in name.strip("[]:"):
            return True
        try:
            ipaddress.ip_address(name.strip("[]"))
        except ValueError:
            return False
        return True


def parse_host(host_header: str, default_port: int) -> tuple[str, int] | None:
    """``Host`` as (lower-case hostname, port), or None when it is malformed."""
    raw = host_header.strip()
    if not raw or any(c in raw for c in "/?#@ \\"):
        return None
    parts = urlsplit("//" + raw)
    try:
        port = parts.port
    except ValueError:  # "127.0.0.1:abc", a port out of range
        return None
    if not parts.hostname:
        return None
    return parts.hostname.lower(), port or default_port


def token_from(
    headers: Mapping[str, str],
    query: Mapping[str, str],
    cookies: Mapping[str, str] | None = None,
) -> str | None:
    """The token of a request: ``?token=``, ``Authorization: Bearer …`` or the console's
    cookie (set on the first load, so the token can leave the address bar)."""
    token = query.get("token")
    if token:
        return token
    auth = headers.get("authorization") or headers.get("Authorization") or ""
    scheme, _, value = auth.partition(" ")
    if scheme.lower() == "bearer" and value.strip():
        return value.strip()
    if cookies:
        return cookies.get(TOKEN_COOKIE) or None
    return None


def require_role(security: Security, *roles: Role | str) -> Callable[..., Any]:
    """A FastAPI dependency: the request's role, if it is one of ``roles`` (default: any).

    401 without a valid token, 403 when the role is not allowed; the detail names the role.
    """
    from fastapi import HTTPException, Request

    wanted: Iterable[Role] = [Role(r) for r in roles] or list(Role)
    wanted_set = set(wanted)

    async def dependency(request: Request) -> Role:
        role = security.role_for(token_from(request.headers, request.query_params, request.cookies))
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

    # FastAPI reads the parameter's type to inject the request: the class, not the name
    dependency.__annotations__["request"] = Request
    return dependency
