"""ROS 1 message definitions and binary serialisation for the graph's types.

Foxglove (and every ROS 1 tool) reads messages as ``ros1msg``: a ``gendeps --cat`` definition
text plus the ROS 1 wire serialisation. The recorder writes MCAP channels in that form and the
rosbridge endpoint sends it for ``compression: "cbor-raw"``.
"""

from server.ros1.codec import MessageCodec, codec_for
from server.ros1.definitions import definition, has_definition, ros1_fields
from server.ros1.errors import DecodeError, EncodeError, Ros1Error, UnknownType

__all__ = [
    "DecodeError",
    "EncodeError",
    "MessageCodec",
    "Ros1Error",
    "UnknownType",
    "codec_for",
    "definition",
    "has_definition",
    "ros1_fields",
]
