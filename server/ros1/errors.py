"""Errors of the ROS 1 codec.

Ros1Error
├── UnknownType   a type (or a type it contains) has no definition
├── EncodeError   a message does not fit its type (the message names the field)
└── DecodeError   bytes are not a message of the type (truncated, bad length, bad UTF-8)
"""

from __future__ import annotations


class Ros1Error(Exception):
    """Base of the ROS 1 codec's errors."""


class UnknownType(Ros1Error):
    pass


class EncodeError(Ros1Error):
    pass


class DecodeError(Ros1Error):
    pass
