"""The outdoor map's tile server: the URL template the operator sets and what the page's CSP
allows for it.

The browser fetches the tiles (``web/static/js/map.js``, Leaflet), never the server, which stays
offline. ``UAVC_TILE_URL`` is a Leaflet URL template (``{z}/{x}/{y}``, optionally ``{s}`` in the
host for subdomains, ``{r}`` for retina); empty turns tiles off (the plain local grid). The
page's ``img-src`` allows exactly that tile host (:func:`tile_source`).

Default: OpenStreetMap's standard tiles. Their usage policy
(https://operations.osmfoundation.org/policies/tiles/) asks for the attribution the page shows
and for moderate use; a site flying often should run or rent its own tile server and set it.
"""

from __future__ import annotations

import re
from urllib.parse import urlsplit

DEFAULT_TILE_URL = "https://tile.openstreetmap.org/{z}/{x}/{y}.png"
DEFAULT_ATTRIBUTION = "© OpenStreetMap contributors"

_HOST = re.compile(r"^(?:\{s\}\.)?[A-Za-z0-9-]+(?:\.[A-Za-z0-9-]+)*$|^\[[0-9A-Fa-f:.]+\]$")
_PLACEHOLDER = re.compile(r"\{[^}]*\}")
_ALLOWED = {"{z}", "{x}", "{y}", "{s}", "{r}"}


class TileUrlError(ValueError):
    """A tile URL template the page could not use (the message says why)."""


def check_tile_url(template: str) -> str:
    """``template`` if usable, stripped ("" turns tiles off).

    Raises:
        TileUrlError: not http(s), no host, a placeholder other than {z} {x} {y} {s} {r},
            one of {z} {x} {y} missing, or {s} anywhere but the start of the host.
    """
    t = template.strip()
    if not t:
        return ""
    try:
        parts = urlsplit(t.replace("{s}", "s-placeholder", 1) if "{s}." in t else t)
        host = urlsplit(t).netloc.rsplit("@", 1)[-1]
        hostname_ok = bool(parts.hostname)
    except ValueError as exc:  # urllib: "Invalid IPv6 URL" and the like
        raise TileUrlError(f"tile URL is not a URL ({exc}): {t!r}") from exc
    if parts.scheme not in ("http", "https"):
        raise TileUrlError(f"tile URL must start with http:// or https://, not {t!r}")
    hostname = re.sub(r":\d{1,5}$", "", host)
    if not hostname_ok or not _HOST.match(hostname):
        raise TileUrlError(f"tile URL has no usable host: {t!r}")
    unknown = set(_PLACEHOLDER.findall(t)) - _ALLOWED
    if unknown:
        raise TileUrlError(f"tile URL placeholders must be {{z}} {{x}} {{y}} {{s}} {{r}}: {t!r}")
    if not all(p in t for p in ("{z}", "{x}", "{y}")):
        raise TileUrlError(f"tile URL must hold {{z}}, {{x}} and {{y}}: {t!r}")
    if "{s}" in t and "{s}" in t.split(host, 1)[-1]:
        raise TileUrlError(f"{{s}} may only start the host: {t!r}")
    return t


def tile_source(template: str) -> str | None:
    """The CSP host-source that allows exactly this template's tile host (``{s}.`` becomes
    ``*.``), e.g. ``https://tile.openstreetmap.org``; None when tiles are off or unusable."""
    try:
        t = check_tile_url(template)
    except TileUrlError:
        return None
    if not t:
        return None
    scheme, rest = t.split("://", 1)
    host = rest.split("/", 1)[0].rsplit("@", 1)[-1]
    return f"{scheme}://{host.replace('{s}.', '*.', 1)}"
