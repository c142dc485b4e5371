"""A console's side of the bus: the embedded router, the client files it hands out, and what it
hears (which vehicles are alive, their latest telemetry).

The router and the console's own session are two Zenoh sessions in the console's process: the
router (mode ``router``: authentication, access control, the listeners) and a client of it as
``console`` (:attr:`ConsoleBus.session`), on which the console declares everything it does on
the bus. Zenoh reads a router's access control and password dictionary when it opens, so a
change of the vehicles' keys restarts the router alone (:meth:`ConsoleBus.rekey`) on the same
endpoints and Zenoh id; every client, the console's session among them, dials it again and
declares again what it had declared (Zenoh keeps a session's declarations across a reconnect).
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

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
    joiner_config,
    router_config,
    router_id,
    vehicle_user,
    vehicles_among,
)
from drone.bus.credentials import Credentials, write_private
from drone.bus.errors import BusConfigError, PayloadError
from drone.bus.payloads import Telemetry, decode_telemetry
from drone.bus.session import DEFAULT_LISTEN, free_listen_endpoint, open_session

log = logging.getLogger(__name__)

CLIENT_FILE = "client.json5"  # observer: watch only
LISTEN_DIR = "listen"  # <bus dir>/listen/<console name>: where its router listened last
PILOT_FILE = "pilot.json5"
# <bus dir>/keyed.txt: the vehicles whose bus password was a vehicle key of this console's, a
# name a line: one that has no key at the next start was revoked meanwhile, and is dropped
KEYED_FILE = "keyed.txt"
JOIN_WATCH_S = 0.5  # how often the joiners' links are looked at (the log, /health)
JOIN_GRACE_S = 2.0  # a router not joined this long after the start is said to be not up
# A restarted router's port may still be held a moment by the one closed (its listener's task
# ends on Zenoh's runtime): tried again this often, this many times.
REOPEN_TRIES = 20
REOPEN_PAUSE_S = 0.1
RELINK_WAIT_S = 5.0  # how long a rekey waits for the console's session to be back on the router
RELINK_POLL_S = 0.005


@dataclass(frozen=True)
class Rekeyed:
    """A restart of the router for a new set of vehicle keys (:meth:`ConsoleBus.rekey`)."""

    added: tuple[str, ...]  # vehicles that may join now
    removed: tuple[str, ...]  # vehicles whose key was revoked: refused from now on
    changed: tuple[str, ...]  # vehicles whose key was replaced (rotated)
    down_s: float  # from the old router's close to the console's session back on the new one

    def said(self) -> str:
        """The restart, in a line for the log."""
        parts = [
            f"{what} {', '.join(names)}"
            for what, names in (
                ("may join:", self.added),
                ("refused from now on:", self.removed),
                ("new key:", self.changed),
            )
            if names
        ]
        return (
            f"bus: vehicle keys changed ({'; '.join(parts) or 'nothing'}); router restarted "
            f"with them, the console back on it in {self.down_s * 1000:.0f} ms"
        )


@dataclass(frozen=True)
class Join:
    """A router this console joins (``--bus-connect``) and whether the link to it is up."""

    endpoint: str
    joined: bool
    since: float  # Unix time it came up (joined) or went or was first dialled (not)
    state: Literal["dialling", "not up", "joined", "went"] = "dialling"

    def said(self) -> str:
        """The change, in a line for the log."""
        return {
            "dialling": f"bus: dialling the router at {self.endpoint}",
            "not up": f"bus: the router at {self.endpoint} is not up; joining it when it is",
            "joined": f"bus: joined the router at {self.endpoint}",
            "went": f"bus: the router at {self.endpoint} went; joining it again when it is back",
        }[self.state]


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
        vehicles: the vehicle names that get a credential (:meth:`rekey` changes the
            others, those of ``vehicle_passwords``).
        name: the console's name (one key segment, unique in the fleet): its router's Zenoh id
            derives from it (:func:`drone.bus.config.router_id`).
        vehicle_passwords: name → password for vehicles whose password is given (the
            console's vehicle keys); they are on the bus too.
        listen: endpoints to listen on; empty: where this console's router listened last
            (``<directory>/listen/<name>``, so the vehicles of a console that crashed find
            the one restarted in its place), else ``tcp/127.0.0.1:7447``; the next free port
            when that one is taken.
        connect: other routers to join (consoles on other hosts, ``zenohd``), each through a
            joiner of its own (:func:`drone.bus.config.joiner_config`): dialled until it
            answers, so either console may start first; :meth:`joins` says which are up.
        tls: the router's certificate, key and CA: it then listens on ``tls/`` endpoints only
            (a ``tcp/`` one given is served as ``tls/`` on the same address) and the client
            files it writes carry the CA. A CA alone: it listens as given and verifies the
            ``tls/`` routers it joins with that CA.
        shared_credentials: another console's ``credentials.txt``, whose users and passwords
            this console's bus takes (:meth:`Credentials.load_or_create`'s ``shared``).
        on_join: told each change of a join (:class:`Join`), on a thread of its own: a
            router not up at the start, joined, gone.
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
        shared_credentials: Path | None = None,
        on_join: Callable[[Join], object] | None = None,
    ) -> None:
        self.directory = directory
        self.tls = tls
        self.shared_credentials = shared_credentials
        self.on_join = on_join
        self.fleet = keys.segment(fleet)
        self.vehicle_passwords = dict(vehicle_passwords or {})
        self._own_vehicles = {keys.segment(v) for v in vehicles}
        wrap = as_tls if tls is not None and tls.cert is not None else str
        self.name = keys.segment(name)
        self.listen = [wrap(e) for e in listen] or [
            free_listen_endpoint(self._listened_last(wrap(DEFAULT_LISTEN)))
        ]
        self.connect = list(connect)
        self.zid = router_id(self.fleet, self.name)  # its router's Zenoh id, from its name
        self.credentials: Credentials | None = None
        self.router: zenoh.Session | None = None  # the router: listeners, auth, ACL
        self.session: zenoh.Session | None = None  # the console's own: a client of the router
        self._router_lock = threading.Lock()  # a rekey's restart against close()
        self.rekeys: list[Rekeyed] = []
        self._presence: zenoh.LivelinessToken | None = None
        self._lock = threading.Lock()
        self._alive: set[str] = set()
        self._latest: dict[str, Telemetry] = {}
        self.refused = 0  # payloads that did not decode (logged, never shown)
        self._subs: list[object] = []
        self._joiners: list[tuple[str, zenoh.Session]] = []
        self._joins: dict[str, Join] = {}
        self._stop = threading.Event()
        self._watch: threading.Thread | None = None

    @property
    def vehicle_names(self) -> list[str]:
        """The vehicles with a credential on this bus: its own and the keyed ones."""
        return sorted(self._own_vehicles | set(self.vehicle_passwords))

    def start(self) -> None:
        """Open the router and the console's session, and write ``client.json5`` /
        ``pilot.json5``.

        Raises:
            BusConfigError: an endpoint cannot be listened on or the credentials are unusable.
        """
        creds = Credentials.load_or_create(
            self.directory,
            self.vehicle_names,
            self.vehicle_passwords,
            self.shared_credentials,
            revoked=self._keyed_before() - set(self.vehicle_passwords),
        )
        self._write_keyed()
        self.credentials = creds
        self.router = self._open_router(creds)
        self.session = open_session(
            client_config(
                connect=self.client_endpoints,
                user=CONSOLE_USER,
                password=creds.password(CONSOLE_USER),
                ca=self.tls.ca if self.tls is not None else None,
            )
        )
        self._write_client(CLIENT_FILE, OBSERVER_USER)
        self._write_client(PILOT_FILE, PILOT_USER)
        (self.directory / LISTEN_DIR).mkdir(mode=0o700, exist_ok=True)
        write_private(self._listen_file, "\n".join(self.listen) + "\n")
        liveliness = self.session.liveliness()
        # this console on the bus (any role), as long as its process: the vehicles' watch of
        # their consoles and the central's election both go by this one token
        self._presence = liveliness.declare_token(keys.console_alive(self.fleet, self.name))
        self._subs.append(
            liveliness.declare_subscriber(keys.all_alive(self.fleet), self._on_alive, history=True)
        )
        self._subs.append(
            self.session.declare_subscriber(keys.all_telemetry(self.fleet), self._on_telemetry)
        )
        self._join(creds.password(CONSOLE_USER))

    def _keyed_before(self) -> set[str]:
        """The vehicles that had a key when this bus's dictionary was last written."""
        try:
            return set((self.directory / KEYED_FILE).read_text().split())
        except OSError:
            return set()

    def _write_keyed(self) -> None:
        names = "".join(f"{n}\n" for n in sorted(self.vehicle_passwords))
        write_private(self.directory / KEYED_FILE, names)

    def _open_router(self, creds: Credentials) -> zenoh.Session:
        return open_session(
            router_config(
                listen=self.listen,
                connect=[],  # others' routers are joined through the joiners
                password=creds.password(CONSOLE_USER),
                dictionary_file=str(creds.path),
                acl=access_control(self.fleet, creds.vehicles()),
                zid=self.zid,  # the same across restarts (router_id)
                tls=self.tls,
            )
        )

    def rekey(
        self, vehicle_passwords: Mapping[str, str], clock: Callable[[], float] = time.monotonic
    ) -> Rekeyed | None:
        """Let exactly these keyed vehicles (name → key) on the bus, besides those this console
        was started for: when that changes who may join (or the router is down after a
        failed restart), restart the router with the new dictionary and access control, on the
        same endpoints. Blocks until the console's session is back on it (tens of milliseconds;
        call it off the event loop). None: nothing changed, the router left as it is.

        A vehicle whose key was revoked or replaced is cut off (its link was authenticated by
        the old router) and refused when it dials again; every other client is back within
        :data:`~drone.bus.config.REJOIN_RETRY_MS` of the new router listening.

        Raises:
            BusConfigError: the new dictionary cannot be written, or the router could not open
                again (the bus is then down: call again to retry).
        """
        passwords = {keys.segment(n): p for n, p in vehicle_passwords.items()}
        with self._router_lock:
            if self.session is None or self.credentials is None:
                raise BusConfigError("the bus is closed")
            old = self.credentials.users
            creds = Credentials.load_or_create(
                self.directory,
                sorted(self._own_vehicles | set(passwords)),
                passwords,
                self.shared_credentials,
                revoked=set(self.vehicle_passwords) - set(passwords),
            )
            self.vehicle_passwords = passwords
            self._write_keyed()
            if creds.users == old and self.router is not None:
                return None
            started = clock()
            if self.router is not None:
                self.router.close()  # type: ignore[no-untyped-call]
                self.router = None
            self.credentials = creds
            for attempt in range(REOPEN_TRIES):
                try:
                    self.router = self._open_router(creds)
                    break
                except BusConfigError:
                    if attempt == REOPEN_TRIES - 1:
                        raise
                    time.sleep(REOPEN_PAUSE_S)
            session = self.session
        deadline = clock() + RELINK_WAIT_S
        while clock() < deadline:
            try:
                if any(str(z) == self.zid for z in session.info.routers_zid()):
                    break
            except zenoh.ZError:  # closed meanwhile: the console stops
                break
            time.sleep(RELINK_POLL_S)
        done = Rekeyed(
            added=tuple(vehicles_among(set(creds.users) - set(old))),
            removed=tuple(vehicles_among(set(old) - set(creds.users))),
            changed=tuple(
                vehicles_among(u for u in set(old) & set(creds.users) if old[u] != creds.users[u])
            ),
            down_s=clock() - started,
        )
        self.rekeys.append(done)
        del self.rekeys[:-100]
        log.warning("%s", done.said())
        return done

    def _join(self, password: str) -> None:
        """A joiner for each router in ``connect``; a thread that says when each link comes
        up or goes (the log; :meth:`joins`)."""
        if not self.connect:
            return
        assert self.session is not None
        ca = self.tls.ca if self.tls is not None else None
        now = time.time()
        for endpoint in self.connect:
            config = joiner_config(
                router=self.client_endpoints[0], peer=endpoint, password=password, ca=ca
            )
            self._joiners.append((endpoint, open_session(config)))
            self._joins[endpoint] = Join(endpoint, False, now)
        self._look()
        self._watch = threading.Thread(target=self._watching, name="bus-joins", daemon=True)
        self._watch.start()

    def _watching(self) -> None:
        while not self._stop.wait(JOIN_WATCH_S):
            try:
                self._look()
            except zenoh.ZError as exc:  # a session closing under us: the console stops
                log.debug("bus: joins not looked at: %s", exc)

    def _look(self) -> None:
        """Each joiner's link to its router: up when it has a router besides ours."""
        now = time.time()
        for endpoint, joiner in self._joiners:
            up = any(str(z) != self.zid for z in joiner.info.routers_zid())
            with self._lock:
                before = self._joins[endpoint]
                if up and not before.joined:
                    join = Join(endpoint, True, now, "joined")
                elif not up and before.joined:
                    join = Join(endpoint, False, now, "went")
                elif before.state == "dialling" and now - before.since >= JOIN_GRACE_S:
                    join = Join(endpoint, False, before.since, "not up")
                else:
                    continue
                self._joins[endpoint] = join
            self._said(join)

    def _said(self, join: Join) -> None:
        log.warning("%s", join.said())
        if self.on_join is not None:
            self.on_join(join)

    def joins(self) -> list[Join]:
        """The routers this console joins (``connect``), each up or not."""
        with self._lock:
            return [self._joins[e] for e in self.connect if e in self._joins]

    @property
    def _listen_file(self) -> Path:
        return self.directory / LISTEN_DIR / self.name

    def _listened_last(self, default: str) -> str:
        """Where this console's router listened last, when it listened on ``default``'s
        transport and address (another port of them, taken then); else ``default``."""
        try:
            last = self._listen_file.read_text().split()
        except OSError:
            return default
        same = [e for e in last if e.rpartition(":")[0] == default.rpartition(":")[0]]
        return same[0] if same and same[0].rpartition(":")[2].isdigit() else default

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
        self._stop.set()
        if self._watch is not None:
            self._watch.join(timeout=5)
            self._watch = None
        for _endpoint, joiner in self._joiners:
            joiner.close()  # type: ignore[no-untyped-call]
        self._joiners = []
        if self._presence is not None:
            self._presence.undeclare()  # type: ignore[no-untyped-call]
            self._presence = None
        with self._router_lock:
            if self.session is not None:
                self.session.close()  # type: ignore[no-untyped-call]
                self.session = None
            if self.router is not None:
                self.router.close()  # type: ignore[no-untyped-call]
                self.router = None

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
