"""Who a sentence is for: "uav2 take off", "drone 2, fly to marker 3", "all drones land".

An operator of a fleet names the drone at the start of the sentence, as a radio call does
("uav2, land"). This module finds that address and hands back the rest of the sentence for the
NLU. Pure text in, :class:`Address` out; the dialog manager decides who answers.

Names are the server's drone names (``uav1``, ``uav2``, … DESIGN §4); "drone 2", "uav two",
"number 2" and "quad 2" all mean ``uav2``. "all drones", "every drone", "everyone", "both
drones", "all of you" address the whole fleet.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

# Spoken numbers a fleet name may carry (fleets here are small: uav1 … uav12).
_WORDS = {
    "one": 1,
    "two": 2,
    "three": 3,
    "four": 4,
    "five": 5,
    "six": 6,
    "seven": 7,
    "eight": 8,
    "nine": 9,
    "ten": 10,
    "eleven": 11,
    "twelve": 12,
}
_NUM = r"(?P<num>\d{1,3}|" + "|".join(sorted(_WORDS, key=len, reverse=True)) + r")"
_GREETING = r"(?:(?:hey|ok|okay|hello|hi|attention)\s+)?"
_ONE = re.compile(
    rf"^\s*{_GREETING}(?:uav|drone|quad|quadcopter|copter|unit|number)\s*-?\s*{_NUM}\b\s*[,:;.!]?\s*(?P<rest>.*)$",
    re.IGNORECASE | re.DOTALL,
)
_ALL = re.compile(
    rf"^\s*{_GREETING}(?:all\s+(?:of\s+the\s+|the\s+)?(?:drones|uavs|units|quads|copters)|"
    r"every\s+(?:drone|uav|unit)|everyone|everybody|all\s+of\s+you|both\s+(?:drones|uavs)|"
    r"fleet|whole\s+fleet|the\s+fleet)\b\s*[,:;.!]?\s*(?P<rest>.*)$",
    re.IGNORECASE | re.DOTALL,
)


@dataclass(frozen=True)
class Address:
    """The addressee of one sentence.

    ``names`` is None when the sentence names nobody (it goes to the drone the console has
    selected); ``everyone`` is True for "all drones …"; ``text`` is the sentence without the
    address (the whole sentence when there is none).
    """

    text: str
    names: tuple[str, ...] | None = None
    everyone: bool = False

    @property
    def addressed(self) -> bool:
        return self.everyone or self.names is not None

    def includes(self, drone: str) -> bool:
        """Whether ``drone`` is one of the addressees (False when nobody is named)."""
        return self.everyone or (self.names is not None and drone in self.names)


def parse_address(text: str) -> Address:
    """The address at the start of ``text`` and the sentence after it.

    A sentence that is only an address ("drone 2") keeps its text, so the NLU still sees it
    (and the operator hears that it was not understood).
    """
    m = _ALL.match(text)
    if m and m.group("rest").strip():
        return Address(m.group("rest").strip(), everyone=True)
    m = _ONE.match(text)
    if m and m.group("rest").strip():
        raw = m.group("num").lower()
        n = int(raw) if raw.isdigit() else _WORDS[raw]
        return Address(m.group("rest").strip(), names=(f"uav{n}",))
    return Address(text)


def recipients(address: Address, selected: str, known: list[str]) -> list[str]:
    """The drones that must act on a sentence, in fleet order.

    Args:
        address: what :func:`parse_address` found.
        selected: the drone the console had selected (or the REST ``drone`` field).
        known: every drone of this server.
    Returns:
        ``known`` for "all drones"; the named drones that exist; else ``[selected]``.
        An empty list means the sentence named only drones that do not exist.
    """
    if address.everyone:
        return list(known)
    if address.names is not None:
        return [n for n in known if n in address.names]
    return [selected]
