"""The map on Leaflet: readable outdoors on a phone, zoom and pan, fit-to-fleet, labels that
never overlap, the operator's tile server (under the page's real CSP) or the plain local grid
when no tiles load.

Two servers of their own on the outdoor field (120 × 120 m): a fleet of two whose tile server
cannot be reached (the grid shows), and one drone whose tiles come from a tile server this test
runs on loopback (the basemap shows, and the CSP allows exactly that host).
"""

from __future__ import annotations

import http.server
import threading
from collections.abc import Iterator
from typing import Any, ClassVar

import cv2
import numpy as np
import pytest

from drone.sim.world import load_world
from tests.browser.conftest import ServerProcess, open_console
from tests.browser.test_5_csp import poll
from tests.support.loopback import free_port, fresh_address

pytestmark = pytest.mark.browser
PHONE = {"width": 390, "height": 844}

LABEL_BOXES = """() => [...document.querySelectorAll('#map .map-label')]
  .filter(e => !e.hidden && e.offsetParent !== null)
  .map(e => { const r = e.getBoundingClientRect();
              return {text: e.textContent, l: r.left, t: r.top, r: r.right, b: r.bottom}; })"""


def overlapping(boxes: list[dict[str, Any]]) -> list[tuple[str, str]]:
    out = []
    for i, a in enumerate(boxes):
        for b in boxes[i + 1 :]:
            if (
                a["l"] < b["r"] - 0.5
                and b["l"] < a["r"] - 0.5
                and a["t"] < b["b"] - 0.5
                and (b["t"] < a["b"] - 0.5)
            ):
                out.append((a["text"], b["text"]))
    return out


def scale_m_per_px(page: Any) -> float:
    """Metres per pixel as the scale bar says it (its label over its width)."""
    text, width = page.evaluate(
        "(() => { const e = document.querySelector('#map .leaflet-control-scale-line');"
        " return [e.textContent, e.getBoundingClientRect().width]; })()"
    )
    value, unit = text.split()
    metres = float(value) * (1000 if unit == "km" else 0.01 if unit == "cm" else 1)
    return metres / float(width)


def zoom(page: Any) -> float:
    return float(page.evaluate("uavConsole.map.map.getZoom()"))


def settle(page: Any) -> None:
    """Until Leaflet's zoom/pan animation is over and the labels are placed again."""
    page.wait_for_function(
        "!uavConsole.map.map._animatingZoom && !uavConsole.map.labelsDirty", timeout=5000
    )
    page.wait_for_timeout(250)


@pytest.fixture
def outdoor_fleet(
    tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch
) -> Iterator[ServerProcess]:
    # A tile server nobody answers (a free port: connection refused at once): tiles fail.
    monkeypatch.setenv("UAVC_TILE_URL", f"http://127.0.0.1:{free_port()}/{{z}}/{{x}}/{{y}}.png")
    server = ServerProcess(
        tmp_path_factory.mktemp("uavc-map-fleet"),
        fresh_address(2),
        ("--world", "outdoor", "--fleet", "2"),
    )
    server.start()
    try:
        yield server
    finally:
        server.stop()


