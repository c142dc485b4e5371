"""Sans-I/O rosbridge v2 protocol for one connection: frames in, typed ops and frames out.

Feed it what the socket received (:meth:`BridgeProtocol.receive_text` /
:meth:`~BridgeProtocol.receive_bytes`, with ``now`` in seconds) and get back decoded ops
(``server.rosbridge.ops``); ask it to send things (``send_publish``, ``send_status``, …) and drain
the frames with :meth:`~BridgeProtocol.frames_to_send` (``str`` = text frame, ``bytes`` = binary
frame). It owns no socket, clock or graph, so every rule here is testable without I/O.

Unlike rosbridge_suite (which logs and drops bad frames), every rejected frame produces a
``status`` message with level ``error``, the request's ``id`` and a ``msg`` saying what was wrong;
``receive_*`` never raise. Field names and defaults follow ROSBRIDGE_PROTOCOL.md §3.4.

Decoding that can be expensive is never done by :meth:`~BridgeProtocol.feed`: a large frame, the
text of a large reassembled ``fragment`` message and every ``png`` image come out as a
:class:`~server.rosbridge.inbound.DecodeRequest` for the driver to run in a worker
(``server.rosbridge.decoder``) and hand back to :meth:`~BridgeProtocol.receive_decoded`. A
``png`` is judged first, at once: refused for a role that may not send one (observers), and
refused when the budget its header announces is over ``server.rosbridge.budget.DecodeBudget``.
:meth:`~BridgeProtocol.receive_frame` runs such requests inline (for tests and tools).
"""

from __future__ import annotations

import itertools
import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import cbor2

from drone.deadline import BadIssued, parse_issued
from server.rosbridge import cborraw, ops
from server.rosbridge.budget import (
    DecodeBudget,
    PngError,
    check_png_budget,
    peek_id,
    png_header_of_base64,
)
from server.rosbridge.encode import fragments, png_frame
from server.rosbridge.errors import (
    BridgeError,
    BudgetExceeded,
    FrameError,
    FrameTooLarge,
    NotAuthenticated,
    OpError,
    RefusedError,
    UnknownOp,
)
from server.rosbridge.inbound import DecodeRequest, decode_frame, frame_id, parse_json, run_decode
from server.rosbridge.values import normalise_type, to_cbor_value

PROTOCOL_VERSION = (2, 0)
COMPRESSIONS = ("none", "png", "cbor", "cbor-raw")
# ROSBRIDGE_PROTOCOL.md §3.2: status levels; a status is sent when its level is at or below the
# connection's level (default "error", as rosbridge_suite's capabilities/defragmentation).
LEVELS = {"none": 0, "error": 1, "warning": 2, "info": 3}
DEFAULT_FRAGMENT_TIMEOUT_S = 600.0  # rosbridge_suite's defragmentation fragment_timeout
MAX_FRAGMENT_BUFFERS = 16
# Bounds of subscription parameters. rosbridge_suite leaves them open; these are far
# beyond what a console or roslibjs asks (defaults 0 / none) and keep one client from making the
# server do per-message work out of proportion: four observers with fragment_size 1 on the
# camera cost 8 link losses; a queue_length of 2**63 was accepted.
MIN_FRAGMENT_SIZE = 1024  # characters of data per fragment
MAX_QUEUE_LENGTH = 1000  # messages (also advertise's queue_size)
MAX_THROTTLE_RATE_MS = 3_600_000  # one hour
MAX_SERVICE_TIMEOUT_S = 3600.0
# Before ``auth`` a connection may send only these ops (and only small frames: the endpoint).
PREAUTH_OPS = frozenset({"auth", "status", "set_level"})
# Frames (and reassembled fragment texts) up to these sizes are decoded by ``feed`` itself: a
# JSON text of 64 KiB holds at most ~32 000 values, a CBOR one of 16 KiB ~16 000 (one byte
# each), and parsing either costs the loop about a millisecond (bench/attacks.py).
OFFLOAD_TEXT_BYTES = 64 * 1024
OFFLOAD_BINARY_BYTES = 16 * 1024

Inbound = ops.Op | DecodeRequest


@dataclass
class _FragmentBuffer:
    total: int
    started: float
    parts: dict[int, str] = field(default_factory=dict)
    size: int = 0


