"""A vehicle's side of the bus: its liveliness and its telemetry, under its own name only."""

from __future__ import annotations

import time
from collections.abc import Iterable

import zenoh

from drone.bus import keys
from drone.bus.config import client_config
from drone.bus.payloads import Telemetry, encode
from drone.bus.session import open_session
from drone.vehicle import VehicleSnapshot


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

    def start(self) -> None:
        """Join the bus (raises BusConfigError when the router cannot be reached or refuses)."""
        self.session = open_session(self._config)
        self._publisher = self.session.declare_publisher(
            keys.telemetry(self.fleet, self.name),
            congestion_control=zenoh.CongestionControl.DROP,
        )
        self._token = self.session.liveliness().declare_token(keys.alive(self.fleet, self.name))

    def publish(self, snapshot: VehicleSnapshot, stamp: float | None = None) -> None:
        if self._publisher is None:
            return
        message = telemetry_of(self.name, snapshot, time.time() if stamp is None else stamp)
        self._publisher.put(encode(message))
        self.sent += 1

    def close(self) -> None:
        if self._token is not None:
            self._token.undeclare()  # type: ignore[no-untyped-call]
            self._token = None
        if self.session is not None:
            self.session.close()  # type: ignore[no-untyped-call]
            self.session = None
