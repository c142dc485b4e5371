"""Opening Zenoh. Open it only after any fork of the process (spawn children instead)."""

from __future__ import annotations

import json
import logging
import socket
from typing import Any

import zenoh

from drone.bus.errors import BusConfigError

log = logging.getLogger(__name__)

DEFAULT_LISTEN = "tcp/127.0.0.1:7447"
PROBE_TIMEOUT_S = 1.5


def open_session(config: dict[str, Any]) -> zenoh.Session:
    """A Zenoh session for ``config``.

    Raises:
        BusConfigError: Zenoh refused the configuration, or could not listen or connect.
    """
    zenoh.init_log_from_env_or("error")  # Zenoh's own log: errors only, unless RUST_LOG says
    try:
        return zenoh.open(zenoh.Config.from_json5(json.dumps(config)))
    except zenoh.ZError as exc:
        raise BusConfigError(f"the bus could not start: {exc}") from exc


def free_listen_endpoint(endpoint: str = DEFAULT_LISTEN, tries: int = 64) -> str:
    """``endpoint`` if its TCP port is free, else the next free port on the same address
    (``tls/`` runs over TCP)."""
    proto, _, rest = endpoint.partition("/")
    host, _, port_text = rest.rpartition(":")
    if proto not in ("tcp", "tls") or not port_text.isdigit():
        return endpoint  # only a TCP endpoint can be probed; others are used as given
    port = int(port_text)
    for candidate in range(port, port + tries):
        with socket.socket(socket.AF_INET6 if ":" in host.strip("[]") else socket.AF_INET) as s:
            try:
                s.bind((host.strip("[]"), candidate))
            except OSError:
                continue
        return f"{proto}/{host}:{candidate}"
    raise BusConfigError(f"no free port from {endpoint} to port {port + tries - 1}")


def router_ids(
    endpoints: list[str],
    user: str,
    password: str,
    timeout_s: float = PROBE_TIMEOUT_S,
    ca: str | None = None,
) -> list[str]:
    """The Zenoh ids of the routers at ``endpoints``, asked with a short client session each
    (those that do not answer in ``timeout_s`` are left out, said in the log).

    A router that joins another authenticates itself to it, but is not authenticated by it: on
    the joining router's side that link carries no user name, so its access control knows the
    routers it joins only by their ids (``drone.bus.config.access_control``'s ``peers``).
    ``ca``: the CA that ``tls/`` routers are verified with.
    """
    from drone.bus.config import client_config

    found: list[str] = []
    for endpoint in endpoints:
        config = client_config(connect=[endpoint], user=user, password=password, ca=ca)
        config["connect"]["timeout_ms"] = int(timeout_s * 1000)
        try:
            session = zenoh.open(zenoh.Config.from_json5(json.dumps(config)))
        except zenoh.ZError as exc:
            log.warning("bus: the router at %s did not answer (%s)", endpoint, exc)
            continue
        try:
            found += [str(zid) for zid in session.info.routers_zid()]
        finally:
            session.close()  # type: ignore[no-untyped-call]
    return found
