"""The pilot lease as a vehicle holds it (sans-I/O; time passed in).

Each vehicle keeps its own lease, so there is one lease per drone across every console on the
bus. It is held by a console (its pilots take turns under that console's own pilot lease); the
status shows the holder as ``pilot@console`` (:attr:`~drone.bus.commands.Command.holder`), the
pilot who last commanded under it. Stops (land,
hover, emergency), reads and an utterance that asks only stops need no lease (DESIGN §5: any
pilot may land); any other command takes a free lease, renews its holder's, and is refused
while another holder's is live. A lease its holder has not used for ``idle_s`` lapses, so a
console that went away does not keep the drone for ever; ``take_over`` takes it explicitly.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from drone.bus.commands import READ_OPS, STOP_ACTIONS, Command

# A lease unused this long lapses (seconds): long enough for a pilot who pauses to think,
# short enough that a console that crashed frees its drones within the same minute.
LEASE_IDLE_S = 60.0


@dataclass(frozen=True)
class LeaseVerdict:
    allowed: bool
    reason: str = ""


class VehicleLease:
    """See the module docstring. ``actions_of(text)``: the actions an utterance asks."""

    def __init__(
        self,
        actions_of: Callable[[str], set[str]] | None = None,
        idle_s: float = LEASE_IDLE_S,
    ) -> None:
        self.actions_of = actions_of
        self.idle_s = idle_s
        self.holder: str | None = None  # pilot@console, for people to read
        self.console: str | None = None  # who holds it
        self.since: float | None = None
        self.used: float | None = None

    def current(self, now: float) -> str | None:
        """The live holder (None: free, or lapsed)."""
        if self.holder is not None and self.used is not None and now - self.used > self.idle_s:
            self._free()
        return self.holder

    def _free(self) -> None:
        self.holder = self.console = self.since = self.used = None

    def exempt(self, command: Command) -> bool:
        """Whether ``command`` needs no lease (stops, reads, an utterance of stops only)."""
        if command.op in READ_OPS or command.is_stop:
            return True
        if command.op == "utterance" and self.actions_of is not None:
            try:
                actions = self.actions_of(str(command.args.get("text", "")))
            except Exception:  # an NLU that cannot read it: judged as a command
                return False
            return bool(actions) and actions <= STOP_ACTIONS
        return False

    def judge(self, command: Command, now: float) -> LeaseVerdict:
        """Whether ``command`` may run now; a command that runs under the lease takes or
        renews it (``args.take_over``: takes it from another holder)."""
        if command.op == "lease":
            return self._lease_op(command, now)
        if self.exempt(command):
            return LeaseVerdict(True)
        holder = self.current(now)
        if self._may_take(command):
            self._hold(command, now)
            return LeaseVerdict(True)
        return LeaseVerdict(False, self._held_by(holder, now))

    def _may_take(self, command: Command) -> bool:
        free = self.console in (None, command.console)
        return free or command.args.get("take_over") is True

    def _hold(self, command: Command, now: float) -> None:
        if self.console != command.console:
            self.console, self.since = command.console, now
        self.holder = command.holder
        self.used = now

    def _held_by(self, holder: str | None, now: float) -> str:
        since = 0.0 if self.since is None else now - self.since
        return (
            f"the pilot lease is held by {holder} (for {since:.0f} s); only land, hover and "
            "emergency are taken from other pilots (take over explicitly to command)"
        )

    def _lease_op(self, command: Command, now: float) -> LeaseVerdict:
        action = command.args.get("action", "status")
        holder = self.current(now)
        if action == "status":
            return LeaseVerdict(True)
        if action == "acquire":
            if self._may_take(command):
                self._hold(command, now)
                return LeaseVerdict(True)
            return LeaseVerdict(False, self._held_by(holder, now))
        if action == "release":
            if holder is not None and self.console == command.console:
                self._free()
            return LeaseVerdict(True)
        return LeaseVerdict(False, f"lease action {action!r} is not status, acquire or release")
