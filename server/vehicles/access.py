"""Who may do what on ``/vehicle-link``: vehicle keys only, each vehicle within its own scope.

A connection authenticates with a vehicle key (:mod:`server.vehicles.keys`), never the pilot or
observer token, and is then the vehicle that key names: role ``vehicle``, ``who`` = its name. A
vehicle reports; it does not command and holds no lease. Its :class:`VehicleScope` is exactly
what its link declares (:func:`server.vehicles.host.link_spec` for that name and prefix):

- it may advertise and publish only its own drone's topics (navdata or MAVROS, camera, pose,
  markers, task, ``/NAME/fleet/ltm_status``, ``/NAME/vehicle/*``): never another drone's, never
  a command topic (``/cmd_vel``, ``/ardrone/*``), never ``/console/*`` or ``/fleet/*`` of the
  server (it runs no dialog; what its own nodes say goes through ``/NAME/vehicle/reply``, which
  the console checks and re-publishes: :mod:`server.vehicles.relay`);
- it may provide only its own services (``/NAME/vehicle/control``, ``/NAME/fleet/plan``);
- it may call none of the server's services (:data:`VEHICLE_CALLS` is empty: the captioner and
  the fleet's patrol are the console dialog's own).

A refusal is a rosbridge ``status`` error naming the vehicle ("vehicle uav1 may not publish to
/console/reply") and a log line (the first of each kind, then every :data:`LOG_EVERY` th).

The prefix of a vehicle's drone topics is the console's decision, not the vehicle's: ``""`` only
for the single drone ``serve`` spawns itself, else ``/NAME`` (:meth:`VehicleLinkSecurity.
prefix_of`), so a vehicle cannot claim another drone's topics by announcing its prefix.
"""

from __future__ import annotations

import collections
import functools
import logging
from collections.abc import Callable
from dataclasses import dataclass

from server.http.security import SERVER_TOPIC_RE, Role, Security, TokenStore
from server.settings import Settings
from server.vehicles.keys import VehicleKeys

log = logging.getLogger("uav_console.vehicle_link")

# Services of the central server a vehicle calls: none (what a vehicle needs of its console
# comes as publications and its heartbeat).
VEHICLE_CALLS: frozenset[str] = frozenset()
LOG_EVERY = 100
MAX_COUNTED = 1024


def canonical(name: str) -> str:
    """``name`` with one leading slash (as the graph spells it); never raises."""
    return "/" + str(name).strip().lstrip("/")


@dataclass(frozen=True)
class VehicleScope:
    """What one vehicle may publish, provide and call (canonical names)."""

    name: str
    prefix: str
    topics: frozenset[str]
    services: frozenset[str]
    calls: frozenset[str] = VEHICLE_CALLS


@functools.lru_cache(maxsize=1024)
def scope_for(name: str, prefix: str) -> VehicleScope:
    """The scope of vehicle ``name`` whose drone topics carry ``prefix``: every topic and
    service its link declares, AR.Drone or MAVLink, GPS world or not, and nothing of the
    server's own."""
    from server.vehicles.host import link_spec  # the link's own declaration, one source

    specs = [
        link_spec(name, prefix, mavlink=m, gps=g) for m in (False, True) for g in (False, True)
    ]
    topics = frozenset(canonical(t.name) for s in specs for t in s.out_topics)
    services = frozenset(canonical(n) for s in specs for n, _ in s.out_services)
    # A floor under the declaration: whatever link_spec says, never the server's own names nor
    # what the vehicle takes in (the commands it obeys, the console's heartbeat).
    inbound = frozenset(canonical(t.name) for s in specs for t in s.in_topics)
    topics = frozenset(t for t in topics if not SERVER_TOPIC_RE.match(t) and t not in inbound)
    services = frozenset(s for s in services if not SERVER_TOPIC_RE.match(s))
    return VehicleScope(name, prefix, topics, services)


class VehicleLinkSecurity(Security):
    """Security of ``/vehicle-link`` (see the module docstring).

    Args:
        keys: the console's vehicle keys.
        prefix_of: the prefix of a vehicle's drone topics (the console's records).
    """

    def __init__(
        self,
        settings: Settings,
        tokens: TokenStore,
        keys: VehicleKeys,
        prefix_of: Callable[[str], str] | None = None,
    ) -> None:
        super().__init__(settings, tokens)
        self.keys = keys
        self.prefix_of = prefix_of or (lambda name: f"/{name}")
        self.refused: collections.Counter[tuple[str, str, str]] = collections.Counter()

    def role_for(self, token: str | None) -> Role | None:
        return Role.VEHICLE if self.keys.vehicle_for(token) is not None else None

    def identify(self, token: str | None) -> str | None:
        return self.keys.vehicle_for(token)

    def origin_allowed(self, origin: str | None, host_header: str | None) -> bool:
        return origin is None  # vehicles are not browsers

    def needs_lease(self, service_or_topic: str, *, service: bool) -> bool:
        return False  # a vehicle reports within its scope; it commands nothing

    def lease_exempt(self, topic: str, msg: object) -> bool:
        return True

    def scope(self, who: str) -> VehicleScope:
        return scope_for(who, self.prefix_of(who))

    def _scoped(self, role: Role | None, who: str | None) -> VehicleScope | None:
        return self.scope(who) if role is Role.VEHICLE and who is not None else None

    def can_publish(self, role: Role | None, topic: str, who: str | None = None) -> bool:
        scope = self._scoped(role, who)
        return scope is not None and canonical(topic) in scope.topics

    def can_call(self, role: Role | None, service: str, who: str | None = None) -> bool:
        scope = self._scoped(role, who)
        return scope is not None and canonical(service) in scope.calls

    def can_provide(self, role: Role | None, service: str, who: str | None = None) -> bool:
        scope = self._scoped(role, who)
        return scope is not None and canonical(service) in scope.services

    def refusal(self, role: Role | None, action: str, name: str, who: str | None = None) -> str:
        text = super().refusal(role, action, name, who)
        if role is Role.VEHICLE and who is not None:
            scope = self.scope(who)
            if action == "call":
                allowed = ", ".join(sorted(scope.calls)) or "none of the server's services"
                text += f": a vehicle calls {allowed}"
            elif action.startswith("provide"):
                text += f": a vehicle provides only its own, {', '.join(sorted(scope.services))}"
            else:
                where = (
                    f"{scope.prefix}/… and /{who}/…" if scope.prefix != f"/{who}" else f"/{who}/…"
                )
                text += f": a vehicle publishes only its own drone's topics ({where})"
        else:
            text += ": /vehicle-link takes only a vehicle key (uav-console vehicle-key NAME)"
        if len(self.refused) > MAX_COUNTED:  # names are the client's: keep the count bounded
            self.refused.clear()
        key = (who or "", action, name)
        count = self.refused[key] = self.refused[key] + 1
        if count == 1 or count % LOG_EVERY == 0:
            log.warning("refused on /vehicle-link (%d×): %s", count, text)
        return text


__all__ = ["VEHICLE_CALLS", "VehicleLinkSecurity", "VehicleScope", "scope_for"]