class BridgeProtocol:
    """Protocol state of one rosbridge connection (status level, fragment buffers, output)."""

    def __init__(
        self,
        *,
        max_frame_bytes: int = 16 * 1024 * 1024,
        fragment_timeout_s: float = DEFAULT_FRAGMENT_TIMEOUT_S,
        budget: DecodeBudget | None = None,
        offload_text_bytes: int = OFFLOAD_TEXT_BYTES,
        offload_binary_bytes: int = OFFLOAD_BINARY_BYTES,
    ) -> None:
        self.max_frame_bytes = max_frame_bytes
        self.fragment_timeout_s = fragment_timeout_s
        self.budget = budget if budget is not None else DecodeBudget()
        self.offload_text_bytes = offload_text_bytes
        self.offload_binary_bytes = offload_binary_bytes
        # Set (by the session, from the role) to refuse every ``png`` with this message before
        # its data is read; None: the connection may send png-compressed frames.
        self.png_refusal: str | None = None
        self.level = "error"
        self._out: list[str | bytes] = []
        self._fragments: dict[str, _FragmentBuffer] = {}
        self._frag_ids = itertools.count(1)
        self.rejected = 0
        # False until the connection authenticates: only PREAUTH_OPS are decoded further (no
        # png inflation, no fragment buffers for a client without a token).
        self.authenticated = True
        self.close_request: tuple[int, str] | None = None

    # -- input ----------------------------------------------------------------------------
    def receive_text(self, text: str, now: float) -> list[ops.Op]:
        """Decode one text frame; rejected frames queue a status error and yield no op."""
        return self.receive_frame(text, now)

    def receive_bytes(self, data: bytes, now: float) -> list[ops.Op]:
        """Decode one binary frame: a CBOR-encoded op object (as a client may send)."""
        return self.receive_frame(data, now)

    def receive_frame(self, payload: str | bytes, now: float) -> list[ops.Op]:
        """Decode one frame (text: JSON, binary: CBOR) and apply it, running any expensive
        decoding inline (:func:`~server.rosbridge.inbound.run_decode`, with the budget); never
        raises. The endpoint uses :meth:`feed` instead, to run that decoding in a worker."""
        out: list[ops.Op] = []
        todo = self.feed(payload, now)
        while todo:
            item = todo.pop(0)
            if isinstance(item, DecodeRequest):
                try:
                    obj: Any = run_decode(item, self.budget, self.max_frame_bytes)
                except BridgeError as err:
                    obj = err
                todo[0:0] = self.receive_decoded(obj, now, item)
            else:
                out.append(item)
        return out

    def feed(self, payload: str | bytes, now: float) -> list[Inbound]:
        """One frame in: the ops it holds, or a :class:`DecodeRequest` where decoding it could
        be expensive (large, or a ``png``). Cheap in every case; never raises."""
        try:
            if len(payload) > self.max_frame_bytes:
                raise FrameTooLarge(
                    f"frame of {len(payload)} bytes exceeds the limit of "
                    f"{self.max_frame_bytes} bytes"
                )
            if self.authenticated and len(payload) > (
                self.offload_text_bytes if isinstance(payload, str) else self.offload_binary_bytes
            ):
                return [
                    DecodeRequest(
                        "frame", payload, peek_id(payload), allow_png=self.png_refusal is None
                    )
                ]
            obj = decode_frame(payload, self.max_frame_bytes)
        except BridgeError as err:
            self.reject(err)
            return []
        except Exception as exc:  # defensive: a bug must cost one frame, not the connection
            self.reject(FrameError(f"frame could not be handled: {type(exc).__name__}: {exc}"))
            return []
        return self.receive_decoded(obj, now)

    def receive_decoded(
        self, obj: Any, now: float, request: DecodeRequest | None = None
    ) -> list[Inbound]:
        """Apply what a :class:`DecodeRequest` (or :meth:`feed`) decoded: the frame's object,
        or a :class:`BridgeError` in its place (decoding refused it), answered like any
        rejected frame (with the request's id where the error has none). Never raises."""
        depth = 0 if request is None or request.kind == "frame" else request.depth + 1
        try:
            if isinstance(obj, BridgeError):
                if obj.id is None and request is not None:
                    obj.id = request.id
                raise obj
            return self._receive_obj(obj, now, depth=depth)
        except BridgeError as err:
            self.reject(err)
            return []
        except Exception as exc:  # defensive, as above
            self.reject(FrameError(f"frame could not be handled: {type(exc).__name__}: {exc}"))
            return []

    def _receive_obj(self, obj: Any, now: float, depth: int) -> list[Inbound]:
        if not isinstance(obj, dict):
            raise FrameError(f"a frame must be a JSON object, not {type(obj).__name__}")
        op = obj.get("op")
        fid = frame_id(obj)
        if op is None:
            raise FrameError("frame has no 'op' field", id=fid)
        if not isinstance(op, str):
            raise FrameError("'op' must be a string", id=fid)
        if not self.authenticated and op not in PREAUTH_OPS:
            self.close_request = (1008, "not authenticated")
            raise NotAuthenticated(
                f"not authenticated: {op!r} refused; connect with ?token=… or an Authorization "
                'bearer header, or send {"op": "auth", "token": …} first',
                id=fid,
                op=op,
            )
        if op == "fragment":
            text = self._defragment(obj, fid, now)
            if text is None:
                return []
            return self._nested(text, now, depth, fid)
        if op == "png":
            return [self._png_request(obj, fid, depth)]
        parser = _PARSERS.get(op)
        if parser is None:
            raise UnknownOp(f"unknown op {op!r}", id=fid, op=op)
        return [parser(obj, op, fid)]

    def close(self) -> None:
        """Free what this connection buffered (fragments, unsent frames): on close."""
        self._fragments.clear()
        self._out.clear()

    def _nested(self, text: str, now: float, depth: int, fid: str | None) -> list[Inbound]:
        if depth > 2:
            raise FrameError("fragments/png nested too deeply", id=fid)
        if len(text) > self.offload_text_bytes:
            return [DecodeRequest("text", text, fid, depth)]
        inner = parse_json(text, "reassembled frame is not valid JSON", None)
        return self._receive_obj(inner, now, depth + 1)

    def _png_request(self, obj: dict[str, Any], fid: str | None, depth: int) -> DecodeRequest:
        """A ``png`` op judged at once (role, then the budget its header announces, from the
        first 44 characters of its data) and, if it passes, handed to a worker to inflate."""
        if self.png_refusal is not None:
            raise RefusedError(self.png_refusal, id=fid, op="png")
        if depth > 2:
            raise FrameError("fragments/png nested too deeply", id=fid)
        data = _field(obj, "png", fid, "data", str, required=True)
        try:
            check_png_budget(png_header_of_base64(data), self.budget)
        except PngError as exc:
            raise OpError(f"png: cannot decode data: {exc}", id=fid, op="png") from exc
        except BudgetExceeded as err:
            err.id, err.op = fid, "png"
            raise
        return DecodeRequest("png", data, fid, depth)

    def _defragment(self, obj: dict[str, Any], fid: str | None, now: float) -> str | None:
        """Collect a fragment (§3.3.1); return the whole text once every piece arrived."""
        self._expire_fragments(now)
        if fid is None:
            raise OpError("fragment: 'id' is required", op="fragment")
        data = _field(obj, "fragment", fid, "data", str, required=True)
        num = _int_field(obj, "fragment", fid, "num", required=True, minimum=0)
        total = _int_field(obj, "fragment", fid, "total", required=True, minimum=1)
        assert num is not None and total is not None
        if num >= total:
            raise OpError(f"fragment: num {num} is not below total {total}", id=fid, op="fragment")
        buf = self._fragments.get(fid)
        if buf is None:
            if len(self._fragments) >= MAX_FRAGMENT_BUFFERS:
                raise OpError(
                    f"fragment: more than {MAX_FRAGMENT_BUFFERS} messages being reassembled",
                    id=fid,
                    op="fragment",
                )
            buf = self._fragments[fid] = _FragmentBuffer(total, now)
        if buf.total != total:
            del self._fragments[fid]
            raise OpError("fragment: 'total' changed between fragments", id=fid, op="fragment")
        if num not in buf.parts:
            buf.parts[num] = data
            buf.size += len(data)
        if buf.size > self.max_frame_bytes:
            del self._fragments[fid]
            raise FrameTooLarge(
                f"fragmented message exceeds the limit of {self.max_frame_bytes} bytes",
                id=fid,
                op="fragment",
            )
        if len(buf.parts) < buf.total:
            return None
        del self._fragments[fid]
        return "".join(buf.parts[i] for i in range(buf.total))

    def _expire_fragments(self, now: float) -> None:
        for fid, buf in list(self._fragments.items()):
            if now - buf.started > self.fragment_timeout_s:
                del self._fragments[fid]
                self.send_status(
                    "warning",
                    f"fragments of {fid} expired after {self.fragment_timeout_s:g} s incomplete",
                    id=fid,
                )

    # -- output ---------------------------------------------------------------------------
    def reject(self, err: BridgeError) -> None:
        """Answer a rejected frame with a status error carrying its id."""
        self.rejected += 1
        self.send_status("error", err.msg, id=err.id)

    def send_status(self, level: str, msg: str, *, id: str | None = None) -> None:
        if LEVELS.get(level, 1) > LEVELS[self.level] or self.level == "none":
            return
        frame: dict[str, Any] = {"op": "status", "level": level, "msg": msg}
        if id is not None:
            frame["id"] = id
        self._out.append(json.dumps(frame))

    def set_level(self, level: str) -> None:
        self.level = level

    def publish_frames(
        self,
        topic: str,
        msg_json: str,
        *,
        compression: str = "none",
        fragment_size: int | None = None,
        msg: Any = None,
        type_name: str | None = None,
        issued: float | None = None,
    ) -> list[str | bytes]:
        """The frames of one outgoing ``publish`` (``msg_json`` is the message's JSON text);
        ``issued``: the command's, carried on to a subscriber that hands it on (a vehicle)."""
        if compression == "cbor":
            body = {"op": "publish", "topic": topic, "msg": to_cbor_value(type_name, msg)}
            if issued is not None:
                body["issued"] = issued
            return [cbor2.dumps(body)]
        if compression == "cbor-raw":
            try:
                return [cborraw.publish_frame(topic, type_name or "", msg)]
            except cborraw.Ros1Error as exc:
                err = {"op": "status", "level": "error", "msg": f"publish {topic}: {exc}"}
                return [json.dumps(err)]
        text = '{"op":"publish","topic":' + json.dumps(topic) + ',"msg":' + msg_json
        if issued is not None and math.isfinite(issued):
            text += ',"issued":' + repr(float(issued))
        text += "}"
        return self._wrap(text, compression, fragment_size)

    def send_publish(self, topic: str, msg_json: str, **kw: Any) -> None:
        self._out.extend(self.publish_frames(topic, msg_json, **kw))

    def _wrap(self, text: str, compression: str, fragment_size: int | None) -> list[str | bytes]:
        if compression == "png":
            text = png_frame(text)
        if fragment_size is not None and len(text) > fragment_size:
            return list(fragments(text, fragment_size, f"fragment:{next(self._frag_ids)}"))
        return [text]

    def send_service_response(
        self,
        service: str,
        id: str | None,
        values: Any,
        result: bool,
        *,
        values_json: str | None = None,
        compression: str = "none",
        fragment_size: int | None = None,
    ) -> None:
        """Queue a ``service_response``; ``values`` is always present (roslibpy needs it)."""
        head: dict[str, Any] = {"op": "service_response", "service": service, "result": result}
        if id is not None:
            head["id"] = id
        if values_json is None:
            values_json = json.dumps(values, allow_nan=False)
        text = json.dumps(head)[:-1] + ',"values":' + values_json + "}"
        self._out.extend(self._wrap(text, compression, fragment_size))

    def send_call_service(self, service: str, id: str, args_json: str) -> None:
        """Forward a call to the client that provides ``service`` (§3.4.8)."""
        head = {"op": "call_service", "id": id, "service": service}
        self._out.append(json.dumps(head)[:-1] + ',"args":' + args_json + "}")

    def frames_to_send(self) -> list[str | bytes]:
        out, self._out = self._out, []
        return out


