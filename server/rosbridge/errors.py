"""Errors of the rosbridge endpoint; each becomes a ``status`` message carrying the request's id.

BridgeError                 base; ``.msg`` is what the client reads, ``.id`` the request's id
├── FrameError              the frame itself is unusable (not JSON, not an object, no ``op``)
│   └── FrameTooLarge       over the per-frame byte limit (Settings.max_frame_bytes)
├── OpError                 a known op with a missing or wrongly typed field
│   └── UnknownOp           an op this server does not implement
├── MessageError            a ``msg``/``args`` does not match its ROS type
├── NotFoundError           unknown topic, service or message type
├── RefusedError            security: the connection's role may not do this
│   └── NotAuthenticated    no valid token yet
└── LimitError              the per-connection rate limit was exceeded
    ├── BudgetExceeded      decoding the frame would cost more than its budget (budget.py)
    └── DecoderBusy         the decoding workers' queue is full; the frame was not decoded
"""

from __future__ import annotations


class BridgeError(Exception):
    """Base of the rosbridge errors; ``msg`` is shown to the client in a ``status`` message."""

    def __init__(self, msg: str, *, id: str | None = None, op: str | None = None) -> None:
        super().__init__(msg)
        self.msg = msg
        self.id = id
        self.op = op


class FrameError(BridgeError):
    pass


class FrameTooLarge(FrameError):
    pass


class OpError(BridgeError):
    pass


class UnknownOp(OpError):
    pass


class MessageError(BridgeError):
    pass


class NotFoundError(BridgeError):
    pass


class RefusedError(BridgeError):
    pass


class NotAuthenticated(RefusedError):
    pass


class LimitError(BridgeError):
    pass


class BudgetExceeded(LimitError):
    pass


class DecoderBusy(LimitError):
    pass
