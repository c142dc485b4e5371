"""A console's side of the central role on the bus: presence, the role's tokens, the central's
state for the standbys, the LTMs' status and the plans sent to them.

- ``uavc/<fleet>/console/<console>/alive``: liveliness of every console of the fleet, the
  one presence token a console has (its session declares it: ``drone.bus.console``); the
  consoles it names take part in the election;
- ``uavc/<fleet>/central/alive`` and ``…/alive/<console>``: liveliness of the central;
- ``uavc/<fleet>/central/missions``: the JSON of ``GET /api/v1/patrol``, from the central;
- ``uavc/<fleet>/central/replica``: the CTM's state (``server.fleet.replica``), from the central;
- ``uavc/<fleet>/<drone>/ltm``: each vehicle's LTM status;
- ``uavc/<fleet>/<drone>/plan``: plans, as queries the vehicle answers.

Who holds the role is decided by ``server.fleet.election`` from :meth:`CentralBus.view`; this
class only declares the role's tokens and watches. While the console's session is off its
router (the router restarting for new vehicle keys: ``drone.bus.console``), and for
:data:`RELINK_SETTLE_S` after, the view is the last one seen on the bus: a console that
briefly sees nobody must not claim the role. Payloads are bytes: the console decodes
them. Zenoh calls back in its own threads; replicas and statuses are handed to ``loop``.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import threading
import time
from collections.abc import Callable

import zenoh

from drone.bus import keys
from drone.bus.errors import BusError
from drone.bus.plans import all_ltm, central_holder, plan_key

log = logging.getLogger(__name__)

REPLICA = "replica"
# The liveliness a session lost with its router comes back within milliseconds of it linking
# again (the history of every token on the bus); the election's own settling time.
RELINK_SETTLE_S = 0.5


def replica_key(fleet: str) -> str:
    return f"{keys.ROOT}/{keys.segment(fleet)}/{keys.CENTRAL}/{REPLICA}"


class CentralBus:
    """One console's central role on the bus, and the consoles it sees there.

    Args:
        session: the console's Zenoh session (a client of its embedded router).
        fleet: the fleet's name.
        console: this console's name (one key segment, unique in the fleet).
        loop: the event loop the callbacks run on.
        on_replica: the central's state (bytes), on ``loop``; standbys keep it.
        on_ltm: an LTM status (drone name, bytes), on ``loop``.
    """

    def __init__(
        self,
        session: zenoh.Session,
        fleet: str,
        console: str,
        loop: asyncio.AbstractEventLoop,
        *,
        on_replica: Callable[[bytes], None],
        on_ltm: Callable[[str, bytes], None],
    ) -> None:
        self.session = session
        self.fleet = keys.segment(fleet)
        self.console = keys.segment(console)
        self.loop = loop
        self.on_replica = on_replica
        self.on_ltm = on_ltm
        self._lock = threading.Lock()
        self._consoles: set[str] = set()
        self._holders: set[str] = set()
        self._decls: list[object] = []
        self._role: list[zenoh.LivelinessToken] = []
        self._missions: zenoh.Publisher | None = None
        self._replica: zenoh.Publisher | None = None
        self.clock = time.monotonic
        self._last_view: tuple[set[str], set[str]] | None = None  # seen while linked, settled
        # When the session last linked to its router again (None: off it now). Linked from the
        # start counts as settled: only a relink waits, never a console's first looks.
        self._linked_since: float | None = -math.inf

    def start(self) -> None:
        lv = self.session.liveliness()
        self._decls.append(
            lv.declare_subscriber(
                keys.all_consoles_alive(self.fleet), self._on_console, history=True
            )
        )
        self._decls.append(
            lv.declare_subscriber(
                f"{keys.central_alive(self.fleet)}/*", self._on_holder, history=True
            )
        )
        self._decls.append(
            self.session.declare_subscriber(replica_key(self.fleet), self._on_replica)
        )
        self._decls.append(self.session.declare_subscriber(all_ltm(self.fleet), self._on_ltm))
        self._missions = self.session.declare_publisher(keys.central_missions(self.fleet))
        self._replica = self.session.declare_publisher(replica_key(self.fleet))

    def view(self) -> tuple[set[str], set[str]]:
        """(consoles alive, consoles holding the central role), as this console sees them;
        while its session is off its router and :data:`RELINK_SETTLE_S` after, the last view
        seen on it (see the module docstring)."""
        with self._lock:
            seen = set(self._consoles) | {self.console}, set(self._holders)
        now = self.clock()
        if not self.session.info.routers_zid():  # off its router (a router's own: never set)
            self._linked_since = None
            return self._frozen(seen)
        if self._linked_since is None:
            self._linked_since = now
        if self._last_view is not None and now - self._linked_since < RELINK_SETTLE_S:
            return self._frozen(seen)
        self._last_view = (set(seen[0]), set(seen[1]))
        return seen

    def _frozen(self, seen: tuple[set[str], set[str]]) -> tuple[set[str], set[str]]:
        if self._last_view is None:
            return seen
        return set(self._last_view[0]), set(self._last_view[1])

    @property
    def holding(self) -> bool:
        return bool(self._role)

    def claim(self) -> None:
        """Declare the central role's tokens (``…/central/alive`` and ``…/alive/<console>``)."""
        if self._role:
            return
        lv = self.session.liveliness()
        self._role = [
            lv.declare_token(central_holder(self.fleet, self.console)),
            lv.declare_token(keys.central_alive(self.fleet)),
        ]

    def release(self) -> None:
        for token in self._role:
            token.undeclare()  # type: ignore[no-untyped-call]
        self._role = []

    def publish_missions(self, payload: bytes) -> None:
        if self._missions is not None:
            self._missions.put(payload)

    def publish_replica(self, payload: bytes) -> None:
        if self._replica is not None:
            self._replica.put(payload)

    async def send_plan(self, drone: str, payload: bytes, timeout_s: float) -> bytes:
        """Query ``drone``'s plan key; its reply's payload.

        Raises:
            BusError: no reply in ``timeout_s`` (no such vehicle, or it did not answer), or an
                error reply.
        """
        key = plan_key(self.fleet, drone)

        def ask() -> bytes:
            replies = self.session.get(key, payload=payload, timeout=timeout_s)
            for reply in replies:
                if reply.ok is not None:
                    return bytes(reply.ok.payload.to_bytes())
                err = reply.err
                raise BusError(
                    f"{drone} answered an error: {err.payload.to_string() if err else '?'}"
                )
            raise BusError(f"{drone} did not answer on the bus in {timeout_s:g} s")

        return await asyncio.to_thread(ask)

    def close(self) -> None:
        self.release()
        for d in self._decls:
            undeclare = getattr(d, "undeclare", None)
            if callable(undeclare):
                undeclare()
        self._decls.clear()
        for pub in (self._missions, self._replica):
            if pub is not None:
                pub.undeclare()  # type: ignore[no-untyped-call]
        self._missions = self._replica = None

    # ------------------------------------------------------------------ Zenoh's threads
    def _on_console(self, sample: zenoh.Sample) -> None:
        name = keys.console_of(str(sample.key_expr))
        if name is not None:
            self._track(self._consoles, name, sample)

    def _on_holder(self, sample: zenoh.Sample) -> None:
        self._track(self._holders, str(sample.key_expr).rsplit("/", 1)[1], sample)

    def _track(self, names: set[str], name: str, sample: zenoh.Sample) -> None:
        with self._lock:
            if sample.kind == zenoh.SampleKind.PUT:
                names.add(name)
            else:
                names.discard(name)

    def _on_replica(self, sample: zenoh.Sample) -> None:
        data = sample.payload.to_bytes()
        self._hand(lambda: self.on_replica(data))

    def _on_ltm(self, sample: zenoh.Sample) -> None:
        drone = keys.drone_of(str(sample.key_expr))
        if drone is None:
            return
        data = sample.payload.to_bytes()
        self._hand(lambda: self.on_ltm(drone, data))

    def _hand(self, fn: Callable[[], None]) -> None:
        with contextlib.suppress(RuntimeError):  # the loop has closed: the console stops
            self.loop.call_soon_threadsafe(fn)