# -- field parsing ------------------------------------------------------------------------
def _field(
    obj: dict[str, Any],
    op: str,
    fid: str | None,
    name: str,
    kind: type | tuple[type, ...],
    *,
    required: bool = False,
    default: Any = None,
) -> Any:
    value = obj.get(name)
    if value is None:
        if required:
            raise OpError(f"{op}: field '{name}' is required", id=fid, op=op)
        return default
    if isinstance(value, bool) and kind is not bool and bool not in _as_tuple(kind):
        raise OpError(f"{op}: field '{name}' has the wrong type (boolean)", id=fid, op=op)
    if not isinstance(value, kind):
        want = " or ".join(_KIND_NAMES.get(k, k.__name__) for k in _as_tuple(kind))
        raise OpError(f"{op}: field '{name}' must be {want}", id=fid, op=op)
    return value


def _as_tuple(kind: type | tuple[type, ...]) -> tuple[type, ...]:
    return kind if isinstance(kind, tuple) else (kind,)


_KIND_NAMES = {str: "a string", dict: "an object", list: "an array", bool: "a boolean"}


def _name(obj: dict[str, Any], op: str, fid: str | None, key: str) -> str:
    value = _field(obj, op, fid, key, str, required=True)
    if not value.strip() or len(value) > 256:
        raise OpError(
            f"{op}: '{key}' must be a non-empty name of at most 256 characters", id=fid, op=op
        )
    return str(value)


