"""Sans-I/O core of the vehicle link: a local graph mirrored onto a rosbridge v2 server.

The vehicle process keeps its own :class:`~server.graph.Graph`; this core turns it into
rosbridge client frames (text in, text out, no socket, no clock of its own):

- ``out_topics``: local publishes become ``publish`` frames (after an ``advertise`` in
  :meth:`hello`; latched ones are re-sent on every reconnect);
- ``in_topics``: the central server's messages (``subscribe`` in :meth:`hello`) are published
  on the local graph, a command with its frame's ``issued`` moved onto the vehicle's clock by
  ``to_local`` (so the part that hands it to the drone judges its deadline);
- ``out_services``: the server's ``call_service`` frames call the local service; the answer goes
  back as ``service_response`` with the request's ``id``;
- :meth:`call`: the vehicle calls a service of the central server (e.g. the captioner).

Outgoing frames wait in a bounded queue (``max_queue``, oldest dropped): a central server that
stops reading costs the vehicle nothing but dropped telemetry.
"""

from __future__ import annotations

import asyncio
import collections
import dataclasses
import itertools
import json
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from server.graph import Graph, GraphError
from server.rosbridge.values import to_json_text
from server.vehicles.errors import RemoteCallError

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class TopicSpec:
    name: str
    type: str
    latch: bool = False


@dataclass(frozen=True)
class LinkSpec:
    """What crosses the link (names canonical, with the fleet prefix already applied)."""

    out_topics: tuple[TopicSpec, ...] = ()
    in_topics: tuple[TopicSpec, ...] = ()
    out_services: tuple[tuple[str, str], ...] = ()  # (name, type)
    owner: str = "vehicle-link"
    extra: dict[str, Any] = field(default_factory=dict)


