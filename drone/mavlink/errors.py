"""Errors of the MAVLink package.

::

    MavlinkError
    ├── ConnectionStringError   a connection string mavutil/MAVProxy would not write
    ├── FrameError              bytes that are not a MAVLink 2 frame we accept (counted, not fatal)
    ├── CommandFailed           a command the vehicle refused, or never answered
    │   └── CommandTimeout      no COMMAND_ACK after every retry
    ├── MissionError            the mission upload was refused or timed out
    ├── NotConnected            no vehicle heard yet (or the link is lost)
    ├── SigningKeyError         the signing passphrase file cannot be made, read or trusted
    └── InsecureLinkError       an unsigned simulator asked to listen beyond loopback
"""

from __future__ import annotations


class MavlinkError(Exception):
    """Base of every error this package raises."""


class ConnectionStringError(MavlinkError, ValueError):
    """A connection string that is not ``tcp:HOST:PORT``, ``udpin:…``, ``udpout:…`` or a serial
    device (``/dev/ttyUSB0,57600``)."""


class FrameError(MavlinkError):
    """Bytes that are not an acceptable MAVLink 2 frame."""


class CommandFailed(MavlinkError):
    """The vehicle refused a command (DENIED, TEMPORARILY_REJECTED, FAILED, UNSUPPORTED…)."""

    def __init__(self, command: str, result: str, reason: str | None = None) -> None:
        self.command = command
        self.result = result
        self.reason = reason
        why = f": {reason}" if reason else ""
        super().__init__(f"the vehicle refused {command} ({result}){why}")


class CommandTimeout(CommandFailed):
    """No COMMAND_ACK for a command after its retries."""

    def __init__(self, command: str, attempts: int) -> None:
        self.attempts = attempts
        CommandFailed.__init__(self, command, "NO_ANSWER")
        self.args = (f"the vehicle did not answer {command} after {attempts} attempts",)


class MissionError(MavlinkError):
    """A mission upload that the vehicle refused or that timed out."""


class NotConnected(MavlinkError):
    """No vehicle is connected (never heard, or its heartbeat stopped)."""


class SigningKeyError(MavlinkError):
    """The MAVLink signing passphrase file cannot be made or read, is readable by others, or
    holds no usable passphrase (``drone.mavlink.signing``)."""


class InsecureLinkError(MavlinkError, ValueError):
    """An unsigned (``--insecure``) simulator was asked to listen on a non-loopback address:
    anyone who can reach it could arm it, take off and cut its motors."""
