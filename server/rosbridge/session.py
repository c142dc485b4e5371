"""One rosbridge connection's state on the graph: its subscriptions, advertisements, services.

:class:`BridgeSession` applies decoded ops (``server.rosbridge.ops``) to the graph after the
security checks, turns graph messages into frames through its :class:`BridgeProtocol`, and calls
``notify()`` whenever frames are ready. It does no socket I/O: the endpoint drains
``protocol.frames_to_send()`` and owns the socket. Service calls run as tasks on the loop.
"""

from __future__ import annotations

import asyncio
import itertools
import json
import re
from collections.abc import Callable, Coroutine
from typing import Any

from drone.deadline import (
    BadIssued,
    Deadline,
    Expired,
    ReportGate,
    expires,
    label,
    not_flown,
    stamp,
)
from server import graph as g
from server.http.security import LEASE_SERVICE, LeaseHeld, Role
from server.rosbridge import cborraw, ops
from server.rosbridge.context import BridgeContext
from server.rosbridge.errors import (
    BridgeError,
    LimitError,
    MessageError,
    NotAuthenticated,
    NotFoundError,
    OpError,
    RefusedError,
)
from server.rosbridge.protocol import BridgeProtocol
from server.rosbridge.streams import SubParams, TopicStream
from server.rosbridge.values import check_message, is_known_type, to_json_text
from server.vehicles import deadlines

Schedule = Callable[[float, Callable[[], None]], object]
# Drone commands over rosbridge that the audit trail records.
_DRONE_COMMAND = re.compile(r"^(/uav\d+)?/ardrone/(takeoff|land|reset|emergency)$")
MAX_AUDIT_PENDING = 16
_JOG_TOPIC = re.compile(r"^(/uav\d+)?/cmd_vel$")
# Topics whose messages are operator commands: published on with their ``issued`` time.
_UTTERANCE_TOPIC = re.compile(r"^(/[^/]+)?/console/utterance$")
Spawn = Callable[[Coroutine[Any, Any, None]], object]


def _command_kind(key: str, msg: dict[str, Any]) -> str | None:
    """What a drone command topic asks (drone/deadline.py's kinds): ``takeoff``, ``land``,
    ``reset``, ``emergency``, ``jog``, or ``hover`` for a ``/cmd_vel`` of zeros (the end of a
    jog: a stop, never dropped); None for any other topic."""
    command = _DRONE_COMMAND.match(key)
    if command is not None:
        return command.group(2)
    if _JOG_TOPIC.match(key) is None:
        return None
    moving = any(
        isinstance(v, int | float) and v != 0
        for part in ("linear", "angular")
        for v in (msg.get(part) or {}).values()
    )
    return "jog" if moving else "hover"


