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
    (``tls/`` runs over TCP). A port is free when nothing listens on it: probed with
    ``SO_REUSEADDR``, as Zenoh binds its listener, so the connections a router killed a moment
    ago left in ``TIME_WAIT`` do not keep its successor off its port."""
    proto, _, rest = endpoint.partition("/")
    host, _, port_text = rest.rpartition(":")
    if proto not in ("tcp", "tls") or not port_text.isdigit():
        return endpoint  # only a TCP endpoint can be probed; others are used as given
    port = int(port_text)
    for candidate in range(port, port + tries):
        with socket.socket(socket.AF_INET6 if ":" in host.strip("[]") else socket.AF_INET) as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                s.bind((host.strip("[]"), candidate))
            except OSError:
                continue
        return f"{proto}/{host}:{candidate}"
    raise BusConfigError(f"no free port from {endpoint} to port {port + tries - 1}")
