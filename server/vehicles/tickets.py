"""Door tickets: what the console gives a page so it can open a vehicle's safety door.

A ticket is ``dt1.<drone>.<role>.<expires>.<mac>``: ``expires`` in whole unix seconds, ``mac``
the HMAC-SHA256 (RFC 2104) of everything before it under the vehicle's door secret, base64url
without padding. The console mints tickets and gives each vehicle it spawns its secret
(``UAVC_DOOR_SECRET``), so the door checks a ticket on its own: tickets keep working while the
console is stopped or gone, until they expire (:data:`TICKET_TTL_S`). A ticket names one drone
and one role; the door takes only pilot tickets for its own drone. A ticket cannot command
anything but the door's stops, so a leaked one is worth less than the pilot token.

:class:`DoorSecrets` keeps one random secret per vehicle name in the data directory (0600), so
a ``serve`` restarted after a crash mints tickets the vehicles it adopts still accept.
"""

from __future__ import annotations

import base64
import contextlib
import hashlib
import hmac
import json
import re
import secrets
from pathlib import Path

from server.vehicles.errors import TicketError

PREFIX = "dt1"
TICKET_TTL_S = 12 * 3600.0  # a shift: a page loaded once keeps its stops all day
NAME_RE = re.compile(r"^[A-Za-z0-9_-]{1,32}$")
ROLES = ("pilot", "observer")
SECRET_BYTES = 32
SECRETS_FILE = "door-secrets.json"
MAX_TICKET_CHARS = 160


def _mac(secret: bytes, body: str) -> str:
    digest = hmac.new(secret, body.encode("ascii"), hashlib.sha256).digest()
    return base64.urlsafe_b64encode(digest).rstrip(b"=").decode("ascii")


def mint(secret: bytes, drone: str, role: str, expires: float) -> str:
    """A ticket for ``role`` on ``drone``'s door, valid until unix time ``expires``.

    Raises:
        TicketError: a drone name or role a ticket cannot carry.
    """
    if not NAME_RE.match(drone):
        raise TicketError(f"a ticket cannot name the drone {drone[:40]!r}")
    if role not in ROLES:
        raise TicketError(f"a ticket cannot carry the role {role[:20]!r}")
    body = f"{PREFIX}.{drone}.{role}.{int(expires)}"
    return f"{body}.{_mac(secret, body)}"


def looks_like_ticket(token: str) -> bool:
    """Whether ``token`` is shaped as a ticket (the door then checks it as one)."""
    return token.startswith(f"{PREFIX}.")


def verify(secret: bytes, ticket: str, drone: str, now: float) -> str:
    """The role ``ticket`` grants on ``drone``'s door at unix time ``now``.

    Raises:
        TicketError: malformed, a wrong MAC (forged, or another vehicle's secret), another
            drone, or expired.
    """
    if not isinstance(ticket, str) or len(ticket) > MAX_TICKET_CHARS:
        raise TicketError("not a ticket")
    parts = ticket.split(".")
    if len(parts) != 5 or parts[0] != PREFIX:
        raise TicketError("not a ticket")
    _, name, role, expires, mac = parts
    if not NAME_RE.match(name) or role not in ROLES or not expires.isdigit():
        raise TicketError("not a ticket")
    body = ".".join(parts[:4])
    if not hmac.compare_digest(_mac(secret, body).encode(), mac.encode("ascii", "replace")):
        raise TicketError("the ticket's signature does not match (forged, or not this vehicle's)")
    if name != drone:
        raise TicketError(f"the ticket is for {name}, not {drone}")
    if int(expires) <= now:
        raise TicketError("the ticket has expired: reload the console for a new one")
    return role


class DoorSecrets:
    """Per-vehicle door secrets in ``<dir>/door-secrets.json`` (hex, mode 0600)."""

    def __init__(self, directory: Path) -> None:
        self.path = Path(directory) / SECRETS_FILE
        self._secrets: dict[str, bytes] = {}
        with contextlib.suppress(OSError, ValueError, AttributeError, TypeError):
            stored = json.loads(self.path.read_text())
            self._secrets = {str(k): bytes.fromhex(str(v)) for k, v in stored.items()}

    def get(self, name: str) -> bytes | None:
        """The secret of vehicle ``name`` (None: none was made for it)."""
        return self._secrets.get(name)

    def get_or_create(self, name: str) -> bytes:
        """The secret of vehicle ``name``, made and stored on first use."""
        found = self._secrets.get(name)
        if found is not None:
            return found
        from server.http.security import secure_dir, write_private_atomically

        secret = secrets.token_bytes(SECRET_BYTES)
        self._secrets[name] = secret
        secure_dir(self.path.parent)
        text = json.dumps({k: v.hex() for k, v in self._secrets.items()})
        write_private_atomically(self.path, text)
        return secret