class BridgeSession:
    """Applies one connection's ops to the graph and feeds graph events back as frames."""

    def __init__(
        self,
        ctx: BridgeContext,
        protocol: BridgeProtocol,
        *,
        owner: str,
        role: Role | None,
        who: str | None = None,
        notify: Callable[[], None],
        schedule: Schedule,
        spawn: Spawn,
    ) -> None:
        self.ctx = ctx
        self.graph = ctx.graph
        self.security = ctx.security
        self.protocol = protocol
        self.owner = owner
        self.role: Role | None = None
        self._set_role(role)
        self.who = who  # beyond the role, who authenticated (a vehicle's name), if known
        self._notify = notify
        self._schedule = schedule
        self._spawn = spawn
        self.streams: dict[str, TopicStream] = {}  # by topic as the client spelled it
        self._graph_subs: dict[str, g.Subscription] = {}
        self.advertised: dict[str, str] = {}  # canonical topic -> type
        self.provided: dict[str, str] = {}  # canonical service -> name as spelled
        self._pending: dict[str, asyncio.Future[Any]] = {}  # service_request id -> future
        self._request_ids = itertools.count(1)
        self._poll_scheduled: set[str] = set()
        self.calls_in_flight = 0
        self.audit_pending = 0
        self._jogging: set[str] = set()  # /cmd_vel topics this connection is jogging on
        self._audit_lock = asyncio.Lock()  # FIFO: this connection's rows in order
        self._expiry_reports = ReportGate()  # one "Not flown" per topic every 2 s (a late jog)
        self.close_request: tuple[int, str] | None = None
        self.closed = False

    # -- dispatch -------------------------------------------------------------------------
    def handle(self, op: ops.Op, now: float) -> None:
        """Apply one op; a refusal or failure becomes a status error with the op's id."""
        try:
            if self.role is None and not isinstance(op, ops.Auth | ops.StatusIn | ops.SetLevel):
                self.close_request = (1008, "not authenticated")
                raise NotAuthenticated(
                    "not authenticated: connect with ?token=… or an Authorization bearer header, "
                    'or send {"op": "auth", "token": …} first',
                    id=op.id,
                )
            handler = _HANDLERS[type(op)]
            handler(self, op, now)
        except BridgeError as err:
            if err.id is None:
                err.id = op.id
            self.protocol.reject(err)
        self._notify()

    # -- auth / level ---------------------------------------------------------------------
    def _auth(self, op: ops.Auth, now: float) -> None:
        role = self.security.role_for(op.token)
        if role is None:
            self.close_request = (1008, "invalid token")
            raise RefusedError("auth: invalid token", id=op.id)
        self._set_role(role)
        self.who = self.security.identify(op.token)
        self.protocol.send_status("info", f"authenticated as {role.value}", id=op.id)

    def _set_role(self, role: Role | None) -> None:
        """The connection's role, and what its protocol may decode for it: nothing past
        ``auth`` without one, and png-compressed frames only from a pilot (an observer only
        watches; a png is the one frame whose decoding can cost far more than its size)."""
        self.role = role
        self.protocol.authenticated = role is not None
        # an observer's messages are small, reassembled from fragments or not
        self.protocol.max_frame_bytes = (
            self.ctx.observer_max_frame_bytes
            if role is Role.OBSERVER
            else self.ctx.settings.max_frame_bytes
        )
        self.protocol.png_refusal = (
            None
            if role is Role.PILOT
            else f"{role.value if role else 'an unauthenticated client'} may not send "
            "png-compressed frames; refused before decoding"
        )

    def _set_level(self, op: ops.SetLevel, now: float) -> None:
        self.protocol.set_level(op.level)

    def _status_in(self, op: ops.StatusIn, now: float) -> None:
        return None  # clients may send status; nothing to do

    # -- topics ---------------------------------------------------------------------------
    def _check_type(self, type_name: str, what: str, id: str | None) -> None:
        if not is_known_type(type_name):
            raise NotFoundError(f"{what}: unknown message type {type_name}", id=id)

    def _advertise(self, op: ops.Advertise, now: float) -> None:
        if not self.security.can_publish(self.role, op.topic, self.who):
            raise RefusedError(self.security.refusal(self.role, "advertise", op.topic, self.who))
        self._check_type(op.type, f"advertise {op.topic}", op.id)
        try:
            key = self.graph.advertise(op.topic, op.type, latch=op.latch, owner=self.owner)
        except g.GraphError as exc:
            raise OpError(f"advertise {op.topic}: {exc}") from exc
        self.advertised[key] = op.type

    def _unadvertise(self, op: ops.Unadvertise, now: float) -> None:
        key = g.canonical(op.topic)
        if key not in self.advertised:
            raise OpError(f"unadvertise: this connection has not advertised {op.topic}")
        del self.advertised[key]
        self.graph.unadvertise(key, owner=self.owner)

    def _publish(self, op: ops.Publish, now: float) -> None:
        topic = op.topic
        if not self.security.can_publish(self.role, topic, self.who):
            raise RefusedError(self.security.refusal(self.role, "publish to", topic, self.who))
        key = g.canonical(topic)
        type_name = self.advertised.get(key) or self.graph.topic_type(key)
        if type_name is None:
            raise NotFoundError(
                f"publish to {topic}: unknown topic; advertise it first with its type"
            )
        if self.security.needs_lease(key, service=False) and not self.security.lease_exempt(
            key, op.msg
        ):
            self._ensure_lease(now, f"publish to {topic}")
        msg = check_message(type_name, op.msg, self.ctx.wall_clock())
        if type_name == "uav_console/Utterance" and not msg.get("source"):
            msg["source"] = "rosbridge"  # a client that does not say: the door it came through
        issued = self._issued(op, key, msg)
        if issued is not None and not self._in_time(key, msg, issued, op.id):
            return
        try:
            if key not in self.advertised or op.latch:
                self.graph.advertise(key, type_name, latch=op.latch, owner=self.owner)
                self.advertised[key] = type_name
            command = _DRONE_COMMAND.match(key)
            if command is not None and self.ctx.audit is not None:
                self._audited_publish(key, msg, command.group(2), command.group(1) or "", issued)
                return
            jog = _JOG_TOPIC.match(key)
            if jog is not None and self.ctx.audit is not None:
                self._audit_jog(key, msg, jog.group(1) or "")
            self.graph.publish(key, msg, issued=issued)
        except g.GraphError as exc:
            raise OpError(f"publish to {topic}: {exc}") from exc

    # -- deadlines ------------------------------------------------------------------------
    def _issued(self, op: ops.Publish, key: str, msg: dict[str, Any]) -> float | None:
        """When a command (``/cmd_vel``, ``/ardrone/*``, ``/console/utterance``) was issued:
        its ``issued``, or now; None for anything else (no deadline, nothing carried on).
        A stamp that is not Unix seconds refuses a motion command; a stop, or an utterance
        (which may be one), goes on judged from its arrival, with a warning."""
        if not (_DRONE_COMMAND.match(key) or _JOG_TOPIC.match(key) or _UTTERANCE_TOPIC.match(key)):
            return None
        arrival = self.ctx.wall_clock()
        error = op.issued_error
        if error is None:
            try:
                return stamp(op.issued, arrival)
            except BadIssued as exc:
                error = str(exc)
        kind = _command_kind(key, msg)
        if kind is not None and expires(kind):
            raise OpError(f"publish to {op.topic}: {error}")
        self.protocol.send_status(
            "warning", f"publish to {op.topic}: {error}; judged from its arrival", id=op.id
        )
        return arrival

    def _in_time(self, key: str, msg: dict[str, Any], issued: float, op_id: str | None) -> bool:
        """Judge a drone command's deadline here, where the console hands it over; an
        expired one is told to this client (a ``status`` error with the op's id), said on
        ``/console/reply`` and audited. Utterances are judged by the dialog, which knows
        what they ask."""
        kind = _command_kind(key, msg)
        if kind is None:
            return True
        now = self.ctx.wall_clock()
        verdict = Deadline(self.ctx.settings.command_deadline_s).judge(kind, issued, now)
        if not isinstance(verdict, Expired):
            self._expiry_reports.reset(key)
            return True
        match = _DRONE_COMMAND.match(key) or _JOG_TOPIC.match(key)
        prefix = (match.group(1) if match else None) or ""
        drone = prefix.strip("/") or "uav1"
        text = not_flown(label(kind), verdict)
        if kind == "jog" and not self._expiry_reports.allow(key, self.ctx.clock()):
            return False  # said a moment ago (a late jog comes ten times a second)
        deadlines.say(self.graph, text, drone, prefix)
        self.protocol.send_status("error", f"publish to {key}: {text}", id=op_id)
        if self.ctx.audit is not None and self.audit_pending < MAX_AUDIT_PENDING:
            self.audit_pending += 1

            async def write() -> None:
                try:
                    await self._audit_write(
                        deadlines.audit_row,
                        self.ctx.audit.log,
                        text,
                        verdict,
                        kind=kind,
                        drone=drone,
                        source="rosbridge",
                        utterance=f"publish {key} by {self.owner}",
                    )
                finally:
                    self.audit_pending -= 1

            self._spawn(write())
        return False

    async def _audit_write(self, fn: Callable[..., Any], *args: Any, **kw: Any) -> Any:
        """One audit write in a worker thread; writes of a connection keep their order."""
        async with self._audit_lock:
            return await asyncio.to_thread(fn, *args, **kw)

    def _audit_jog(self, key: str, msg: dict[str, Any], prefix: str) -> None:
        """A row when a jog starts and when it stops (not one per message: the page sends
        ``/cmd_vel`` at 10 Hz while a key is held). The jog acts at once; its rows follow."""
        moving = any(
            isinstance(v, int | float) and v != 0
            for part in ("linear", "angular")
            for v in (msg.get(part) or {}).values()
        )
        if moving == (key in self._jogging):
            return
        if moving:
            self._jogging.add(key)
        else:
            self._jogging.discard(key)
        if self.audit_pending >= MAX_AUDIT_PENDING:
            return  # rows of a jog toggled faster than they can be written: the next will do
        what = "jog_start" if moving else "jog_stop"
        drone = prefix.strip("/") or "uav1"
        detail = f"publish {key} by {self.owner}"
        self._spawn_published_rows(what, drone, detail, self.ctx.wall_clock())

    def _spawn_published_rows(self, what: str, drone: str, detail: str, arrived: float) -> None:
        """Write the intent and outcome rows of a publish that has already happened, in the
        background, stamped with the time it arrived (counted in ``audit_pending``)."""
        self.audit_pending += 1

        async def write() -> None:
            try:
                await self._audit_write(
                    self.ctx.audit.both,
                    what,
                    "published",
                    role="pilot",
                    source="rosbridge",
                    drone=drone,
                    detail=detail,
                    at=arrived,
                )
            finally:
                self.audit_pending -= 1

        self._spawn(write())

    def _audited_publish(
        self, key: str, msg: dict[str, Any], what: str, prefix: str, issued: float | None = None
    ) -> None:
        """Publish a drone command with its audit rows (server.http.audit_trail): land and
        emergency first and the rows after; the others after their intent row is committed."""
        trail = self.ctx.audit
        drone = prefix.strip("/") or "uav1"
        detail = f"publish {key} by {self.owner}"
        if self.audit_pending >= MAX_AUDIT_PENDING:
            raise LimitError(
                f"publish to {key} refused: {self.audit_pending} commands of this connection "
                "are waiting for their audit rows"
            )
        if what in ("land", "emergency"):
            arrived = self.ctx.wall_clock()
            self.graph.publish(key, msg, issued=issued)
            self._spawn_published_rows(what, drone, detail, arrived)
            return
        self.audit_pending += 1

        async def intent_first() -> None:
            try:
                iid = await self._audit_write(
                    trail.intent,
                    what,
                    role="pilot",
                    source="rosbridge",
                    drone=drone,
                    detail=detail,
                )
                if self.closed:
                    result = "not published: the connection closed"
                else:
                    try:
                        # Judged again where it reaches the drone (the vehicle node, or the
                        # vehicle process): the audit row's fsync above counts against it.
                        self.graph.publish(key, msg, issued=issued)
                        result = "published"
                    except g.GraphError as exc:
                        result = f"failed: {exc}"
                await self._audit_write(
                    trail.outcome, iid, what, result, role="pilot", source="rosbridge", drone=drone
                )
            finally:
                self.audit_pending -= 1

        self._spawn(intent_first())

    def _subscribe(self, op: ops.Subscribe, now: float) -> None:
        key = g.canonical(op.topic)
        existing = self.graph.topic_type(key)
        type_name = op.type or existing
        if type_name is None:
            raise NotFoundError(
                f"subscribe to {op.topic}: unknown topic and no type given to create it"
            )
        if existing is not None and op.type is not None and existing != op.type:
            raise OpError(f"subscribe to {op.topic}: topic has type {existing}, not {op.type}")
        self._check_type(type_name, f"subscribe to {op.topic}", op.id)
        if op.compression == "cbor-raw" and not cborraw.can_encode(type_name):
            raise OpError(
                f"subscribe to {op.topic}: compression cbor-raw (ROS 1 bytes) needs the message "
                f"definition of {type_name}, which this server does not have; use cbor or none"
            )
        params = SubParams(op.throttle_rate_ms, op.queue_length, op.fragment_size, op.compression)
        stream = self.streams.get(op.topic)
        if stream is not None:
            stream.add(op.id, params)
            return
        stream = self.streams[op.topic] = TopicStream(op.topic, type_name)
        stream.add(op.id, params)

        def deliver(msg: dict[str, Any]) -> None:
            self._on_message(stream, msg, self.graph.issued)

        try:
            self._graph_subs[op.topic] = self.graph.subscribe(
                key, deliver, type=type_name, owner=self.owner
            )
        except g.GraphError as exc:
            del self.streams[op.topic]
            raise OpError(f"subscribe to {op.topic}: {exc}") from exc

    def _unsubscribe(self, op: ops.Unsubscribe, now: float) -> None:
        stream = self.streams.get(op.topic)
        if stream is None or not stream.remove(op.id):
            which = f" with id {op.id}" if op.id is not None else ""
            raise OpError(f"unsubscribe: not subscribed to {op.topic}{which}")
        if stream.empty:
            del self.streams[op.topic]
            sub = self._graph_subs.pop(op.topic, None)
            if sub is not None:
                sub.close()

    def _on_message(
        self, stream: TopicStream, msg: dict[str, Any], issued: float | None = None
    ) -> None:
        if self.closed or self.streams.get(stream.topic) is not stream:
            return
        self._send(stream, stream.offer(msg, self.ctx.clock()), (msg, issued))
        self._arm_poll(stream)

    def _send(
        self,
        stream: TopicStream,
        msgs: list[Any],
        issued_of: tuple[Any, float | None] = (None, None),
    ) -> None:
        """Send ``msgs``; the one that is ``issued_of[0]`` (sent as it arrives, not from a
        queue) carries its command's ``issued`` on to the client (a vehicle judges it)."""
        if not msgs:
            return
        p = stream.params
        fresh, issued = issued_of
        for msg in msgs:
            text = "" if p.compression in ("cbor", "cbor-raw") else self.ctx.json_cache.text(msg)
            self.protocol.send_publish(
                stream.topic,
                text,
                compression=p.compression,
                fragment_size=p.fragment_size,
                msg=msg,
                type_name=stream.type_name,
                issued=issued if msg is fresh else None,
            )
        self._notify()

    def _arm_poll(self, stream: TopicStream) -> None:
        due = stream.next_due()
        if due is None or stream.topic in self._poll_scheduled:
            return
        self._poll_scheduled.add(stream.topic)
        delay = max(0.0, due - self.ctx.clock())

        def fire() -> None:
            self._poll_scheduled.discard(stream.topic)
            if self.closed or self.streams.get(stream.topic) is not stream:
                return
            self._send(stream, stream.poll(self.ctx.clock()))
            self._arm_poll(stream)

        self._schedule(delay, fire)

    # -- services -------------------------------------------------------------------------
    def _call_service(self, op: ops.CallService, now: float) -> None:
        key = g.canonical(op.service)
        if not self.security.can_call(self.role, key, self.who):
            msg = self.security.refusal(self.role, "call", op.service, self.who)
            self._service_failed(op, msg)
            raise RefusedError(msg)
        if key == LEASE_SERVICE:
            self._lease_call(op, now)
            return
        if self.security.needs_lease(key, service=True):
            try:
                self._ensure_lease(now, f"call {op.service}")
            except RefusedError as err:
                self._service_failed(op, err.msg)
                raise
        try:
            args = self._args(op, key)
            if self.calls_in_flight >= self.ctx.max_calls_in_flight:
                raise LimitError(
                    f"call {op.service} refused: {self.calls_in_flight} calls of this connection "
                    f"are still running (at most {self.ctx.max_calls_in_flight} at a time)"
                )
        except BridgeError as err:
            self._service_failed(op, err.msg)
            raise
        self.calls_in_flight += 1
        self._spawn(self._run_call(op, key, args))

    def _args(self, op: ops.CallService, key: str) -> dict[str, Any]:
        if isinstance(op.args, dict):
            return op.args
        if not op.args:
            return {}
        stype = self.graph.service_type(key) or ""
        names = self.ctx.request_fields.get(stype)
        if names is None:
            raise OpError(
                f"call {op.service}: positional args need a known request type ({stype or '?'}); "
                "send args as an object"
            )
        if len(op.args) > len(names):
            raise OpError(f"call {op.service}: {len(op.args)} args for {len(names)} fields")
        return dict(zip(names, op.args, strict=False))

    async def _run_call(self, op: ops.CallService, key: str, args: dict[str, Any]) -> None:
        try:
            await self._run_call_counted(op, key, args)
        finally:
            self.calls_in_flight -= 1

    async def _run_call_counted(self, op: ops.CallService, key: str, args: dict[str, Any]) -> None:
        timeout = op.timeout_s if op.timeout_s is not None else self.ctx.service_timeout_s
        try:
            values = await self.graph.call_service(key, args, timeout=timeout)
            values_json = to_json_text(values)
        except g.GraphError as exc:
            self._service_failed(op, str(exc))
            self._notify()
            return
        except (TypeError, ValueError) as exc:
            self._service_failed(op, f"service {key} returned values that are not JSON: {exc}")
            self._notify()
            return
        if self.closed:
            return
        self.protocol.send_service_response(
            op.service,
            op.id,
            None,
            True,
            values_json=values_json,
            compression="png" if op.compression == "png" else "none",
            fragment_size=op.fragment_size,
        )
        self._notify()

    def _service_failed(self, op: ops.CallService, message: str) -> None:
        if not self.closed:
            self.protocol.send_service_response(op.service, op.id, message, False)

    def _advertise_service(self, op: ops.AdvertiseService, now: float) -> None:
        key = g.canonical(op.service)
        if not self.security.can_provide(self.role, key, self.who):
            msg = self.security.refusal(self.role, "provide the service", op.service, self.who)
            raise RefusedError(msg)
        owner = self.graph.service_owner(key)
        if (
            key.startswith("/rosapi/")
            or key == LEASE_SERVICE
            or (owner is not None and owner == g.INTERNAL)
        ):
            raise RefusedError(f"{op.service} is provided by the server and cannot be replaced")
        self.provided[key] = op.service
        spelled = op.service

        async def handler(args: dict[str, Any]) -> dict[str, Any]:
            values: dict[str, Any] = await self._forward_call(key, spelled, args)
            return values

        self.graph.advertise_service(key, op.type, handler, owner=self.owner)

    async def _forward_call(self, key: str, spelled: str, args: dict[str, Any]) -> Any:
        if self.closed:
            raise g.ServiceError(f"the provider of {key} disconnected")
        req_id = f"service_request:{spelled}:{next(self._request_ids)}"
        fut: asyncio.Future[Any] = asyncio.get_running_loop().create_future()
        self._pending[req_id] = fut
        self.protocol.send_call_service(spelled, req_id, to_json_text(args))
        self._notify()
        try:
            return await fut
        finally:
            self._pending.pop(req_id, None)

    def _service_response(self, op: ops.ServiceResponse, now: float) -> None:
        fut = self._pending.get(op.id or "")
        if fut is None:
            raise OpError(f"service_response: no call {op.id!r} is waiting for an answer")
        if fut.done():
            return
        if op.result:
            values = op.values if op.values is not None else {}
            if not isinstance(values, dict):
                fut.set_exception(g.ServiceError(f"provider answered non-object values {values!r}"))
                return
            fut.set_result(values)
        else:
            detail = op.values if isinstance(op.values, str) else json.dumps(op.values)
            fut.set_exception(g.ServiceError(f"the provider reported failure: {detail}"))

    def _unadvertise_service(self, op: ops.UnadvertiseService, now: float) -> None:
        key = g.canonical(op.service)
        if key not in self.provided:
            raise OpError(f"unadvertise_service: this connection does not provide {op.service}")
        del self.provided[key]
        self.graph.unadvertise_service(key, owner=self.owner)

    # -- the pilot lease ------------------------------------------------------------------
    def _ensure_lease(self, now: float, what: str) -> None:
        try:
            self.security.lease.acquire(self.owner, now, on_revoke=self._lease_revoked)
        except LeaseHeld as exc:
            raise RefusedError(f"{what} refused: {exc}") from exc

    def _lease_revoked(self, new_holder: str) -> None:
        self.protocol.send_status(
            "warning",
            f"pilot lease taken over by {new_holder}; this connection may no longer command",
        )
        self.protocol.send_status(
            "error", "pilot lease lost: another pilot took over", id="lease:revoked"
        )
        self._notify()

    def _lease_call(self, op: ops.CallService, now: float) -> None:
        """``/console/lease {action: status|acquire|release, take_over}`` for this connection."""
        args = op.args if isinstance(op.args, dict) else {}
        action = args.get("action", "acquire")
        lease = self.security.lease
        try:
            if action not in ("status", "acquire", "release"):
                raise OpError(f"{LEASE_SERVICE}: action must be status, acquire or release")
            if action != "status" and self.role is not Role.PILOT:
                raise RefusedError(self.security.refusal(self.role, "take", "the pilot lease"))
            if action == "acquire":
                take_over = bool(args.get("take_over", False))
                try:
                    lease.acquire(
                        self.owner, now, take_over=take_over, on_revoke=self._lease_revoked
                    )
                except LeaseHeld as exc:
                    raise RefusedError(str(exc)) from exc
            elif action == "release":
                lease.release(self.owner)
        except BridgeError as err:
            self._service_failed(op, err.msg)
            raise
        state = lease.state
        mine = state.holder == self.owner
        # The holder is told its holding's secret (what REST callers name in X-Pilot-Lease);
        # everyone else only that someone holds it (a holder id is a credential).
        key = lease.key_of(self.owner) or ""
        values = {
            "holder": key if mine else (lease.PUBLIC_NAME if state.holder else ""),
            "held_by_me": mine,
            "since": state.since or 0.0,
            "key": key,
        }
        self.protocol.send_service_response(op.service, op.id, values, True)

    # -- teardown -------------------------------------------------------------------------
    def close(self) -> None:
        """Remove everything this connection put on the graph; fail calls waiting on it."""
        if self.closed:
            return
        self.closed = True
        for sub in self._graph_subs.values():
            sub.close()
        self._graph_subs.clear()
        self.streams.clear()
        for fut in self._pending.values():
            if not fut.done():
                fut.set_exception(g.ServiceError(f"the provider {self.owner} disconnected"))
        self._pending.clear()
        self._poll_scheduled.clear()
        self.advertised.clear()
        self.provided.clear()
        self.protocol.close()
        self.graph.drop_owner(self.owner)
        self.security.lease.release(self.owner)


_HANDLERS: dict[type, Callable[[BridgeSession, Any, float], None]] = {
    ops.Auth: BridgeSession._auth,
    ops.SetLevel: BridgeSession._set_level,
    ops.StatusIn: BridgeSession._status_in,
    ops.Advertise: BridgeSession._advertise,
    ops.Unadvertise: BridgeSession._unadvertise,
    ops.Publish: BridgeSession._publish,
    ops.Subscribe: BridgeSession._subscribe,
    ops.Unsubscribe: BridgeSession._unsubscribe,
    ops.CallService: BridgeSession._call_service,
    ops.ServiceResponse: BridgeSession._service_response,
    ops.AdvertiseService: BridgeSession._advertise_service,
    ops.UnadvertiseService: BridgeSession._unadvertise_service,
}

__all__ = ["BridgeSession", "MessageError"]
