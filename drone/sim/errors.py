"""Exceptions of the simulator.

::

    SimError
    ├── FaultError (ValueError)     inject_fault() with an unknown kind or bad parameters
    ├── SimConfigError (ValueError) bad simulator construction (bounds, start pose, speed, ports)
    └── AddressInUse (OSError)      a simulator's socket is already bound (another simulator)

World files raise ``drone.sim.world.WorldError`` (a ``ValueError``) — owned by the world module.
"""

from __future__ import annotations


class SimError(Exception):
    """Base of the simulator's own errors."""


class FaultError(SimError, ValueError):
    """An injected fault has an unknown kind or invalid parameters."""


class SimConfigError(SimError, ValueError):
    """The simulator was constructed with values it cannot use."""


class AddressInUse(SimError, OSError):
    """A socket the simulator binds is already in use on its address (most often another
    console's simulator); the message names the address, the port and the protocol."""