def _int_field(
    obj: dict[str, Any],
    op: str,
    fid: str | None,
    name: str,
    *,
    required: bool = False,
    default: int | None = None,
    minimum: int = 0,
    maximum: int | None = None,
) -> int | None:
    value = _field(obj, op, fid, name, (int, float), required=required)
    if value is None:
        return default
    if isinstance(value, float) and not value.is_integer():  # also NaN and ±inf
        raise OpError(f"{op}: field '{name}' must be an integer", id=fid, op=op)
    if value < minimum:
        raise OpError(f"{op}: field '{name}' must be at least {minimum}", id=fid, op=op)
    if maximum is not None and value > maximum:
        raise OpError(f"{op}: field '{name}' must be at most {maximum}", id=fid, op=op)
    return int(value)


def _type(obj: dict[str, Any], op: str, fid: str | None, *, required: bool) -> str | None:
    raw = _field(obj, op, fid, "type", str, required=required)
    if raw is None:
        return None
    try:
        return normalise_type(raw)
    except BridgeError as err:
        raise OpError(f"{op}: {err.msg}", id=fid, op=op) from err


def _compression(obj: dict[str, Any], op: str, fid: str | None) -> str:
    value = _field(obj, op, fid, "compression", str, default="none")
    if value not in COMPRESSIONS:
        raise OpError(
            f"{op}: compression {value!r} is not one of {', '.join(COMPRESSIONS)}", id=fid, op=op
        )
    return str(value)


