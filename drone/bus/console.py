"""A console's side of the bus: the embedded router, the client files it hands out, and what it
hears (which vehicles are alive, their latest telemetry)."""

from __future__ import annotations

import json
import logging
import threading
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

import zenoh

from drone.bus import keys
from drone.bus.config import (
    CONSOLE_USER,
    OBSERVER_USER,
    PILOT_USER,
    BusTLS,
    access_control,
    as_tls,
    client_config,
    router_config,
    router_id,
    vehicle_user,
)
from drone.bus.credentials import Credentials, write_private
from drone.bus.errors import PayloadError
from drone.bus.payloads import Telemetry, decode_telemetry
from drone.bus.session import DEFAULT_LISTEN, free_listen_endpoint, open_session, router_ids

log = logging.getLogger(__name__)

CLIENT_FILE = "client.json5"  # observer: watch only
PILOT_FILE = "pilot.json5"


@dataclass(frozen=True)
class VehicleCredential:
    """What a vehicle process needs to join this console's bus."""

    connect: tuple[str, ...]
    user: str
    password: str
    ca: str | None = None  # the CA file the router's certificate is verified with (tls/)


class ConsoleBus:
    """The console's embedded Zenoh router.

    Args:
        directory: ``<data dir>/bus`` (credentials and the client files, 0600).
        fleet: the fleet's name, the second key segment.
        vehicles: the vehicle names that get a credential (the ACL is fixed at start).
        name: the console's name (one key segment, unique in the fleet): its router's Zenoh id
            derives from it (:func:`drone.bus.config.router_id`).
        vehicle_passwords: name → password for vehicles whose password is given (the
            console's vehicle keys); they are on the bus too.
        listen: endpoints to listen on; empty: ``tcp/127.0.0.1:7447`` or the next free port.
        connect: other routers to join (consoles on other hosts, ``zenohd``).
        tls: the router's certificate, key and CA: it then listens on ``tls/`` endpoints only
            (a ``tcp/`` one given is served as ``tls/`` on the same address) and the client
            files it writes carry the CA. A CA alone: it listens as given and verifies the
            ``tls/`` routers it joins with that CA.
    """

    def __init__(
        self,
        directory: Path,
        fleet: str,
        vehicles: Iterable[str],
        *,
        name: str,
        listen: Iterable[str] = (),
        connect: Iterable[str] = (),
        vehicle_passwords: Mapping[str, str] | None = None,
        tls: BusTLS | None = None,
    ) -> None:
        self.directory = directory
        self.tls = tls
        self.fleet = keys.segment(fleet)
        self.vehicle_passwords = dict(vehicle_passwords or {})
        self.vehicle_names = sorted(
            {keys.segment(v) for v in vehicles} | set(self.vehicle_passwords)
        )
        wrap = as_tls if tls is not None and tls.cert is not None else str
        self.listen = [wrap(e) for e in listen] or [free_listen_endpoint(wrap(DEFAULT_LISTEN))]
        self.connect = list(connect)
        self.name = keys.segment(name)  # the console's name: its router's id (router_id)
        self.credentials: Credentials | None = None
        self.session: zenoh.Session | None = None
        self._presence: zenoh.LivelinessToken | None = None
        self._lock = threading.Lock()
        self._alive: set[str] = set()
        self._latest: dict[str, Telemetry] = {}
        self.refused = 0  # payloads that did not decode (logged, never shown)
        self._subs: list[object] = []

    def start(self) -> None:
        """Open the router and write ``client.json5`` / ``pilot.json5``.

        Raises:
            BusConfigError: an endpoint cannot be listened on or the credentials are unusable.
        """
        creds = Credentials.load_or_create(
            self.directory, self.vehicle_names, self.vehicle_passwords
        )
        self.credentials = creds
        # the routers we join, known by their ids (drone.bus.session.router_ids)
        ca = self.tls.ca if self.tls is not None else None
        peers = router_ids(self.connect, CONSOLE_USER, creds.password(CONSOLE_USER), ca=ca)
        acl = access_control(self.fleet, creds.vehicles(), peers)
        self.session = open_session(
            router_config(
                listen=self.listen,
                connect=self.connect,
                password=creds.password(CONSOLE_USER),
                dictionary_file=str(creds.path),
                acl=acl,
                # the same id across restarts: the routers that joined it name it in their ACL
                zid=router_id(self.fleet, self.name),
                tls=self.tls,
            )
        )
        self._write_client(CLIENT_FILE, OBSERVER_USER)
        self._write_client(PILOT_FILE, PILOT_USER)
        liveliness = self.session.liveliness()
        # this console on the bus (any role), as long as its router: the vehicles' watch of
        # their consoles and the central's election both go by this one token
        self._presence = liveliness.declare_token(keys.console_alive(self.fleet, self.name))
        self._subs.append(
            liveliness.declare_subscriber(keys.all_alive(self.fleet), self._on_alive, history=True)
        )
        self._subs.append(
            self.session.declare_subscriber(keys.all_telemetry(self.fleet), self._on_telemetry)
        )

    @property
    def client_endpoints(self) -> list[str]:
        """Where a client dials this router (a wildcard listen address as loopback)."""
        return [_reachable(e) for e in self.listen]

    @property
    def client_file(self) -> Path:
        return self.directory / CLIENT_FILE

    def vehicle_credential(self, name: str) -> VehicleCredential:
        assert self.credentials is not None, "start() first"
        return VehicleCredential(
            tuple(self.client_endpoints),
            vehicle_user(name),
            self.credentials.password(vehicle_user(name)),
            self.tls.ca if self.tls is not None else None,
        )

    def alive(self) -> list[str]:
        with self._lock:
            return sorted(self._alive)

    def latest(self, drone: str) -> Telemetry | None:
        with self._lock:
            return self._latest.get(drone)

    def close(self) -> None:
        if self._presence is not None:
            self._presence.undeclare()  # type: ignore[no-untyped-call]
            self._presence = None
        if self.session is not None:
            self.session.close()  # type: ignore[no-untyped-call]
            self.session = None

    def _write_client(self, name: str, user: str) -> None:
        assert self.credentials is not None
        config = client_config(
            connect=self.client_endpoints,
            user=user,
            password=self.credentials.password(user),
            ca=self.tls.ca if self.tls is not None else None,
        )
        write_private(self.directory / name, json.dumps(config, indent=2) + "\n")

    def _on_alive(self, sample: zenoh.Sample) -> None:
        drone = keys.drone_of(str(sample.key_expr))
        if drone is None:
            return
        with self._lock:
            if sample.kind == zenoh.SampleKind.PUT:
                self._alive.add(drone)
            else:
                self._alive.discard(drone)
                self._latest.pop(drone, None)
        log.info("bus: %s %s", drone, "alive" if sample.kind == zenoh.SampleKind.PUT else "gone")

    def _on_telemetry(self, sample: zenoh.Sample) -> None:
        drone = keys.drone_of(str(sample.key_expr))
        try:
            telemetry = decode_telemetry(sample.payload.to_bytes())
        except PayloadError as exc:
            self.refused += 1
            log.warning("bus: telemetry on %s refused: %s", sample.key_expr, exc)
            return
        if drone is None or telemetry.drone != drone:
            self.refused += 1
            log.warning("bus: telemetry on %s names drone %r", sample.key_expr, telemetry.drone)
            return
        with self._lock:
            self._latest[drone] = telemetry


def _reachable(endpoint: str) -> str:
    """A listen endpoint as a client dials it: a wildcard address becomes loopback."""
    for wildcard in ("0.0.0.0", "[::]"):
        endpoint = endpoint.replace(f"/{wildcard}:", "/127.0.0.1:")
    return endpoint
