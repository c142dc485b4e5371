"""Per-message deflate that leaves large messages uncompressed (camera frames).

A camera frame is a 40–60 KB JPEG in base64 text: deflate wins back little more than base64's
third and costs ~1 ms of zlib per frame and per hop, on the event loop that carries every
drone's telemetry and commands. With two drones at 15 fps over rosbridge links and out to a
page, deflate was a third of the console's event loop under load; the loop fell behind and
frames queued for seconds (bench/fleet_camera.py). RFC 7692 §6 lets a sender choose per
message: a message sent with RSV1 clear is not compressed and the peer's decompressor is not
touched (§6.2). So messages over ``PLAIN_BYTES`` go out as they are; telemetry, replies and
service calls, small and repetitive, stay compressed.

:class:`PlainLargeServerFactory` replaces websockets' server factory (uvicorn's, via
``server.http.ws_guard``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from websockets.extensions.base import Extension, ServerExtensionFactory
from websockets.extensions.permessage_deflate import (
    PerMessageDeflate,
    ServerPerMessageDeflateFactory,
)
from websockets.frames import CTRL_OPCODES, Frame, Opcode
from websockets.typing import ExtensionParameter

# Larger messages are sent uncompressed: above any telemetry message (navdata ~2 KB), below a
# camera frame (~40 KB).
PLAIN_BYTES = 16 * 1024


class PlainLargeDeflate(PerMessageDeflate):
    """``PerMessageDeflate`` sending messages over ``plain_bytes`` uncompressed."""

    def __init__(self, *args: Any, plain_bytes: int = PLAIN_BYTES, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.plain_bytes = plain_bytes
        self._plain = False  # the message being sent (its first frame decided) goes plain

    @classmethod
    def like(cls, ext: PerMessageDeflate, plain_bytes: int = PLAIN_BYTES) -> PlainLargeDeflate:
        """The same negotiated parameters as ``ext``."""
        return cls(
            ext.remote_no_context_takeover,
            ext.local_no_context_takeover,
            ext.remote_max_window_bits,
            ext.local_max_window_bits,
            ext.compress_settings,
            plain_bytes=plain_bytes,
        )

    def encode(self, frame: Frame) -> Frame:
        if frame.opcode in CTRL_OPCODES:
            return frame
        if frame.opcode is not Opcode.CONT:
            self._plain = len(frame.data) > self.plain_bytes
        if self._plain:
            return frame  # RSV1 clear: not compressed (RFC 7692 §6)
        return super().encode(frame)


class PlainLargeServerFactory(ServerPerMessageDeflateFactory):
    """websockets' server factory, negotiating :class:`PlainLargeDeflate`."""

    @classmethod
    def like(cls, factory: ServerPerMessageDeflateFactory) -> PlainLargeServerFactory:
        return cls(
            factory.server_no_context_takeover,
            factory.client_no_context_takeover,
            factory.server_max_window_bits,
            factory.client_max_window_bits,
            factory.compress_settings,
            factory.require_client_max_window_bits,
        )

    def process_request_params(
        self, params: Sequence[ExtensionParameter], accepted_extensions: Sequence[Extension]
    ) -> tuple[list[ExtensionParameter], PerMessageDeflate]:
        response, ext = super().process_request_params(params, accepted_extensions)
        return response, PlainLargeDeflate.like(ext)


def plain_large(factories: Sequence[ServerExtensionFactory]) -> list[ServerExtensionFactory]:
    """``factories`` with each per-message deflate factory a :class:`PlainLargeServerFactory`."""
    return [
        PlainLargeServerFactory.like(f) if isinstance(f, ServerPerMessageDeflateFactory) else f
        for f in factories
    ]
