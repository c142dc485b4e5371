"""Where ``serve``'s simulators listen: free loopback addresses, chosen before they start.

Each simulated drone of a console listens on a loopback address of its own with the drone's
standard ports (``drone.sim.server.sim_endpoint``): 127.0.0.2, 127.0.0.3 … A second console on
the same machine would find its first console's simulators there. ``serve`` looks first: from
the configured address (``UAVC_SIM_BASE_ADDR``, 127.0.0.2 by default) it moves its simulators to
the first block of addresses whose sockets are all free and says so in one line; an address
given with ``--sim-addr`` is used as it is, or ``serve`` refuses to start, in one line naming
what is taken.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from drone.sim.server import in_use, sim_endpoint, sim_sockets
from server.settings import Settings, SettingsError

SIM_KINDS = ("sim", "sim-mavlink")  # server.vehicles.mavlink_stack.SIM_MAVLINK


@dataclass(frozen=True)
class SimChoice:
    """The first simulator's address, and the line that says why it moved ("" if it did not)."""

    base: str
    note: str = ""


def taken(base: str, kinds: Sequence[str], settings: Settings) -> str | None:
    """What is in use among the sockets the simulators of ``kinds`` (one ``--drone`` entry per
    drone) would bind from ``base`` ("UDP 5554 on 127.0.0.2"), or None when all are free.

    Raises:
        SettingsError: an address cannot be bound at all (not a local address).
    """
    for index, kind in enumerate(kinds):
        if kind not in SIM_KINDS:
            continue
        addr, ports = sim_endpoint(index, base)
        sockets = [("tcp", settings.mavlink_sim_port)] if kind != "sim" else sim_sockets(ports)
        try:
            why = in_use(addr, sockets)
        except OSError as exc:
            raise SettingsError(f"the simulator address {addr} cannot be used: {exc}") from None
        if why is not None:
            return why
    return None


def choose_sim_base(settings: Settings, kinds: Sequence[str], *, fixed: bool) -> SimChoice:
    """Where this console's simulators go (see the module docstring).

    Args:
        kinds: each drone's ``--drone`` entry; only ``sim`` and ``sim-mavlink`` bind anything.
        fixed: the address was given with ``--sim-addr``: use it or refuse.
    Raises:
        SettingsError: ``fixed`` and taken, no free block of addresses, or not an IPv4
            loopback address of the form ``127.a.b.c``.
    """
    base = settings.sim_base_addr
    parts = base.split(".")
    if len(parts) != 4 or parts[0] != "127" or not all(p.isdigit() for p in parts):
        raise SettingsError(f"the simulator address must be a 127.x.y.z loopback address: {base}")
    why = taken(base, kinds, settings)
    if why is None:
        return SimChoice(base)
    first = int(parts[3])
    free = None
    for last in range(first + 1, 256 - max(1, len(kinds))):
        candidate = ".".join([*parts[:3], str(last)])
        if taken(candidate, kinds, settings) is None:
            free = candidate
            break
    if fixed or free is None:
        hint = f"; e.g. --sim-addr {free} is free" if free else ""
        raise SettingsError(
            f"the simulator address {base} is taken ({why} is in use: another console?); "
            f"choose another with --sim-addr{hint}"
        )
    return SimChoice(
        free,
        f"the simulator address {base} is taken ({why} is in use: another console?); this "
        f"console's simulators are on {free} (--sim-addr chooses)",
    )
