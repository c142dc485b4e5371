"""Errors of the bus.

BusError
├── KeySegmentError  a fleet or drone name that cannot be one segment of a key
├── PayloadError     bytes that are not a valid payload of the key's schema
├── BusConfigError   an endpoint or credential that cannot be used
└── NoReply          a command nobody answered
"""

from __future__ import annotations


class BusError(Exception):
    """Base of the bus's errors."""


class KeySegmentError(BusError, ValueError):
    """A fleet or drone name that cannot be one segment of a key (``/``, ``*``, ``$``…)."""


class PayloadError(BusError, ValueError):
    """A payload that does not decode to its key's schema; the message says why."""


class BusConfigError(BusError, ValueError):
    """An endpoint or credential that cannot be used; the message names it."""


class NoReply(BusError):
    """A command no vehicle answered: none on the bus by that name, the router refused the
    query (not a pilot), or the answer did not come in time. Nothing was done."""
