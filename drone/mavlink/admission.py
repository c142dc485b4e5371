"""``Admission``: which clients may hold a link to the simulated autopilot, sans-I/O.

A link is *trusted* once its codec accepted one frame from it: a correctly signed frame on a
signing simulator, any MAVLink 2 frame on an ``--insecure`` one. Until then it *waits*. The
rules, so that no flood of connections (or UDP peers) displaces a ground station that has the
key, and none costs the simulator more than a fixed number of links:

* at most ``max_trusted`` trusted links; one more that proves itself is closed (a log line says
  why), never one already flying;
* at most ``max_waiting`` waiting links: when another arrives, the one waiting longest is closed
  to make room, so a client that sends its first signed frame at once is never locked out by
  connections that send nothing;
* a waiting link that has sent bytes of which none were accepted (garbage, unsigned or badly
  signed frames) for ``deadline_s`` is closed; one that sends nothing (a pymavlink script in
  ``wait_heartbeat``, a passive watcher) keeps waiting until it speaks or is displaced.

Time is passed in (``now``, seconds on any monotonic clock).
"""

from __future__ import annotations

from dataclasses import dataclass

MAX_TRUSTED = 8
MAX_WAITING = 8
DEADLINE_S = 5.0


@dataclass
class _Entry:
    since: float
    first_bytes_t: float | None = None
    trusted: bool = False


class Admission:
    """See the module docstring."""

    def __init__(
        self,
        *,
        max_trusted: int = MAX_TRUSTED,
        max_waiting: int = MAX_WAITING,
        deadline_s: float = DEADLINE_S,
    ) -> None:
        if max_trusted < 1 or max_waiting < 1 or deadline_s <= 0:
            raise ValueError("admission limits must be positive")
        self.max_trusted = max_trusted
        self.max_waiting = max_waiting
        self.deadline_s = deadline_s
        self._links: dict[object, _Entry] = {}
        self.refused = 0  # links closed by these rules, in all

    @property
    def trusted(self) -> int:
        return sum(1 for e in self._links.values() if e.trusted)

    @property
    def waiting(self) -> int:
        return sum(1 for e in self._links.values() if not e.trusted)

    def is_trusted(self, cid: object) -> bool:
        entry = self._links.get(cid)
        return entry is not None and entry.trusted

    def arrive(self, cid: object, now: float) -> list[object]:
        """A new link waits; returns the links to close to make room (oldest waiting first)."""
        close: list[object] = []
        waiting = sorted(
            (e.since, i, c) for i, (c, e) in enumerate(self._links.items()) if not e.trusted
        )
        while len(waiting) >= self.max_waiting:
            _, _, oldest = waiting.pop(0)
            close.append(oldest)
            self.leave(oldest)
            self.refused += 1
        self._links[cid] = _Entry(since=now)
        return close

    def heard(self, cid: object, now: float, *, accepted: bool) -> bool:
        """``cid`` sent bytes (``accepted``: its codec has accepted a frame from it so far).

        Returns:
            False when ``cid`` must be closed: it proved itself while every trusted place is
            taken, or it is unknown here (already closed).
        """
        entry = self._links.get(cid)
        if entry is None:
            return False
        if entry.first_bytes_t is None:
            entry.first_bytes_t = now
        if accepted and not entry.trusted:
            if self.trusted >= self.max_trusted:
                self.leave(cid)
                self.refused += 1
                return False
            entry.trusted = True
        return True

    def expired(self, now: float) -> list[object]:
        """Waiting links that sent only refused bytes for ``deadline_s``: close them."""
        out = [
            cid
            for cid, e in self._links.items()
            if not e.trusted
            and e.first_bytes_t is not None
            and now - e.first_bytes_t >= self.deadline_s
        ]
        for cid in out:
            self.leave(cid)
            self.refused += 1
        return out

    def leave(self, cid: object) -> None:
        """``cid`` is gone (closed by either side)."""
        self._links.pop(cid, None)
