"""The in-process graph: typed topics and services, the one bus every door opens onto.

Messages are JSON-compatible dicts shaped like the ROS message of the topic's type (the form
rosbridge puts on the wire), so the rosbridge endpoint forwards them untouched. Internal modules
build them from typed dataclasses (see ``server.msgs``).

Threading: all delivery happens on the asyncio loop bound with :meth:`Graph.bind_loop`.
``publish`` may be called from any thread (the 100 Hz controller, perception workers); off the
loop thread it hands the message over with ``call_soon_threadsafe``. Without a bound loop
(lockstep tests) delivery is synchronous.

Subscribers are either callbacks (must not block) or :class:`QueueSubscription` objects whose
bounded queue drops the oldest message, so a slow consumer never stalls a publisher or others.

A command may be published with ``issued`` (Unix seconds: when the operator gave it,
drone/deadline.py); a callback reads it as :attr:`Graph.issued` while it is being called, so
the part that hands the command to the drone judges its deadline (a queue does not keep it).
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import itertools
import json
import logging
import threading
from collections.abc import Awaitable, Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

Message = dict[str, Any]
Callback = Callable[[Message], None]
# (canonical topic, type, message): sees every message published on the graph (the recorder).
Tap = Callable[[str, str, Message], None]
ServiceHandler = Callable[[Message], Awaitable[Message]]

log = logging.getLogger("uav_console.graph")

INTERNAL = "internal"
DEFAULT_QUEUE_LENGTH = 100


class GraphError(Exception):
    """Base of the graph's errors.

    GraphError
    ├── TypeMismatch      a topic or service used with a type other than its own
    ├── NotFound          no such topic, service or parameter
    └── ServiceError      the provider failed or did not answer in time
        └── ServiceTimeout
    """


class TypeMismatch(GraphError):
    pass


class NotFound(GraphError):
    pass


class ServiceError(GraphError):
    pass


class ServiceTimeout(ServiceError):
    pass


def canonical(name: str) -> str:
    """Return ``name`` with exactly one leading slash (``rosapi/topics`` -> ``/rosapi/topics``)."""
    stripped = name.strip()
    if not stripped:
        raise GraphError("empty name")
    return "/" + stripped.lstrip("/")


@dataclass(eq=False)
class Subscription:
    """A live subscription; call :meth:`close` to end it."""

    graph: Graph
    topic: str
    callback: Callback
    owner: str = INTERNAL

    def close(self) -> None:
        self.graph._remove_subscription(self)


class QueueSubscription(Subscription):
    """A subscription that buffers into a bounded queue (oldest dropped) for async consumers."""

    def __init__(self, graph: Graph, topic: str, maxlen: int, owner: str = INTERNAL) -> None:
        self._queue: collections.deque[Message] = collections.deque(maxlen=max(1, maxlen))
        self._event = asyncio.Event()
        self.dropped = 0
        super().__init__(graph, topic, self._push, owner)

    def _push(self, msg: Message) -> None:
        if len(self._queue) == self._queue.maxlen:
            self.dropped += 1
        self._queue.append(msg)
        self._event.set()

    def pending(self) -> int:
        return len(self._queue)

    def get_nowait(self) -> Message | None:
        return self._queue.popleft() if self._queue else None

    async def get(self) -> Message:
        while not self._queue:
            self._event.clear()
            await self._event.wait()
        return self._queue.popleft()


@dataclass
class _Topic:
    name: str
    type: str
    latch: bool = False
    publishers: set[str] = field(default_factory=set)
    subscriptions: list[Subscription] = field(default_factory=list)
    last: Message | None = None


@dataclass
class _Service:
    name: str
    type: str
    handler: ServiceHandler
    owner: str


class Graph:
    """Topics, services and parameters shared by every part of one server process."""

    def __init__(self) -> None:
        self._topics: dict[str, _Topic] = {}
        self._services: dict[str, _Service] = {}
        self._params: dict[str, Any] = {}
        self._loop: asyncio.AbstractEventLoop | None = None
        self._loop_thread: int | None = None
        self._lock = threading.RLock()
        self._ids = itertools.count(1)
        self._taps: tuple[Tap, ...] = ()
        self._issued: float | None = None

    # -- loop -----------------------------------------------------------------------------
    def bind_loop(self, loop: asyncio.AbstractEventLoop) -> None:
        """Deliver messages on ``loop`` (call from the loop's own thread)."""
        self._loop = loop
        self._loop_thread = threading.get_ident()

    @property
    def loop(self) -> asyncio.AbstractEventLoop | None:
        """The loop messages are delivered on (None until :meth:`bind_loop`)."""
        return self._loop

    def _on_loop_thread(self) -> bool:
        return self._loop is None or threading.get_ident() == self._loop_thread

    # -- topics ---------------------------------------------------------------------------
    def advertise(self, name: str, type: str, *, latch: bool = False, owner: str = INTERNAL) -> str:
        """Declare that ``owner`` publishes ``type`` on ``name``; returns the canonical name.

        Raises:
            TypeMismatch: the topic exists with another type.
        """
        key = canonical(name)
        with self._lock:
            topic = self._topics.get(key)
            if topic is None:
                topic = self._topics[key] = _Topic(key, type, latch)
            elif topic.type != type:
                raise TypeMismatch(f"topic {key} has type {topic.type}, not {type}")
            topic.latch = topic.latch or latch
            topic.publishers.add(owner)
        return key

    def unadvertise(self, name: str, owner: str = INTERNAL) -> None:
        key = canonical(name)
        with self._lock:
            topic = self._topics.get(key)
            if topic is None:
                return
            self._drop_publisher(topic, owner)
            self._forget_if_unused(topic)

    @staticmethod
    def _drop_publisher(topic: _Topic, owner: str) -> None:
        """``owner`` no longer publishes ``topic``; a latched message of a topic nobody
        publishes any more expires with its publisher (a client's latched message must not
        outlive its connection: it would greet every later subscriber)."""
        if owner not in topic.publishers:
            return
        topic.publishers.discard(owner)
        if not topic.publishers:
            topic.last = None
            topic.latch = False

    def _forget_if_unused(self, topic: _Topic) -> None:
        if not topic.publishers and not topic.subscriptions and not topic.latch:
            self._topics.pop(topic.name, None)

    def publish(
        self, name: str, msg: Message, *, type: str | None = None, issued: float | None = None
    ) -> None:
        """Send ``msg`` to every subscriber of ``name``; safe to call from any thread.
        ``issued``: when the operator gave the command (:attr:`issued` to the callbacks).

        Raises:
            NotFound: nobody advertised the topic and no ``type`` was given.
            TypeMismatch: ``type`` differs from the topic's.
        """
        key = canonical(name)
        with self._lock:
            topic = self._topics.get(key)
            if topic is None:
                if type is None:
                    raise NotFound(f"topic {key} is not advertised")
                topic = self._topics[key] = _Topic(key, type)
                topic.publishers.add(INTERNAL)
            elif type is not None and type != topic.type:
                raise TypeMismatch(f"topic {key} has type {topic.type}, not {type}")
            if topic.latch:
                topic.last = msg
            subscriptions = list(topic.subscriptions)
            type_name = topic.type
        for tap in self._taps:
            tap(key, type_name, msg)
        if not subscriptions:
            return
        if self._on_loop_thread():
            self._deliver(subscriptions, msg, issued)
        else:
            assert self._loop is not None
            # RuntimeError: the loop closed while a worker thread was finishing.
            with contextlib.suppress(RuntimeError):
                self._loop.call_soon_threadsafe(self._deliver, subscriptions, msg, issued)

    @property
    def issued(self) -> float | None:
        """Inside a subscriber's callback: the ``issued`` its message was published with
        (None when none was given, and outside a delivery)."""
        return self._issued

    def _deliver(
        self, subscriptions: list[Subscription], msg: Message, issued: float | None = None
    ) -> None:
        # Delivery runs on the loop thread only, so one attribute carries ``issued``; a
        # callback that publishes in turn gets its own and ours back after.
        outer, self._issued = self._issued, issued
        try:
            # One subscriber's bug must not cost the others their message: each
            # callback is isolated, and the failure logged with the topic and the subscriber.
            for sub in subscriptions:
                try:
                    sub.callback(msg)
                except Exception:
                    log.exception(
                        "subscriber %s of %s failed; other subscribers served", sub.owner, sub.topic
                    )
        finally:
            self._issued = outer

    def subscribe(
        self, name: str, callback: Callback, *, type: str | None = None, owner: str = INTERNAL
    ) -> Subscription:
        """Call ``callback(msg)`` for each message on ``name`` (latched message first, if any)."""
        return self._attach(Subscription(self, canonical(name), callback, owner), type)

    def subscribe_queue(
        self,
        name: str,
        *,
        type: str | None = None,
        maxlen: int = DEFAULT_QUEUE_LENGTH,
        owner: str = INTERNAL,
    ) -> QueueSubscription:
        """Subscribe into a bounded queue that drops the oldest message when full."""
        return self._attach(QueueSubscription(self, canonical(name), maxlen, owner), type)  # type: ignore[return-value]

    def _attach(self, sub: Subscription, type: str | None) -> Subscription:
        with self._lock:
            topic = self._topics.get(sub.topic)
            if topic is None:
                if type is None:
                    raise NotFound(f"topic {sub.topic} is unknown and no type was given")
                topic = self._topics[sub.topic] = _Topic(sub.topic, type)
            elif type is not None and type != topic.type:
                raise TypeMismatch(f"topic {sub.topic} has type {topic.type}, not {type}")
            topic.subscriptions.append(sub)
            latched = topic.last
        if latched is not None:
            sub.callback(latched)
        return sub

    def _remove_subscription(self, sub: Subscription) -> None:
        with self._lock:
            topic = self._topics.get(sub.topic)
            if topic is None:
                return
            if sub in topic.subscriptions:
                topic.subscriptions.remove(sub)
            self._forget_if_unused(topic)

    def drop_owner(self, owner: str) -> None:
        """Remove everything ``owner`` (e.g. a closed connection) advertised or subscribed."""
        with self._lock:
            for topic in list(self._topics.values()):
                self._drop_publisher(topic, owner)
                topic.subscriptions = [s for s in topic.subscriptions if s.owner != owner]
                self._forget_if_unused(topic)
            for name in [n for n, s in self._services.items() if s.owner == owner]:
                del self._services[name]

    def add_tap(self, tap: Tap) -> Callable[[], None]:
        """Call ``tap(topic, type, msg)`` for every message published on any topic.

        A tap runs in the publishing thread, before delivery, and must only hand the message
        on (e.g. append it to a queue): it sees every topic without subscribing to any, so it
        is not listed as a subscriber and keeps no topic alive. Returns a function removing it.
        """
        with self._lock:
            self._taps = (*self._taps, tap)

        def remove() -> None:
            with self._lock:
                self._taps = tuple(t for t in self._taps if t is not tap)

        return remove

    def latched(self, name: str) -> Message | None:
        topic = self._topics.get(canonical(name))
        return topic.last if topic else None

    # -- services -------------------------------------------------------------------------
    def advertise_service(
        self, name: str, type: str, handler: ServiceHandler, *, owner: str = INTERNAL
    ) -> str:
        """Provide service ``name``; a later provider replaces an earlier one (as in ROS)."""
        key = canonical(name)
        with self._lock:
            self._services[key] = _Service(key, type, handler, owner)
        return key

    def unadvertise_service(self, name: str, owner: str | None = None) -> None:
        key = canonical(name)
        with self._lock:
            svc = self._services.get(key)
            if svc is not None and (owner is None or svc.owner == owner):
                del self._services[key]

    async def call_service(
        self, name: str, args: Message | None = None, *, timeout: float | None = None
    ) -> Message:
        """Call a service and return its response values.

        Raises:
            NotFound: no provider.
            ServiceTimeout: no answer within ``timeout`` seconds.
            ServiceError: the provider raised; the message says why.
        """
        key = canonical(name)
        svc = self._services.get(key)
        if svc is None:
            raise NotFound(f"service {key} does not exist")
        try:
            if timeout is None:
                return await svc.handler(dict(args or {}))
            return await asyncio.wait_for(svc.handler(dict(args or {})), timeout)
        except TimeoutError as exc:
            raise ServiceTimeout(f"service {key} did not answer within {timeout} s") from exc
        except GraphError:
            raise
        except Exception as exc:
            raise ServiceError(f"service {key} failed: {exc}") from exc

    # -- introspection --------------------------------------------------------------------
    def topics(self) -> dict[str, str]:
        """Canonical topic name -> type, sorted by name."""
        with self._lock:
            return {n: t.type for n, t in sorted(self._topics.items())}

    def topic_type(self, name: str) -> str | None:
        topic = self._topics.get(canonical(name))
        return topic.type if topic else None

    def publishers(self, name: str) -> list[str]:
        topic = self._topics.get(canonical(name))
        return sorted(topic.publishers) if topic else []

    def subscribers(self, name: str) -> list[str]:
        topic = self._topics.get(canonical(name))
        return sorted({s.owner for s in topic.subscriptions}) if topic else []

    def services(self) -> dict[str, str]:
        with self._lock:
            return {n: s.type for n, s in sorted(self._services.items())}

    def service_type(self, name: str) -> str | None:
        svc = self._services.get(canonical(name))
        return svc.type if svc else None

    def service_owner(self, name: str) -> str | None:
        svc = self._services.get(canonical(name))
        return svc.owner if svc else None

    def owners(self) -> Iterator[str]:
        """Every owner (node) known to the graph."""
        seen: set[str] = {INTERNAL}
        with self._lock:
            for t in self._topics.values():
                seen.update(t.publishers)
                seen.update(s.owner for s in t.subscriptions)
            seen.update(s.owner for s in self._services.values())
        return iter(sorted(seen))

    # -- parameters (rosapi get/set_param; values are any JSON value) ---------------------
    def set_param(self, name: str, value: Any) -> None:
        json.dumps(value)  # only JSON values are parameters; raises TypeError otherwise
        self._params[canonical(name)] = value

    def get_param(self, name: str, default: Any = None) -> Any:
        return self._params.get(canonical(name), default)

    def has_param(self, name: str) -> bool:
        return canonical(name) in self._params

    def delete_param(self, name: str) -> None:
        self._params.pop(canonical(name), None)

    def param_names(self) -> list[str]:
        return sorted(self._params)