def test_outdoor_map_reads_on_a_phone(browser: Any, outdoor_fleet: ServerProcess) -> None:
    ctx, cp = open_console(browser, outdoor_fleet.url(), viewport=PHONE)
    page = cp.page
    try:
        page.wait_for_function("uavConsole.map.drones.size === 2", timeout=15_000)
        page.locator("#map").scroll_into_view_if_needed()
        settle(page)
        # offline: the tiles failed, the plain local grid is drawn instead
        page.wait_for_selector("#map[data-tiles='failed'][data-grid='on']", timeout=10_000)
        assert page.locator("#map .map-grid").count() > 10
        # Web Mercator around the GPS origin: the world's own lat/lon for wp1 (to ~1 cm)
        world = load_world("outdoor").to_dict()
        wp1 = world["waypoints"][0]
        lat, lon = page.evaluate(
            "([x, y]) => { const ll = uavConsole.map.frame.latLng(x, y);"
            " return [ll.lat, ll.lng]; }",
            [wp1["position"]["x"], wp1["position"]["y"]],
        )
        assert lat == pytest.approx(wp1["lat"], abs=1e-7) and lon == pytest.approx(
            wp1["lon"], abs=1e-7
        )

        # Readable: the 30 m patrol square fills most of the phone's map, not 55 px of it.
        box = page.locator("#map").bounding_box()
        assert box is not None and box["width"] >= 370
        p1, p2 = (
            page.evaluate(
                "([x, y]) => uavConsole.map.pixelOf(x, y)", [w["position"]["x"], w["position"]["y"]]
            )
            for w in world["waypoints"][:2]
        )
        assert abs(p2["x"] - p1["x"]) >= 180, (p1, p2)
        # Both drones (side by side on their pads) and the route are labelled, none overlaps.
        labels = page.evaluate(LABEL_BOXES)
        texts = [x["text"] for x in labels]
        assert any(t.startswith("uav1") for t in texts) and any(t.startswith("uav2") for t in texts)
        assert {"wp1", "wp2", "wp3", "wp4"} <= set(texts)
        assert overlapping(labels) == [], labels
        page.screenshot(path=str(outdoor_fleet.data_dir / "map-phone.png"))

        # Zoom: the buttons, the wheel; the scale follows.
        m0, z0 = scale_m_per_px(page), zoom(page)
        page.click("#map .leaflet-control-zoom-in")
        settle(page)
        m1, z1 = scale_m_per_px(page), zoom(page)
        assert z1 > z0 and m1 < 0.8 * m0, (m0, m1, z0, z1)
        assert overlapping(page.evaluate(LABEL_BOXES)) == []
        # where the map is now (a banner or a scroll since may have moved it)
        page.locator("#map").scroll_into_view_if_needed()
        box = page.locator("#map").bounding_box()
        assert box is not None
        centre = (box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
        page.mouse.move(*centre)
        page.mouse.wheel(0, 400)  # out (Leaflet gathers wheel events for 40 ms first)
        page.wait_for_function("z => uavConsole.map.map.getZoom() < z", arg=z1, timeout=5000)
        settle(page)
        assert overlapping(page.evaluate(LABEL_BOXES)) == []
        # Pan: a drag moves the map; Fit brings the fleet and its route back.
        before = page.evaluate("uavConsole.map.map.getCenter()")
        page.mouse.move(*centre)
        page.mouse.down()
        page.mouse.move(centre[0] + 120, centre[1] + 60, steps=8)
        page.mouse.up()
        settle(page)
        after = page.evaluate("uavConsole.map.map.getCenter()")
        assert after != before
        page.click("#map .map-fit a")
        settle(page)
        assert zoom(page) == pytest.approx(z0, abs=0.3)
        # Keys on the focused map: + zooms in, F fits.
        page.focus("#map")
        page.keyboard.press("+")
        settle(page)
        assert zoom(page) > z0
        page.keyboard.press("f")
        settle(page)
        assert zoom(page) == pytest.approx(z0, abs=0.3)
        # the refused tiles are the only errors
        assert [e for e in cp.console_errors() if "ERR_CONNECTION_REFUSED" not in e] == []
    finally:
        ctx.close()


class _Tiles(http.server.BaseHTTPRequestHandler):
    """Any /z/x/y.png: one 256 × 256 PNG tile (a light green field with a border)."""

    png = b""
    served: ClassVar[list[str]] = []

    def do_GET(self) -> None:
        self.served.append(self.path)
        self.send_response(200)
        self.send_header("Content-Type", "image/png")
        self.send_header("Content-Length", str(len(self.png)))
        self.end_headers()
        self.wfile.write(self.png)

    def log_message(self, *args: Any) -> None:
        pass


@pytest.fixture
def tile_server() -> Iterator[str]:
    img = np.full((256, 256, 3), (200, 230, 200), np.uint8)
    cv2.rectangle(img, (0, 0), (255, 255), (150, 180, 150), 1)
    ok, buf = cv2.imencode(".png", img)
    assert ok
    _Tiles.png = buf.tobytes()
    _Tiles.served = []
    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", free_port()), _Tiles)
    thread = threading.Thread(target=httpd.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{httpd.server_address[1]}"
    finally:
        httpd.shutdown()
        httpd.server_close()


def test_tiles_from_the_operators_server_under_the_csp(
    browser: Any,
    tile_server: str,
    tmp_path_factory: pytest.TempPathFactory,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setenv("UAVC_TILE_URL", f"{tile_server}/{{z}}/{{x}}/{{y}}.png")
    server = ServerProcess(
        tmp_path_factory.mktemp("uavc-map-tiles"),
        fresh_address(),
        ("--world", "outdoor"),
    )
    server.start()
    ctx = browser.new_context(viewport=PHONE, service_workers="block")  # the CSP applies
    try:
        page = ctx.new_page()
        violations: list[str] = []
        page.on("console", lambda m: violations.append(m.text) if m.type == "error" else None)
        page.add_init_script(
            "document.addEventListener('securitypolicyviolation', e =>"
            " console.error('CSP violation: ' + e.violatedDirective + ' ' + e.blockedURI))"
        )
        response = page.goto(server.url())
        assert response is not None
        csp = response.headers["content-security-policy"]
        img_src = next(d for d in csp.split("; ") if d.startswith("img-src"))
        assert img_src == f"img-src 'self' data: blob: {tile_server}"  # exactly that host
        assert poll(page, "document.querySelector('#map').dataset.tiles === 'loaded'")
        assert poll(page, "document.querySelector('#map').dataset.grid === 'off'")
        loaded = page.evaluate(
            "[...document.querySelectorAll('#map img.leaflet-tile-loaded')].length"
        )
        assert loaded >= 1 and _Tiles.served
        assert "OpenStreetMap" not in (page.text_content("#map .leaflet-control-attribution") or "")
        assert violations == []
    finally:
        ctx.close()
        server.stop()