def _fragment_size(obj: dict[str, Any], op: str, fid: str | None) -> int | None:
    return _int_field(obj, op, fid, "fragment_size", minimum=MIN_FRAGMENT_SIZE)


def _bool(obj: dict[str, Any], op: str, fid: str | None, name: str, default: bool) -> bool:
    return bool(_field(obj, op, fid, name, bool, default=default))


def _p_advertise(obj: dict[str, Any], op: str, fid: str | None) -> ops.Op:
    return ops.Advertise(
        topic=_name(obj, op, fid, "topic"),
        type=_type(obj, op, fid, required=True) or "",
        id=fid,
        latch=_bool(obj, op, fid, "latch", False),
        queue_size=_int_field(obj, op, fid, "queue_size", default=100, maximum=MAX_QUEUE_LENGTH)
        or 100,
    )


def _p_unadvertise(obj: dict[str, Any], op: str, fid: str | None) -> ops.Op:
    return ops.Unadvertise(topic=_name(obj, op, fid, "topic"), id=fid)


def _issued(obj: dict[str, Any]) -> tuple[float | None, str | None]:
    """A ``publish``'s ``issued`` (a JSON number of Unix seconds) or None, and why it is
    not one (judged by the session: a bad stamp must not hold a stop back)."""
    value = obj.get("issued")
    if value is None:
        return None, None
    if isinstance(value, str):
        return None, "field 'issued' must be a number of Unix seconds"
    try:
        return parse_issued(value), None
    except BadIssued as exc:
        return None, f"field 'issued': {exc}"


def _p_publish(obj: dict[str, Any], op: str, fid: str | None) -> ops.Op:
    issued, issued_error = _issued(obj)
    return ops.Publish(
        topic=_name(obj, op, fid, "topic"),
        msg=_field(obj, op, fid, "msg", dict, required=True),
        id=fid,
        latch=_bool(obj, op, fid, "latch", False),
        issued=issued,
        issued_error=issued_error,
    )


