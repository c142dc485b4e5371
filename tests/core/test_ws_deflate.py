"""Per-message deflate that sends camera frames uncompressed (server/http/ws_deflate.py).

websockets' sans-I/O client and server protocols shake hands in memory: the server with the
console's extension factories, the client with websockets' stock deflate (as a browser offers
it). Large messages must leave with RSV1 clear and the payload as it was;
small ones compressed; and the peer must read every message, in any order (the compression
context survives plain messages in between).
"""

from __future__ import annotations

import json
import os

from websockets.client import ClientProtocol
from websockets.extensions.permessage_deflate import (
    ClientPerMessageDeflateFactory,
    ServerPerMessageDeflateFactory,
)
from websockets.frames import Frame, Opcode
from websockets.server import ServerProtocol
from websockets.uri import parse_uri

from server.http.ws_deflate import (
    PLAIN_BYTES,
    PlainLargeDeflate,
    plain_large,
)


def pair(server_ext: list, client_ext: list) -> tuple[ServerProtocol, ClientProtocol]:
    server = ServerProtocol(extensions=server_ext)
    client = ClientProtocol(parse_uri("ws://127.0.0.1/rosbridge"), extensions=client_ext)
    request = client.connect()
    client.send_request(request)
    server.receive_data(b"".join(client.data_to_send()))
    (req,) = server.events_received()
    server.send_response(server.accept(req))
    client.receive_data(b"".join(server.data_to_send()))
    client.events_received()
    return server, client


def raw_frames(data: bytes) -> list[Frame]:
    """Server frames as they are on the wire (RFC 6455 §5.2, unmasked): RSV1 and payload as
    sent, decoded by no extension."""
    out = []
    i = 0
    while i < len(data):
        b0, b1 = data[i], data[i + 1]
        n, i = b1 & 0x7F, i + 2
        if n == 126:
            n, i = int.from_bytes(data[i : i + 2], "big"), i + 2
        elif n == 127:
            n, i = int.from_bytes(data[i : i + 8], "big"), i + 8
        out.append(Frame(Opcode(b0 & 0x0F), data[i : i + n], bool(b0 & 0x80), bool(b0 & 0x40)))
        i += n
    return out


def image_text(n: int) -> str:
    return json.dumps(
        {
            "op": "publish",
            "topic": "/ardrone/image_raw/compressed",
            "msg": {"data": os.urandom(n).hex()},
        }
    )


def test_the_server_sends_large_messages_plain_and_small_ones_deflated() -> None:
    server, client = pair(
        plain_large([ServerPerMessageDeflateFactory()]), [ClientPerMessageDeflateFactory()]
    )
    assert isinstance(server.extensions[0], PlainLargeDeflate)
    telemetry = json.dumps({"op": "publish", "topic": "/ardrone/navdata", "msg": {"x": [0] * 200}})
    texts = [telemetry, image_text(PLAIN_BYTES), telemetry, image_text(30_000), telemetry]
    for t in texts:
        server.send_text(t.encode())
    wire = b"".join(server.data_to_send())
    frames = raw_frames(wire)
    assert [f.rsv1 for f in frames] == [True, False, True, False, True]
    assert frames[1].data == texts[1].encode()  # as it was, not one byte deflated
    assert len(frames[0].data) < len(telemetry) / 4
    client.receive_data(wire)
    got = [e.data.decode() for e in client.events_received()]
    assert got == texts


def test_a_fragmented_large_message_stays_plain_to_its_last_frame() -> None:
    server, client = pair(
        plain_large([ServerPerMessageDeflateFactory()]), [ClientPerMessageDeflateFactory()]
    )
    big = image_text(20_000).encode()
    server.send_text(big[:20_000], fin=False)
    server.send_continuation(big[20_000:], fin=True)
    server.send_text(b"after " * 100)
    wire = b"".join(server.data_to_send())
    frames = raw_frames(wire)
    assert [(f.opcode, f.rsv1) for f in frames] == [
        (Opcode.TEXT, False),
        (Opcode.CONT, False),
        (Opcode.TEXT, True),
    ]
    client.receive_data(wire)
    first, rest, after = client.events_received()  # frames: the message in two, then one
    assert bytes(first.data + rest.data) == big and after.data == b"after " * 100
