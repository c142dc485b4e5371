"""``compression: "cbor-raw"``: the message as ROS 1 bytes in a CBOR frame, as rosbridge_suite
sends it and Foxglove's Rosbridge connection subscribes to every topic.

rosbridge_suite (ROS 1, ``rosbridge_library/capabilities/subscribe.py`` and
``internal/subscribers.py``): for a cbor-raw subscription the outgoing ``publish`` carries
``msg: {"bytes": <serialised message>, "secs": <receipt time>, "nsecs": …}`` and the whole
frame is CBOR (a binary WebSocket frame), ``bytes`` a CBOR byte string. Foxglove reads
``msg.bytes`` with a ROS 1 ``MessageReader`` built from the ``topics_and_raw_types``
definition, so the bytes here come from the same definitions (``server.ros1``).
"""

from __future__ import annotations

import math
import time
from typing import Any

import cbor2

from server.ros1 import Ros1Error, codec_for, has_definition


def can_encode(type_name: str) -> bool:
    """True when ``type_name`` has a full ROS 1 definition (else cbor-raw is refused)."""
    return has_definition(type_name)


def raw_message(type_name: str, msg: dict[str, Any], now: float | None = None) -> dict[str, Any]:
    """The ``msg`` of a cbor-raw ``publish``: ``{"bytes", "secs", "nsecs"}``.

    Raises:
        Ros1Error: the type has no definition, or the message does not fit it.
    """
    t = time.time() if now is None else now
    secs = math.floor(t)
    return {
        "bytes": codec_for(type_name).encode(msg),
        "secs": int(secs),
        "nsecs": int((t - secs) * 1e9) % 1_000_000_000,
    }


def publish_frame(
    topic: str, type_name: str, msg: dict[str, Any], now: float | None = None
) -> bytes:
    """One binary (CBOR) frame: ``{"op": "publish", "topic", "msg": {bytes, secs, nsecs}}``.

    Raises:
        Ros1Error: as :func:`raw_message`.
    """
    body = {"op": "publish", "topic": topic, "msg": raw_message(type_name, msg, now)}
    return cbor2.dumps(body)


__all__ = ["Ros1Error", "can_encode", "publish_frame", "raw_message"]
