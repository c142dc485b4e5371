"""Decoding inbound frames, within their budget: pure functions a worker runs (sans-I/O).

:class:`BridgeProtocol` decodes small frames itself and hands everything that can be expensive
to its driver as a :class:`DecodeRequest`: a large frame (JSON or CBOR), the text of a large
reassembled ``fragment`` message, and every ``png`` frame's image. :func:`run_decode` is what
a worker does with one (``server.rosbridge.decoder`` runs it in a small process pool), and
``BridgeProtocol.receive_decoded`` takes the result back. Every path checks the budgets of
``server.rosbridge.budget``; nothing here reads a socket or the wall clock.
"""

from __future__ import annotations

import base64
import binascii
import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

import cbor2

from server.rosbridge.budget import (
    PNG_HEADER_BYTES,
    DecodeBudget,
    PngError,
    check_png_budget,
    check_values,
    json_values_bound,
    png_header,
    png_text,
)
from server.rosbridge.errors import BudgetExceeded, FrameError, FrameTooLarge, OpError

Kind = Literal["frame", "text", "png"]


@dataclass(frozen=True)
class DecodeRequest:
    """Decoding the protocol leaves to a worker.

    Attributes:
        kind: ``frame`` (a whole frame: JSON text or CBOR bytes), ``text`` (the JSON text of a
            reassembled fragment message) or ``png`` (a ``png`` op's base64 ``data``).
        payload: that frame, text or data.
        id: the request's id where known (a ``png``/``fragment`` op's; a frame's from
            ``budget.peek_id``), for the status that answers a refusal.
        depth: nesting of ``fragment``/``png`` this came from (0: a frame as received).
        allow_png: a ``png`` frame may be inflated (the connection's role may send one).
    """

    kind: Kind
    payload: str | bytes
    id: str | None = None
    depth: int = 0
    allow_png: bool = True


@dataclass
class DecodeWork:
    """What a decoding did, for the decoder's statistics."""

    png_inflated: bool = False


def run_decode(
    request: DecodeRequest,
    budget: DecodeBudget,
    max_frame_bytes: int,
    *,
    clock: Callable[[], float] = time.thread_time,
    work: DecodeWork | None = None,
) -> Any:
    """The object ``request`` holds, decoded within ``budget`` (a ``png`` is inflated and its
    text parsed); thread-safe, and picklable arguments for a process pool.

    Raises:
        FrameTooLarge: over ``max_frame_bytes``.
        FrameError: not JSON / CBOR, or a ``png`` holding another ``png`` or ``fragment``.
        OpError: a ``png`` whose data cannot be decoded.
        BudgetExceeded: over ``budget``.
    """
    work = work if work is not None else DecodeWork()
    if request.kind == "png":
        if not isinstance(request.payload, str):
            raise OpError("png: field 'data' must be a string", id=request.id, op="png")
        obj = expand_png(request.payload, request.id, budget, clock=clock, work=work)
    elif request.kind == "text":
        obj = parse_json(request.payload, "reassembled frame is not valid JSON", request.id)
    else:
        obj = decode_frame(request.payload, max_frame_bytes)
        if request.allow_png and isinstance(obj, dict) and obj.get("op") == "png":
            fid = frame_id(obj)
            data = obj.get("data")
            if not isinstance(data, str):
                raise OpError("png: field 'data' must be a string", id=fid, op="png")
            obj = expand_png(data, fid, budget, clock=clock, work=work)
    check_values(obj, budget, request.id if not isinstance(obj, dict) else frame_id(obj))
    return obj


def decode_frame(payload: str | bytes, max_frame_bytes: int) -> Any:
    """The object one frame holds: JSON for text, CBOR for binary (no ``png`` expansion).

    Raises:
        FrameTooLarge: over ``max_frame_bytes``.
        FrameError: not JSON, or not one CBOR map.
    """
    if len(payload) > max_frame_bytes:
        raise FrameTooLarge(
            f"frame of {len(payload)} bytes exceeds the limit of {max_frame_bytes} bytes"
        )
    if isinstance(payload, str):
        return parse_json(payload, "invalid JSON", None)
    try:
        obj = cbor2.loads(payload)
    except Exception as exc:
        raise FrameError(f"binary frames must hold one CBOR object: {exc}") from exc
    if not isinstance(obj, dict):  # cbor2 < 6 returns a lone break marker (0xff) as a value
        raise FrameError(f"binary frames must hold one CBOR map, not {type(obj).__name__}")
    return obj


def parse_json(text: str | bytes, what: str, fid: str | None) -> Any:
    """``json.loads`` with its errors as :class:`FrameError` (``what: …``)."""
    try:
        return json.loads(text)
    except (ValueError, RecursionError) as exc:
        raise FrameError(f"{what}: {exc}", id=fid) from exc


def expand_png(
    data: str,
    fid: str | None,
    budget: DecodeBudget,
    *,
    clock: Callable[[], float] = time.thread_time,
    work: DecodeWork | None = None,
) -> Any:
    """The op inside a ``png`` op's base64 ``data`` (ROSBRIDGE_PROTOCOL.md §3.3.2).

    Raises:
        OpError: the data is not base64 of a PNG of rosbridge's shape.
        BudgetExceeded: over ``budget`` (pixels, bytes, work, or values in its text).
        FrameError: its text is not JSON, or holds another ``png`` or ``fragment``.
    """
    try:
        png = base64.b64decode(data, validate=True)
    except (binascii.Error, ValueError) as exc:
        raise OpError(f"png: cannot decode data: {exc}", id=fid, op="png") from exc
    try:
        check_png_budget(png_header(png[:PNG_HEADER_BYTES]), budget)
        if work is not None:
            work.png_inflated = True
        text = png_text(png, budget, clock=clock).rstrip("\n")
    except PngError as exc:
        raise OpError(f"png: cannot decode data: {exc}", id=fid, op="png") from exc
    except BudgetExceeded as err:
        err.id = err.id if err.id is not None else fid
        raise
    bound = json_values_bound(text)
    if bound > budget.max_values:
        raise BudgetExceeded(
            f"png: its text may hold {bound} values, over the decoding budget of "
            f"{budget.max_values} a frame; refused before parsing",
            id=fid,
            op="png",
        )
    obj = parse_json(text, "reassembled frame is not valid JSON", fid)
    if isinstance(obj, dict) and obj.get("op") in ("png", "fragment"):
        raise FrameError("png frames may not hold another png or fragment", id=fid)
    return obj


def frame_id(obj: dict[str, Any]) -> str | None:
    """A frame's ``id`` as text (non-string ids as JSON, or their repr when not JSON-able)."""
    raw = obj.get("id")
    if raw is None:
        return None
    if isinstance(raw, str):
        return raw
    try:
        return json.dumps(raw)
    except (TypeError, ValueError):  # CBOR bytes, simple values, tags (found by bench/fuzz.py)
        return repr(raw)[:200]
