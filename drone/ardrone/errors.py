"""Exceptions of the AR.Drone 2.0 codecs and driver.

Every error here is a ``ValueError`` or ``RuntimeError`` subclass so callers that only care about
"bad input" can catch the builtin, and callers that care can catch the precise class::

    ARDroneError
    ├── ATError (ValueError)            AT command codec (drone/ardrone/at.py)
    │   ├── ATEncodeError               argument cannot be put on the wire (range, quote, size)
    │   └── ATParseError                a datagram is not a well-formed list of AT commands
    ├── NavdataError (ValueError)       navdata codec (drone/ardrone/navdata.py)
    │   ├── NavdataMagicError           first u32 is not 0x55667788
    │   ├── NavdataTruncatedError       packet shorter than its header or an option claims
    │   ├── NavdataChecksumError        checksum option missing or wrong
    │   └── NavdataOptionSizeError      option size < 4, or a known option with the wrong size
    ├── VideoError (ValueError)         PaVE / H.264 (drone/ardrone/video.py)
    └── DriverError (RuntimeError)      driver misuse (drone/ardrone/driver.py)
        └── DriverNotStartedError       command issued before ``start()`` / after ``stop()``
"""

from __future__ import annotations


class ARDroneError(Exception):
    """Base of every error raised by ``drone.ardrone``."""


class ATError(ARDroneError, ValueError):
    """AT command codec error."""


class ATEncodeError(ATError):
    """An argument cannot be encoded (out of range, contains a quote or CR, datagram too big)."""


class ATParseError(ATError):
    """A datagram is not a well-formed sequence of ``AT*NAME=seq[,args]\\r`` commands."""


class NavdataError(ARDroneError, ValueError):
    """Navdata packet cannot be decoded."""


class NavdataMagicError(NavdataError):
    """The header is not 0x55667788 (Developer Guide §7.1.1)."""


class NavdataTruncatedError(NavdataError):
    """The packet ends before its header or before the end of an option."""


class NavdataChecksumError(NavdataError):
    """The checksum option is missing or does not match the sum of the preceding bytes."""


class NavdataOptionSizeError(NavdataError):
    """An option's size is below 4 bytes, or a known option has the wrong size."""


class VideoError(ARDroneError, ValueError):
    """PaVE framing or H.264 decode error."""


class DriverError(ARDroneError, RuntimeError):
    """The driver was used in a way it does not support."""


class DriverNotStartedError(DriverError):
    """A command was issued while the driver is not running."""
