"""Exceptions of the flight controller (drone/control).

::

    ControlError
    ├── GainError (ValueError)        a gain, limit or period that is negative, zero or NaN
    └── LoopStateError (RuntimeError) ControlLoop started twice or stepped after stop()
"""

from __future__ import annotations


class ControlError(Exception):
    """Base of every error raised by ``drone.control``."""


class GainError(ControlError, ValueError):
    """A controller gain, limit or period is not a finite value in its allowed range."""


class LoopStateError(ControlError, RuntimeError):
    """The control loop was used in a state that does not allow it (e.g. started twice)."""
