"""No single point of failure: several consoles on one fleet's bus, one of them central.

Each console runs a :class:`CentralRole` beside its fleet service. Through the bus
(:class:`drone.bus.central.CentralBus`) it sees the consoles there (each one's presence token,
which its console session declares) and the holders of the role, and the election
(:mod:`server.fleet.election`) decides which console holds it:

- **central**: its central task manager decides and sends plans to the vehicles' LTMs as queries
  on ``uavc/<fleet>/<drone>/plan`` (over the graph to a drone the bus does not carry); it
  publishes its state (:mod:`server.fleet.replica`) on ``uavc/<fleet>/central/replica`` each
  second and before every plan it sends (so a standby knows a plan before the vehicle does),
  and ``GET /api/v1/patrol``'s JSON on ``uavc/<fleet>/central/missions``.
- **standby**: its CTM holds the central's latest state plus the LTM statuses heard since, and
  decides nothing; its REST doors read that state and refuse changes (409 naming the central).
  When the central's token leaves the bus (its process died: the routers see the link drop),
  the standby claims the role and its CTM decides from where the mission stands.

A vehicle flying a plan keeps flying it while no console holds the role, for the grace
(``central_grace_s``), then flies home (``server.fleet.bus_ltm``).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import socket
import time
from collections import deque
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from fastapi import HTTPException, Request

from drone.bus import keys
from drone.bus.central import CentralBus
from drone.bus.errors import BusError
from server.fleet.election import Action, Election, View
from server.fleet.errors import MessageError
from server.fleet.messages import LtmStatus
from server.fleet.replica import restore, snapshot
from server.graph import GraphError

if TYPE_CHECKING:
    import zenoh

    from server.fleet.service import FleetService

log = logging.getLogger("uav_console.central")

PERIOD_S = 0.1  # the election's look at the bus: a takeover starts within this of a loss
REPLICA_PERIOD_S = 1.0
# LTM statuses a standby keeps per drone to apply again after a replica (replica.restore): an LTM
# reports once a second (LocalTaskManager.period_s) and a replica comes each REPLICA_PERIOD_S, so
# a replica lacks one or two of them at most
HEARD_KEPT = 4
ON_BUS_S = 5.0  # a drone whose LTM status came over the bus this recently gets plans there


def default_console_name(host: str, port: int) -> str:
    """``HOST-PORT`` as one key segment (dots and other characters become ``-``)."""
    raw = f"{socket.gethostname() if host in ('', '0.0.0.0', '::') else host}-{port}"
    name = "".join(c if c.isalnum() or c in "_-" else "-" for c in raw)[:64]
    return keys.segment(name or "console")


class CentralRole:
    """See the module docstring.

    Args:
        service: this console's fleet service (its CTM and CTM node).
        session: the console's Zenoh session.
        fleet: the fleet's name on the bus.
        console: this console's name (unique in the fleet).
        clock: the CTM's clock.
    """

    def __init__(
        self,
        service: FleetService,
        session: zenoh.Session,
        fleet: str,
        console: str,
        *,
        clock: Callable[[], float] = time.monotonic,
        period_s: float = PERIOD_S,
        replica_period_s: float = REPLICA_PERIOD_S,
    ) -> None:
        self.service = service
        self.node = service.node
        self.ctm = service.ctm
        self.session = session
        self.fleet = keys.segment(fleet)
        self.console = keys.segment(console)
        self.clock = clock
        self.period_s = period_s
        self.replica_period_s = replica_period_s
        self.election = Election(self.console, clock())
        self.bus: CentralBus | None = None
        self.on_bus: dict[str, float] = {}  # drone → when its LTM status last came on the bus
        # drone → its latest LTM statuses from the bus and when each came, for replica.restore
        self.heard: dict[str, deque[tuple[LtmStatus, float]]] = {}
        self.replicas_in = 0
        self.refused = 0  # replicas and statuses that did not decode (logged)
        self.claimed_at: float | None = None
        self.lost_holder_at: float | None = None  # when the last holder's token left the bus
        self.takeovers: list[float] = []  # seconds from a holder's loss to this claim
        self.claimed_unix: float | None = None  # Unix time of the last claim (for a log, a test)
        self.lost_holder_unix: float | None = None  # Unix time the last holder's loss was seen
        self._next_replica = 0.0
        self._task: asyncio.Task[None] | None = None

    # ------------------------------------------------------------------ lifecycle
    async def start(self) -> None:
        loop = asyncio.get_running_loop()
        self.bus = CentralBus(
            self.session,
            self.fleet,
            self.console,
            loop,
            on_replica=self._on_replica,
            on_ltm=self._on_ltm,
        )
        self.bus.start()
        self.election = Election(self.console, self.clock())
        self.node.active = lambda: self.election.central
        self.node.send_plan = self._send_plan
        self._task = asyncio.create_task(self._run(), name="central-role")
        log.info("console %s on the fleet %s's bus", self.console, self.fleet)

    async def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
        if self.bus is not None:
            if self.election.resign() is Action.RELEASE:
                self.bus.release()
            self.bus.close()
            self.bus = None

    async def _run(self) -> None:
        while True:
            try:
                self.step(self.clock())
            except Exception:  # one bad look must not end the election
                log.exception("central role: step failed")
            await asyncio.sleep(self.period_s)

    # ------------------------------------------------------------------ the role
    @property
    def central(self) -> bool:
        return self.election.central

    def info(self) -> dict[str, Any]:
        """``GET /api/v1/central``: who holds the role, as this console sees it."""
        consoles, holders = self.bus.view() if self.bus is not None else ({self.console}, set())
        return {
            "console": self.console,
            "fleet": self.fleet,
            "role": "central" if self.central else "standby",
            "central": self.election.holder,
            "consoles": sorted(consoles),
            "holders": sorted(holders),
            "takeovers_s": [round(t, 3) for t in self.takeovers],
            "claimed_unix": self.claimed_unix,
            "lost_holder_unix": self.lost_holder_unix,
            "replicas_in": self.replicas_in,
            "on_bus": sorted(self.on_bus),
        }

    def step(self, now: float) -> None:
        """Look at the bus, act on the election, publish the central's state when due."""
        if self.bus is None:
            return
        consoles, holders = self.bus.view()
        had_holder = self.election.holder
        action = self.election.observe(View.of(consoles, holders), now)
        if had_holder not in (None, self.console) and had_holder not in holders:
            self.lost_holder_at, self.lost_holder_unix = now, time.time()
            log.warning("central role: %s left the bus", had_holder)
        if action is Action.CLAIM:
            self.bus.claim()
            self.claimed_at, self.claimed_unix = now, time.time()
            if self.lost_holder_at is not None:
                self.takeovers.append(now - self.lost_holder_at)
            log.warning(
                "central role: %s holds it%s",
                self.console,
                ""
                if self.lost_holder_at is None
                else f" ({now - self.lost_holder_at:.2f} s after the last central left)",
            )
            self.ctm.claim(now)
            self._next_replica = 0.0
            self.node.poke()
        elif action is Action.RELEASE:
            self.bus.release()
            log.warning(
                "central role: %s keeps it; %s stands by", self.election.holder, self.console
            )
        if self.central and now >= self._next_replica:
            self.publish(now)

    def publish(self, now: float) -> None:
        """The central's state for the standbys, and the patrol's JSON for everyone."""
        if self.bus is None:
            return
        self._next_replica = now + self.replica_period_s
        body = {"console": self.console, "ctm": snapshot(self.ctm, now)}
        self.bus.publish_replica(json.dumps(body, separators=(",", ":")).encode())
        self.bus.publish_missions(json.dumps(self.service.central.status()).encode())

    def standby_of(self) -> str | None:
        """None while this console holds the role (or no bus); else who holds it."""
        if self.central:
            return None
        return self.election.holder or "no console yet"

    # ------------------------------------------------------------------ from the bus
    def _on_replica(self, data: bytes) -> None:
        if self.central:
            return  # ours (a session hears itself), or a rival's before the election settles
        try:
            body = json.loads(data)
            if not isinstance(body, dict) or not isinstance(body.get("console"), str):
                raise MessageError("a replica names its console")
            if body["console"] == self.console:
                return
            heard = [h for kept in self.heard.values() for h in kept]
            restore(self.ctm, body.get("ctm"), self.clock(), heard)
        except (ValueError, MessageError) as exc:
            self.refused += 1
            log.warning("central role: a replica refused: %s", exc)
            return
        self.replicas_in += 1

    def _on_ltm(self, drone: str, data: bytes) -> None:
        now = self.clock()
        try:
            status = LtmStatus.from_dict(json.loads(data))
        except (ValueError, MessageError) as exc:
            self.refused += 1
            log.warning("central role: LTM status on %s refused: %s", drone, exc)
            return
        if status.name != drone:
            self.refused += 1
            log.warning("central role: LTM status on %s names %r", drone, status.name)
            return
        self.on_bus[drone] = now
        kept = self.heard.setdefault(drone, deque(maxlen=HEARD_KEPT))
        if kept and kept[-1][0].seq >= status.seq:
            kept.clear()  # its LTM started again (its statuses count from 1): the old ones go
        kept.append((status, now))
        self.ctm.on_status(status, now)

    # ------------------------------------------------------------------ plans
    async def _send_plan(
        self, drone: str, plan: dict[str, Any], timeout_s: float
    ) -> dict[str, Any]:
        """A plan to ``drone``: over the bus when its LTM is there, else over the graph."""
        now = self.clock()
        if self.central:
            self.publish(now)  # the standbys know the plan before the vehicle does
        if self.bus is None or now - self.on_bus.get(drone, -ON_BUS_S - 1) > ON_BUS_S:
            from server.fleet.node import plan_service

            try:
                return dict(
                    await self.node.graph.call_service(plan_service(drone), plan, timeout=timeout_s)
                )
            except GraphError as exc:
                return {"accepted": False, "reason": f"not delivered: {exc}"}
        try:
            raw = await self.bus.send_plan(drone, json.dumps(plan).encode(), timeout_s)
            answer = json.loads(raw)
        except (BusError, ValueError) as exc:
            return {"accepted": False, "reason": f"not delivered: {exc}"}
        if not isinstance(answer, dict):
            return {"accepted": False, "reason": "not delivered: the reply is not an object"}
        return answer


def standby_guard(role: Callable[[], CentralRole | None]) -> Callable[[Request], None]:
    """A REST dependency: a standby console refuses changes to the fleet (409, naming the
    console that holds the central role); reading is always allowed."""

    def guard(request: Request) -> None:
        current = role()
        if current is None or request.method in ("GET", "HEAD", "OPTIONS"):
            return
        holder = current.standby_of()
        if holder is not None:
            raise HTTPException(
                status_code=409,
                detail=f"this console stands by; {holder} holds the central role: ask it",
            )

    return guard
