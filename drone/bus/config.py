"""Zenoh configurations as plain dicts (JSON is JSON5): the console's router, its clients, and the
access control that lets each credential do only its own part.

Roles on the bus (``transport/auth/usrpwd`` user names):
- ``console``: the router's own user, and consoles joining it; may do everything in its fleet.
- ``observer``: subscribes and queries liveliness; publishes and commands nothing.
- ``pilot``: an observer that may also send commands (queries on ``…/cmd``); the vehicle judges
  each one by its lease.
- ``vehicle-<name>``: publishes, declares liveliness and answers queries under its own
  ``uavc/<fleet>/<name>/`` only.
Access control is the router's (Zenoh 1.x ``access_control``, default deny); a message it refuses
never leaves the router.
"""

from __future__ import annotations

import hashlib
import ipaddress
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any, Literal

from drone.bus import keys

CONSOLE_USER = "console"
OBSERVER_USER = "observer"
PILOT_USER = "pilot"
VEHICLE_PREFIX = "vehicle-"

_EVERYTHING = [
    "put",
    "delete",
    "declare_subscriber",
    "query",
    "declare_queryable",
    "reply",
    "liveliness_token",
    "declare_liveliness_subscriber",
    "liveliness_query",
]
# Zenoh's shared-memory transport between processes on one host: off. Its watchdog threads run
# at SCHED_FIFO 1 (seen in /proc/<pid>/task of a vehicle process), above every normal thread,
# which a vehicle keeps for its 100 Hz control thread alone; the bus's messages are small.
NO_SHARED_MEMORY: dict[str, Any] = {"shared_memory": {"enabled": False}}

JOIN_RETRY_MS = 1000  # a joiner dials a router that is not up (yet, or again) this often
# A client or joiner that lost its router dials it again after this, then backs off (×2) to
# JOIN_RETRY_MS: a console restarts its router to change its access control (a vehicle key
# made or revoked while it runs) and its clients are back within tens of milliseconds of the
# router listening again, well inside a vehicle's 1 s heartbeat timeout. Zenoh's default
# (1 s) would leave them off the bus about a second (measured: docs/bus.md).
REJOIN_RETRY_MS = 20


def _retry(init_ms: int) -> dict[str, Any]:
    """Zenoh 1.x ``connect/retry``: dial after ``init_ms``, doubling up to JOIN_RETRY_MS."""
    return {
        "period_init_ms": init_ms,
        "period_max_ms": JOIN_RETRY_MS,
        "period_increase_factor": 2,
    }


_WATCH = ["declare_subscriber", "declare_liveliness_subscriber", "liveliness_query"]
_OWN = ["put", "delete", "liveliness_token", "declare_queryable", "reply"]


@dataclass(frozen=True)
class BusTLS:
    """TLS on the bus's links: the CA (PEM file) a client verifies the router with, and, for
    the router, the certificate and key it listens with (signed by that CA)."""

    ca: str
    cert: str | None = None
    key: str | None = None


def tls_link(tls: BusTLS) -> dict[str, Any]:
    """Zenoh 1.x ``transport/link/tls`` for ``tls``: files, not inline PEM (Zenoh's
    DEFAULT_CONFIG.json5). Names are verified on connect (Zenoh's default)."""
    section: dict[str, Any] = {"root_ca_certificate": tls.ca}
    if tls.cert is not None and tls.key is not None:
        section |= {"listen_certificate": tls.cert, "listen_private_key": tls.key}
    return {"link": {"tls": section}}


def endpoint_host(endpoint: str) -> str:
    """The host of ``proto/host:port`` (brackets of an IPv6 address removed)."""
    _proto, _, rest = endpoint.partition("/")
    host, _, _port = rest.partition("#")[0].rpartition(":")
    return host.strip("[]")


def on_loopback(endpoint: str) -> bool:
    """Whether ``endpoint`` listens for this machine only (a wildcard address does not)."""
    host = endpoint_host(endpoint)
    if host in ("localhost", "localhost."):
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def wants_tls(mode: Literal["auto", "on", "off"], listen: Iterable[str]) -> bool:
    """TLS for the router listening on ``listen``: ``auto`` when any endpoint is off loopback
    or already ``tls/``."""
    if mode != "auto":
        return mode == "on"
    return any(e.startswith("tls/") or not on_loopback(e) for e in listen)


def as_tls(endpoint: str) -> str:
    """``tcp/HOST:PORT`` as ``tls/HOST:PORT`` (TLS runs over TCP); other endpoints unchanged."""
    return "tls/" + endpoint.removeprefix("tcp/") if endpoint.startswith("tcp/") else endpoint


def vehicle_user(name: str) -> str:
    return VEHICLE_PREFIX + keys.segment(name)


def vehicles_among(users: Iterable[str]) -> list[str]:
    """The vehicle names among bus users (those :func:`vehicle_user` makes), sorted."""
    return sorted(u.removeprefix(VEHICLE_PREFIX) for u in users if u.startswith(VEHICLE_PREFIX))


