"""A vehicle's fleet end on the bus: the central's plans as queries it answers, its LTM status as
publications, and whether any console holds the central role.

- ``uavc/<fleet>/<drone>/plan``: a flight plan (``FlightPlan`` JSON) as a query; the reply is
  ``{accepted, reason, plan_id}``;
- ``uavc/<fleet>/<drone>/ltm``: the LTM's status (``LtmStatus`` JSON), 1 Hz;
- ``uavc/<fleet>/central/alive`` (and ``…/<console>``): liveliness of the central.

The payloads are bytes here (this package imports nothing from ``server``); the vehicle's LTM
decodes them. Zenoh calls back in its own threads: a plan is handed to the vehicle's event loop
and answered from there, so the LTM is only ever touched by that loop.
"""

from __future__ import annotations

import asyncio
import json
import logging
import threading
from collections.abc import Awaitable, Callable
from concurrent.futures import Future

import zenoh

from drone.bus import keys

log = logging.getLogger(__name__)

PLAN_TOPIC = "plan"
LTM_TOPIC = "ltm"
PLAN_REPLY_TIMEOUT_S = 5.0  # the vehicle answers from its loop; a stalled loop answers nothing


def plan_key(fleet: str, drone: str) -> str:
    return keys.drone_key(fleet, drone, PLAN_TOPIC)


def ltm_key(fleet: str, drone: str) -> str:
    return keys.drone_key(fleet, drone, LTM_TOPIC)


def all_ltm(fleet: str) -> str:
    return f"{keys.ROOT}/{keys.segment(fleet)}/*/{LTM_TOPIC}"


def central_holder(fleet: str, console: str) -> str:
    """The named token of the console holding the central role."""
    return f"{keys.central_alive(fleet)}/{keys.segment(console)}"


def central_any(fleet: str) -> str:
    """Both central tokens (``…/central/alive`` and ``…/central/alive/<console>``)."""
    return f"{keys.central_alive(fleet)}/**"


def refusal(reason: str) -> bytes:
    """A plan reply that refuses, with the reason (the vehicle could not judge the plan)."""
    return json.dumps({"accepted": False, "reason": reason, "plan_id": 0}).encode()


class VehiclePlans:
    """One vehicle's plans, LTM status and view of the central role on the bus.

    Args:
        session: the vehicle's Zenoh session (``VehicleBus.session``).
        fleet, name: its keys' segments.
        loop: the event loop that owns the LTM.
        on_plan: the plan's payload → the reply's payload, run on ``loop``.
    """

    def __init__(
        self,
        session: zenoh.Session,
        fleet: str,
        name: str,
        loop: asyncio.AbstractEventLoop,
        on_plan: Callable[[bytes], Awaitable[bytes]],
    ) -> None:
        self.session = session
        self.fleet = keys.segment(fleet)
        self.name = keys.segment(name)
        self.loop = loop
        self.on_plan = on_plan
        self._lock = threading.Lock()
        self._central: set[str] = set()  # keys of the central tokens alive
        self._decls: list[object] = []
        self._publisher: zenoh.Publisher | None = None
        self.plans = 0  # plan queries answered

    def start(self) -> None:
        key = plan_key(self.fleet, self.name)
        self._decls.append(self.session.declare_queryable(key, self._on_query))
        self._publisher = self.session.declare_publisher(ltm_key(self.fleet, self.name))
        self._decls.append(
            self.session.liveliness().declare_subscriber(
                central_any(self.fleet), self._on_central, history=True
            )
        )

    @property
    def central_alive(self) -> bool:
        """Some console holds the central role (its token is on the bus)."""
        with self._lock:
            return bool(self._central)

    @property
    def central_name(self) -> str | None:
        """The console holding the role, when its named token is seen."""
        with self._lock:
            named = sorted(k.rsplit("/", 1)[1] for k in self._central if k.count("/") >= 4)
        return named[0] if named else None

    def publish_status(self, payload: bytes) -> None:
        if self._publisher is not None:
            self._publisher.put(payload)

    def close(self) -> None:
        for d in self._decls:
            undeclare = getattr(d, "undeclare", None)
            if callable(undeclare):
                undeclare()
        self._decls.clear()
        if self._publisher is not None:
            self._publisher.undeclare()  # type: ignore[no-untyped-call]
            self._publisher = None

    # ------------------------------------------------------------------ Zenoh's threads
    def _on_central(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        with self._lock:
            if sample.kind == zenoh.SampleKind.PUT:
                self._central.add(key)
            else:
                self._central.discard(key)

    def _on_query(self, query: zenoh.Query) -> None:
        payload = query.payload.to_bytes() if query.payload is not None else b""
        key = plan_key(self.fleet, self.name)
        try:
            future = asyncio.run_coroutine_threadsafe(_call(self.on_plan, payload), self.loop)
        except RuntimeError:  # the loop has stopped: the vehicle is shutting down
            query.reply(key, refusal("the vehicle is stopping"))
            query.drop()  # type: ignore[no-untyped-call]
            return

        def answer(done: Future[bytes]) -> None:
            try:
                out = done.result()
            except Exception as exc:  # the handler's bug must still answer the central
                log.exception("%s: plan handler failed", self.name)
                out = refusal(f"the vehicle failed to judge the plan: {exc}")
            query.reply(key, out)
            query.drop()  # type: ignore[no-untyped-call]
            self.plans += 1

        future.add_done_callback(answer)


async def _call(fn: Callable[[bytes], Awaitable[bytes]], payload: bytes) -> bytes:
    return await fn(payload)