def _p_subscribe(obj: dict[str, Any], op: str, fid: str | None) -> ops.Op:
    return ops.Subscribe(
        topic=_name(obj, op, fid, "topic"),
        id=fid,
        type=_type(obj, op, fid, required=False),
        throttle_rate_ms=_int_field(
            obj, op, fid, "throttle_rate", default=0, maximum=MAX_THROTTLE_RATE_MS
        )
        or 0,
        queue_length=_int_field(obj, op, fid, "queue_length", default=0, maximum=MAX_QUEUE_LENGTH)
        or 0,
        fragment_size=_fragment_size(obj, op, fid),
        compression=_compression(obj, op, fid),
    )


def _p_unsubscribe(obj: dict[str, Any], op: str, fid: str | None) -> ops.Op:
    return ops.Unsubscribe(topic=_name(obj, op, fid, "topic"), id=fid)


def _p_call_service(obj: dict[str, Any], op: str, fid: str | None) -> ops.Op:
    timeout = _field(obj, op, fid, "timeout", (int, float))
    if timeout is not None and not math.isfinite(timeout):
        raise OpError(f"{op}: field 'timeout' must be a finite number of seconds", id=fid, op=op)
    if timeout is not None and timeout > MAX_SERVICE_TIMEOUT_S:
        raise OpError(
            f"{op}: field 'timeout' must be at most {MAX_SERVICE_TIMEOUT_S:g} s", id=fid, op=op
        )
    if timeout is not None and timeout <= 0:
        timeout = None  # roslibjs: a non-positive timeout means none
    return ops.CallService(
        service=_name(obj, op, fid, "service"),
        args=_field(obj, op, fid, "args", (dict, list), default={}),
        id=fid,
        timeout_s=None if timeout is None else float(timeout),
        fragment_size=_fragment_size(obj, op, fid),
        compression=_compression(obj, op, fid),
    )


def _p_service_response(obj: dict[str, Any], op: str, fid: str | None) -> ops.Op:
    if fid is None:
        raise OpError("service_response: 'id' is required to route the response", op=op)
    return ops.ServiceResponse(
        service=str(_field(obj, op, fid, "service", str, default="")),
        id=fid,
        values=obj.get("values"),
        result=_bool(obj, op, fid, "result", True),
    )


def _p_advertise_service(obj: dict[str, Any], op: str, fid: str | None) -> ops.Op:
    return ops.AdvertiseService(
        service=_name(obj, op, fid, "service"),
        type=_type(obj, op, fid, required=True) or "",
        id=fid,
    )


def _p_unadvertise_service(obj: dict[str, Any], op: str, fid: str | None) -> ops.Op:
    return ops.UnadvertiseService(service=_name(obj, op, fid, "service"), id=fid)


def _p_set_level(obj: dict[str, Any], op: str, fid: str | None) -> ops.Op:
    level = _field(obj, op, fid, "level", str, required=True)
    if level not in LEVELS:
        choices = ", ".join(LEVELS)
        raise OpError(f"set_level: level {level!r} is not one of {choices}", id=fid, op=op)
    return ops.SetLevel(level=level, id=fid)


def _p_auth(obj: dict[str, Any], op: str, fid: str | None) -> ops.Op:
    token = obj.get("token", obj.get("mac"))
    if not isinstance(token, str) or not token:
        raise OpError("auth: field 'token' (or rosauth's 'mac') must be the token", id=fid, op=op)
    return ops.Auth(token=token, id=fid)


def _p_status(obj: dict[str, Any], op: str, fid: str | None) -> ops.Op:
    return ops.StatusIn(
        level=str(_field(obj, op, fid, "level", str, default="info")),
        msg=str(_field(obj, op, fid, "msg", str, default="")),
        id=fid,
    )


_PARSERS: dict[str, Callable[[dict[str, Any], str, str | None], ops.Op]] = {
    "advertise": _p_advertise,
    "unadvertise": _p_unadvertise,
    "publish": _p_publish,
    "subscribe": _p_subscribe,
    "unsubscribe": _p_unsubscribe,
    "call_service": _p_call_service,
    "service_response": _p_service_response,
    "advertise_service": _p_advertise_service,
    "unadvertise_service": _p_unadvertise_service,
    "set_level": _p_set_level,
    "auth": _p_auth,
    "status": _p_status,
}
