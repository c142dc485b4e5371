"""A vehicle's side of the bus: its liveliness and its telemetry, under its own name only.

A vehicle may start before its router (a companion computer booting before the console): it
then dials the router on a thread of its own until it answers (:meth:`VehicleBus.join_later`).
Zenoh's own connect retry is not used for this: a client's ``zenoh.open`` with
``connect.timeout_ms: -1`` blocks until the router answers and cannot be called off, so a
vehicle stopped while waiting could not close it.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterable

import zenoh

from drone.bus import keys
from drone.bus.config import client_config
from drone.bus.errors import BusError
from drone.bus.payloads import Telemetry, encode
from drone.bus.session import open_session
from drone.vehicle import VehicleSnapshot

log = logging.getLogger(__name__)

JOIN_RETRY_S = 1.0  # how often a vehicle dials a router that is not up, as a console's joiner


def telemetry_of(name: str, snapshot: VehicleSnapshot, stamp: float) -> Telemetry:
    return Telemetry(
        drone=name,
        stamp=stamp,
        x=snapshot.x,
        y=snapshot.y,
        z=snapshot.z,
        yaw_deg=snapshot.yaw_deg,
        battery_pct=snapshot.battery_pct,
        state=snapshot.ctrl_state,
        link_ok=snapshot.link_ok,
        flying=snapshot.flying,
    )


class VehicleBus:
    """One vehicle on the bus: a liveliness token and a telemetry publisher that drops rather
    than queues under congestion (the next sample supersedes a late one)."""

    def __init__(
        self,
        connect: Iterable[str],
        user: str,
        password: str,
        fleet: str,
        name: str,
        ca: str | None = None,
    ) -> None:
        """``ca``: the CA file a ``tls/`` router's certificate must be signed by."""
        self.fleet = keys.segment(fleet)
        self.name = keys.segment(name)
        self._config = client_config(connect=list(connect), user=user, password=password, ca=ca)
        self.session: zenoh.Session | None = None
        self._publisher: zenoh.Publisher | None = None
        self._token: zenoh.LivelinessToken | None = None
        self.sent = 0
        self.tries = 0  # dials of a router that was not up, since :meth:`join_later`
        self._lock = threading.Lock()
        self._closed = threading.Event()
        self._dialler: threading.Thread | None = None

    def start(self) -> None:
        """Join the bus (raises BusConfigError when the router cannot be reached or refuses)."""
        self._declare(open_session(self._config))

    def _declare(self, session: zenoh.Session) -> None:
        self.session = session
        self._publisher = session.declare_publisher(
            keys.telemetry(self.fleet, self.name),
            congestion_control=zenoh.CongestionControl.DROP,
        )
        self._token = session.liveliness().declare_token(keys.alive(self.fleet, self.name))

    def join_later(
        self,
        on_joined: Callable[[], object],
        on_refused: Callable[[str], object] = lambda why: None,
        retry_s: float = JOIN_RETRY_S,
    ) -> None:
        """Dial the router every ``retry_s`` on a thread of its own until it answers, then
        join and call ``on_joined()`` (on that thread); ``on_refused(why)`` when a dial
        fails for a reason other than the one before. :meth:`close` stops the dialling."""

        def dial() -> None:
            said = ""
            while not self._closed.wait(retry_s):
                try:
                    session = open_session(self._config)
                except BusError as exc:
                    self.tries += 1
                    if str(exc) != said:
                        said = str(exc)
                        on_refused(said)
                    continue
                with self._lock:
                    if self._closed.is_set():
                        session.close()  # type: ignore[no-untyped-call]
                        return
                    self._declare(session)
                on_joined()
                return

        self._dialler = threading.Thread(target=dial, name=f"bus-dial:{self.name}", daemon=True)
        self._dialler.start()

    def publish(self, snapshot: VehicleSnapshot, stamp: float | None = None) -> None:
        if self._publisher is None:
            return
        message = telemetry_of(self.name, snapshot, time.time() if stamp is None else stamp)
        self._publisher.put(encode(message))
        self.sent += 1

    def close(self) -> None:
        with self._lock:
            self._closed.set()
            self._publisher = None
            if self._token is not None:
                self._token.undeclare()  # type: ignore[no-untyped-call]
                self._token = None
            if self.session is not None:
                self.session.close()  # type: ignore[no-untyped-call]
                self.session = None