def access_control(fleet: str, vehicles: Iterable[str]) -> dict[str, Any]:
    """The router's ACL for ``fleet`` and these vehicle names. Zenoh reads it when the router
    opens, so a console restarts its router when the vehicles change
    (:meth:`drone.bus.console.ConsoleBus.rekey`).

    The routers of other consoles reach it only through its joiners
    (:func:`joiner_config`), which authenticate as ``console``."""
    root = f"{keys.ROOT}/{keys.segment(fleet)}"
    rules: list[dict[str, Any]] = [
        _rule("deliver", ["egress"], _EVERYTHING, [f"{keys.ROOT}/**"]),
        _rule("watch", ["ingress"], _WATCH, [f"{root}/**"]),
        _rule("command", ["ingress"], ["query"], [f"{root}/*/cmd"]),
        _rule("console", ["ingress"], _EVERYTHING, [f"{root}/**"]),
    ]
    subjects: list[dict[str, Any]] = [
        {"id": "everyone"},
        {"id": "commanders", "usernames": [PILOT_USER, CONSOLE_USER]},
        {"id": "consoles", "usernames": [CONSOLE_USER]},
    ]
    policies: list[dict[str, Any]] = [
        {"id": "all-watch", "rules": ["deliver", "watch"], "subjects": ["everyone"]},
        {"id": "pilots-command", "rules": ["command"], "subjects": ["commanders"]},
        {"id": "consoles-all", "rules": ["console"], "subjects": ["consoles"]},
    ]
    for name in sorted(set(vehicles)):
        rid = f"own-{name}"
        rules.append(_rule(rid, ["ingress"], _OWN, [f"{root}/{keys.segment(name)}/**"]))
        subjects.append({"id": f"vehicle-{name}", "usernames": [vehicle_user(name)]})
        policies.append({"id": rid, "rules": [rid], "subjects": [f"vehicle-{name}"]})
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }


def _rule(rid: str, flows: list[str], messages: list[str], key_exprs: list[str]) -> dict[str, Any]:
    return {
        "id": rid,
        "permission": "allow",
        "flows": flows,
        "messages": messages,
        "key_exprs": key_exprs,
    }


def router_config(
    *,
    listen: list[str],
    connect: list[str],
    password: str,
    dictionary_file: str,
    acl: dict[str, Any],
    zid: str | None = None,
    tls: BusTLS | None = None,
) -> dict[str, Any]:
    """The console's embedded router: listens where told, joins only the routers named (no
    multicast scouting: a second console on the same machine must not join this fleet).
    ``zid``: its Zenoh id, the same at every start (other consoles trust it by its id).
    ``tls``: its certificate for ``tls/`` endpoints, and the CA it checks routers it joins by."""
    return {
        **({"id": zid} if zid else {}),
        "mode": "router",
        "listen": {"endpoints": listen},
        "connect": {"endpoints": connect},
        # delay: what `zenoh.open` waits to scout others before it returns (500 ms by
        # default); this router scouts nobody, and a restart (ConsoleBus.rekey) keeps its
        # clients off the bus no longer than it takes to open (2 ms measured, against 500)
        "scouting": {"multicast": {"enabled": False}, "delay": 0},
        "transport": {
            "auth": {
                "usrpwd": {
                    "user": CONSOLE_USER,
                    "password": password,
                    "dictionary_file": dictionary_file,
                }
            },
            **NO_SHARED_MEMORY,
            **(tls_link(tls) if tls is not None else {}),
        },
        "access_control": acl,
    }


def joiner_config(
    *, router: str, peer: str, password: str, ca: str | None = None
) -> dict[str, Any]:
    """A console's joiner: a router of its own that listens nowhere and links the console's
    router (``router``, dialled as a client would) with another console's or ``zenohd``
    (``peer``), authenticating to both as ``console``. It keeps dialling ``peer`` until it
    answers and after it goes (Zenoh's router retries for ever), so a console may start before
    the one it joins.

    Why a router between them: the router that dials another authenticates itself but learns
    no user name of the other, so its access control could only admit the other by a Zenoh
    id known before it starts. Both routers admit the joiner by its user name instead, and the
    joiner, which accepts no link, needs no access control. ``ca``: the CA ``tls/`` routers
    are verified with."""
    return {
        "mode": "router",
        "listen": {"endpoints": []},
        "connect": {
            "endpoints": [router, peer],
            "retry": _retry(REJOIN_RETRY_MS),
        },
        "scouting": {"multicast": {"enabled": False}},
        "transport": {
            "auth": {"usrpwd": {"user": CONSOLE_USER, "password": password}},
            **NO_SHARED_MEMORY,
            **(tls_link(BusTLS(ca)) if ca is not None else {}),
        },
    }


def client_config(
    *, connect: list[str], user: str, password: str, ca: str | None = None
) -> dict[str, Any]:
    """A client of the router: what ``client.json5`` holds for a third-party script.
    ``ca``: the CA file that a ``tls/`` router's certificate must be signed by. A client that
    loses its router dials it again within :data:`REJOIN_RETRY_MS` (a router restarted on
    its endpoint takes it back at once)."""
    return {
        "mode": "client",
        "connect": {"endpoints": connect, "retry": _retry(REJOIN_RETRY_MS)},
        "scouting": {"multicast": {"enabled": False}},
        "transport": {
            "auth": {"usrpwd": {"user": user, "password": password}},
            **NO_SHARED_MEMORY,
            **(tls_link(BusTLS(ca)) if ca is not None else {}),
        },
    }


def router_id(fleet: str, console: str) -> str:
    """The Zenoh id of console ``console``'s router in ``fleet``: SHA-256 of the two names, 32 hex
    digits without leading zeros (Zenoh refuses an id with a leading ``0``: "Leading 0s are not
    valid"), so the same across restarts and unique while console names are."""
    digest = hashlib.sha256(f"uavc/{keys.segment(fleet)}/{keys.segment(console)}".encode())
    return digest.hexdigest()[:32].lstrip("0") or "1"