class GraphLinkCore:
    """See the module docstring. ``on_output`` is called when frames are ready to send."""

    def __init__(
        self,
        graph: Graph,
        spec: LinkSpec,
        *,
        max_queue: int = 256,
        on_output: Callable[[], None] = lambda: None,
        to_local: Callable[[float], float] = lambda t: t,
    ) -> None:
        self.graph = graph
        self.to_local = to_local
        self.spec = spec
        self.on_output = on_output
        self.connected = False
        self.dropped = 0
        self.frames_in = 0
        self.errors: list[str] = []  # status messages from the server, newest last
        self._out: collections.deque[str] = collections.deque()
        self._max_queue = max_queue
        self._ids = itertools.count(1)
        self._calls: dict[str, asyncio.Future[Any]] = {}
        self._tasks: set[asyncio.Task[None]] = set()
        self._subs = {
            t.name: graph.subscribe(t.name, self._forwarder(t.name), type=t.type, owner=spec.owner)
            for t in spec.out_topics
        }
        for t in spec.in_topics:
            graph.advertise(t.name, t.type, latch=t.latch, owner=spec.owner)

    # ------------------------------------------------------------------ out
    def leave_out(self, topics: set[str]) -> None:
        """Stop carrying these out-topics (another road carries them: the bus, the camera);
        from the next :meth:`hello` they are not advertised either."""
        keep = tuple(t for t in self.spec.out_topics if t.name not in topics)
        for name in topics:
            sub = self._subs.pop(name, None)
            if sub is not None:
                sub.close()
        self.spec = dataclasses.replace(self.spec, out_topics=keep)

    def _push(self, frame: str) -> None:
        if len(self._out) >= self._max_queue:
            self._out.popleft()
            self.dropped += 1
        self._out.append(frame)
        self.on_output()

    def _forwarder(self, topic: str) -> Callable[[dict[str, Any]], None]:
        def forward(msg: dict[str, Any]) -> None:
            if self.connected:
                self._push(_frame({"op": "publish", "topic": topic, "msg": msg}))

        return forward

    def drain(self) -> list[str]:
        """Frames to send now (oldest first)."""
        out = list(self._out)
        self._out.clear()
        return out

    def hello(self) -> list[str]:
        """(Re)connected: declare everything, then re-send the latched local messages."""
        self.connected = True
        self._out.clear()
        frames = [
            _frame({"op": "advertise", "topic": t.name, "type": t.type, "latch": t.latch})
            for t in self.spec.out_topics
        ]
        frames += [
            _frame({"op": "advertise_service", "service": name, "type": typ})
            for name, typ in self.spec.out_services
        ]
        frames += [
            _frame({"op": "subscribe", "topic": t.name, "type": t.type})
            for t in self.spec.in_topics
        ]
        for t in self.spec.out_topics:
            last = self.graph.latched(t.name)
            if last is not None:
                frames.append(_frame({"op": "publish", "topic": t.name, "msg": last}))
        return frames

    def disconnected(self) -> None:
        self.connected = False
        self._out.clear()
        for fut in self._calls.values():
            if not fut.done():
                fut.set_exception(RemoteCallError("the link to the central server closed"))
        self._calls.clear()

    # ------------------------------------------------------------------ in
    def receive(self, text: str) -> None:
        """Handle one frame from the server (bad frames are counted and logged, never raised)."""
        self.frames_in += 1
        try:
            obj = json.loads(text)
        except ValueError:
            self._error(f"unparsable frame from the server: {text[:80]!r}")
            return
        if not isinstance(obj, dict):
            self._error(f"frame is not an object: {text[:80]!r}")
            return
        op = obj.get("op")
        if op == "publish":
            self._on_publish(obj)
        elif op == "call_service":
            self._on_call(obj)
        elif op == "service_response":
            fut = self._calls.pop(str(obj.get("id")), None)
            if fut is not None and not fut.done():
                if obj.get("result", True):
                    fut.set_result(obj.get("values"))
                else:
                    fut.set_exception(RemoteCallError(str(obj.get("values"))))
        elif op == "status" and obj.get("level") in ("error", "warning"):
            self._error(f"central server: {obj.get('msg')}")

    def _error(self, text: str) -> None:
        self.errors.append(text)
        del self.errors[:-50]
        log.warning("%s", text)

    def _on_publish(self, obj: dict[str, Any]) -> None:
        topic, msg = obj.get("topic"), obj.get("msg")
        if not isinstance(topic, str) or not isinstance(msg, dict):
            self._error(f"bad publish frame for {topic!r}")
            return
        issued = obj.get("issued")
        if isinstance(issued, bool) or not isinstance(issued, int | float):
            issued = None
        elif not math.isfinite(issued):
            self._error(f"bad issued {issued!r} on {topic}: dropped")
            return
        try:
            local = None if issued is None else self.to_local(float(issued))
            self.graph.publish(topic, msg, issued=local)
        except GraphError as exc:
            self._error(f"cannot deliver {topic}: {exc}")

    def _on_call(self, obj: dict[str, Any]) -> None:
        service = str(obj.get("service", ""))
        head: dict[str, Any] = {"op": "service_response", "service": service}
        if obj.get("id") is not None:
            head["id"] = obj["id"]
        if service not in {name for name, _ in self.spec.out_services}:
            self._push(_frame({**head, "result": False, "values": f"no service {service}"}))
            return
        args = obj.get("args")
        task = asyncio.get_running_loop().create_task(
            self._answer(head, service, args if isinstance(args, dict) else {})
        )
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _answer(self, head: dict[str, Any], service: str, args: dict[str, Any]) -> None:
        try:
            values = await self.graph.call_service(service, args)
            reply = {**head, "result": True, "values": values}
        except GraphError as exc:
            reply = {**head, "result": False, "values": str(exc)}
        if self.connected:
            self._push(_frame(reply))

    async def call(self, service: str, args: dict[str, Any], timeout_s: float = 10.0) -> Any:
        """Call a service of the central server.

        Raises:
            RemoteCallError: not connected, refused, failed, or no answer within ``timeout_s``.
        """
        if not self.connected:
            raise RemoteCallError(f"cannot call {service}: not connected to the central server")
        call_id = f"call_service:{service}:{next(self._ids)}"
        fut: asyncio.Future[Any] = asyncio.get_running_loop().create_future()
        self._calls[call_id] = fut
        self._push(_frame({"op": "call_service", "service": service, "args": args, "id": call_id}))
        try:
            return await asyncio.wait_for(fut, timeout_s)
        except TimeoutError as exc:
            raise RemoteCallError(f"{service} did not answer within {timeout_s} s") from exc
        finally:
            self._calls.pop(call_id, None)

    def close(self) -> None:
        for s in self._subs.values():
            s.close()
        self._subs = {}
        for t in self.spec.in_topics:
            self.graph.unadvertise(t.name, self.spec.owner)
        self.disconnected()


def _frame(obj: dict[str, Any]) -> str:
    return to_json_text(obj)
