"""Inputs bench/fuzz.py found to crash a parser (issue 14's fuzz campaign), each now a test."""

from __future__ import annotations

import base64
import json

import pytest

from server.rosbridge.protocol import BridgeProtocol

# CBOR frames whose ``id`` is a byte string or a CBOR simple value: building the status error
# raised TypeError (json.dumps of bytes), caught only by the defensive catch-all.
CBOR_CRASHES = [
    "o2JvcGt1bnN1YnNjcmliZWV0b3BpY2IvYWJpZE5hTmJzMWt1bnN1YnNjcmliZWV0b3BpY2IvYWJpZE5hTmJzMQ==",
    "o2JvcGt1bnN1YnNjcmliZWV0b3BpY2IvYWJpZOJzMQ==",
    "pWJvcGxjYWxsX3NlcnZpY2ViaWRJbmZpbml0eWFjZ3NlcnZpY2VuL3Jvc2FwaS90b3BpY3NkYXJnc6BndGltZW91dAI=",
    "pWJvcGhmcmFnbWVudGJpZEFmZGRhdGFmeyJvcCI6Y251bQBldG90YWwC",
]


@pytest.mark.parametrize("frame", CBOR_CRASHES)
def test_cbor_ids_of_any_type_are_answered(frame: str) -> None:
    proto = BridgeProtocol()
    proto.receive_bytes(base64.b64decode(frame), 0.0)
    for out in proto.frames_to_send():
        assert isinstance(out, str)
        assert "could not be handled" not in json.loads(out)["msg"]
