"""The console in the field, in Chromium against the real server and simulator.

- A layout made for flying, at five sizes, with an alarm and the lease banner up: the camera
  whole (full width and uncovered on an upright phone, at least half the screen on its side),
  EMERGENCY STOP, Land and Hover on screen and uncovered without scrolling, alarms one line
  each with "Acknowledge" inside its button, and nothing moves when ● REC, a running task and
  an alarm appear. Screenshots of each size are kept in docs/screenshots/size-*.png.
- Take off pressed while flying says so on the button; the command box's placeholder is whole
  at 1280 px and the first page says what to try; recordings download without a token in the
  link; the drone picker's contrast in dark mode; the dialog log takes focus on a phone held
  landscape.

The server of this file runs its simulated drone on a loopback address of its own.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from tests.browser.conftest import (
    AXE,
    PILOT,
    SCREENSHOTS,
    SIZES,
    ConsolePage,
    ServerProcess,
    _server,
    open_console,
)
from tests.browser.helpers import is_flying, position, type_command, wait_until
from tests.support.loopback import fresh_address

pytestmark = pytest.mark.browser

STOPS = ("#btn-emergency", "#btn-land", "#btn-hover")

# Where things are, after the layout settled (two animation frames).
MEASURE = """async () => {
  await new Promise((ok) => requestAnimationFrame(() => requestAnimationFrame(ok)));
  const box = (el) => { const r = el.getBoundingClientRect();
    return { x: r.x, y: r.y, w: r.width, h: r.height }; };
  const $ = (s) => document.querySelector(s);
  const inside = (sel, b) => {
    // a grid of points over the box: each must hit the element itself (nothing covers it)
    const out = [];
    for (const fx of [0.05, 0.3, 0.5, 0.7, 0.95]) for (const fy of [0.05, 0.5, 0.95]) {
      const hit = document.elementFromPoint(b.x + fx * b.w, b.y + fy * b.h);
      out.push(Boolean(hit && hit.closest(sel)));
    }
    return out.every(Boolean);
  };
  const cam = box($('#camera-panel .camera-frame'));
  const stops = {};
  for (const s of ['#btn-emergency', '#btn-land', '#btn-hover']) {
    const b = box($(s));
    stops[s] = { ...b, top: inside(s, b) };
  }
  const ack = $('#alert-ack');
  const lines = [...document.querySelectorAll('#alert-text .alert-line')].map((l) => {
    const t = l.querySelector('.alert-line-text');
    return { h: l.getBoundingClientRect().height,
             line: parseFloat(getComputedStyle(l).lineHeight), text: t.textContent };
  });
  return {
    header: box($('.topbar')), camera: { ...cam, uncovered: inside('#camera-panel', cam) },
    stops, lines,
    ack: ack.offsetParent ? { ...box(ack), fits: ack.scrollWidth <= ack.clientWidth } : null,
    banner: $('#banner').hidden ? null : box($('#banner')),
    scrollX: document.documentElement.scrollWidth > window.innerWidth,
  };
}"""


# Landed with no command this long, a flight's recording ends (Settings.recorder_idle_s, 30 s
# by default): the recordings and replay tests wait for a flight that ended.
RECORDER_IDLE_S = "3"


@pytest.fixture(scope="module")
def srv(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    yield from _server(
        tmp_path_factory,
        "uavc-field",
        fresh_address(),
        env={"UAVC_RECORDER_IDLE_S": RECORDER_IDLE_S},
    )


@pytest.fixture
def pilot(browser: Any, srv: ServerProcess) -> Iterator[ConsolePage]:
    ctx, cp = open_console(browser, srv.url(), viewport={"width": 1280, "height": 800}, lease=True)
    try:
        yield cp
    finally:
        ctx.close()


def land(srv: ServerProcess) -> None:
    srv.api("POST", "/drones/uav1/land")  # stops need no lease
    ok, truth, _ = wait_until(srv.truth, lambda t: not is_flying(t), timeout_s=30)
    assert ok, truth


def at_size(page: Any, w: int, h: int) -> dict[str, Any]:
    page.set_viewport_size({"width": w, "height": h})
    page.evaluate("window.scrollTo(0, 0)")
    return dict(page.evaluate(MEASURE))


def check_size(name: str, w: int, h: int, m: dict[str, Any]) -> None:
    """What a pilot needs at this size, from one measurement (with the alarm and banner up)."""
    cam = m["camera"]
    assert cam["uncovered"], (name, cam)
    assert cam["x"] >= 0 and cam["y"] >= 0 and cam["x"] + cam["w"] <= w + 0.5, (name, cam)
    assert cam["y"] + cam["h"] <= h + 0.5, (name, cam)  # whole, on the first screen
    if name == "phone":  # full width
        assert cam["x"] == 0 and abs(cam["w"] - w) < 0.5, (name, cam)
    if name == "phone-landscape":  # at least half the screen
        assert cam["w"] * cam["h"] >= 0.5 * w * h, (name, cam, cam["w"] * cam["h"] / (w * h))
    for sel, b in m["stops"].items():
        assert b["x"] >= 0 and b["y"] >= 0, (name, sel, b)
        assert b["x"] + b["w"] <= w and b["y"] + b["h"] <= h, (name, sel, b)
        assert b["w"] >= 44 and b["h"] >= 44 and b["top"], (name, sel, b)
    assert m["lines"], name
    for line in m["lines"]:  # one line each
        assert line["h"] < 1.5 * line["line"], (name, line)
    ack = m["ack"]
    assert ack is not None and ack["fits"], (name, ack)  # "Acknowledge" inside its button
    assert ack["y"] >= 0 and ack["y"] + ack["h"] <= h and ack["x"] + ack["w"] <= w, (name, ack)
    assert m["banner"] is not None, name  # the lease banner is up
    assert not m["scrollX"], name  # nothing wider than the screen


def test_take_off_while_flying_says_so_on_the_button(
    pilot: ConsolePage, srv: ServerProcess
) -> None:
    page = pilot.page
    sent: list[str] = []
    page.on("request", lambda r: sent.append(r.url) if r.url.endswith("/takeoff") else None)
    page.click("#btn-takeoff")
    ok, truth, _ = wait_until(srv.truth, lambda t: position(t)[2] > 0.5, timeout_s=30)
    assert ok, truth
    page.wait_for_function(
        "['Hovering', 'Flying'].includes(document.getElementById('sb-flight-v').textContent)",
        timeout=15_000,
    )
    assert len(sent) == 1
    page.click("#btn-takeoff")
    page.wait_for_selector("#btn-takeoff[data-said='I am already flying.']", timeout=5000)
    assert page.get_attribute("#btn-takeoff", "aria-description") == "I am already flying."
    assert "I am already flying." in (page.text_content("#dialog") or "")
    assert len(sent) == 1  # nothing was sent
    # Typed, the dialog answers the same.
    type_command(page, "take off")
    page.wait_for_function(
        """[...document.querySelectorAll('#dialog .msg-bot .text')]
            .some(e => e.textContent.includes('I am already flying'))""",
        timeout=10_000,
    )
    land(srv)
    # On the ground the button takes off again (the words are gone after a while).
    page.wait_for_function(
        "document.getElementById('sb-flight-v').textContent === 'Landed'", timeout=15_000
    )
    page.wait_for_selector("#btn-takeoff:not([data-said])", timeout=10_000)


def moved(name: str, before: dict[str, Any], after: dict[str, Any]) -> None:
    """Nothing moved between two measurements: the top bar, the camera, the stops."""
    assert after["header"] == before["header"], name
    cam = {k: after["camera"][k] for k in "xywh"}
    assert cam == {k: before["camera"][k] for k in "xywh"}, name
    for sel in STOPS:
        was, now = before["stops"][sel], after["stops"][sel]
        assert {k: now[k] for k in "xywh"} == {k: was[k] for k in "xywh"}, (name, sel)


def test_a_layout_made_for_flying_at_five_sizes(
    browser: Any, pilot: ConsolePage, srv: ServerProcess
) -> None:
    """One page resized through five sizes (media queries on the viewport, as a tablet or a
    phone is turned): landed and idle; flying a patrol (● REC, a running task); with an alarm.
    Nothing moves from one to the next. It leaves the battery low (the last flight here)."""
    key = pilot.page.evaluate("uavConsole.api.leaseHolder")
    ctx, cp = open_console(browser, srv.url(), viewport={"width": 1280, "height": 800}, frames=2)
    try:
        page = cp.page
        page.wait_for_selector("#banner[data-source='lease']", timeout=10_000)
        assert (page.text_content("#sb-task-v") or "").startswith("idle")
        # Before: landed, idle, no alarm, nothing recording (the recorder may already hold a
        # session open for the pilot's first command: its pill is hidden as when none runs).
        before = {}
        for n, (w, h) in SIZES.items():
            page.evaluate("document.getElementById('rec').hidden = true")
            before[n] = at_size(page, w, h)
        # The other pilot flies a patrol: the flight is recorded (● REC), the task runs ...
        page.set_viewport_size({"width": 1280, "height": 800})
        pilot.page.click("#btn-takeoff")
        ok, truth, _ = wait_until(srv.truth, lambda t: position(t)[2] > 0.5, timeout_s=30)
        assert ok, (truth, pilot.page.text_content("#banner"), pilot.page.text_content("#dialog"))
        type_command(pilot.page, "patrol markers 0 and 1")
        page.wait_for_function(
            "document.getElementById('sb-task-v').textContent.startsWith('patrol')",
            timeout=15_000,
        )
        page.wait_for_selector("#rec:not([hidden])", timeout=15_000)
        for name, (w, h) in SIZES.items():
            flying = at_size(page, w, h)
            assert (page.text_content("#sb-task-v") or "").startswith("patrol"), name
            moved(name, before[name], flying)
        # ... and the battery reads low: an alarm (in flight, a drop this sudden is doubted
        # first: the navdata alarm, a long one, says so).
        r = httpx.post(
            f"{srv.base}/api/v1/sim/uav1/fault",
            headers={"Authorization": f"Bearer {PILOT}", "X-Pilot-Lease": key},
            json={"kind": "battery", "battery_pct": 20},
            timeout=10.0,
        )
        assert r.status_code == 200, r.text
        page.wait_for_function(
            "document.getElementById('alert-text').textContent.includes('attery')",
            timeout=15_000,
        )
        SCREENSHOTS.mkdir(parents=True, exist_ok=True)
        for name, (w, h) in SIZES.items():
            after = at_size(page, w, h)
            page.screenshot(path=str(SCREENSHOTS / f"size-{name}.png"))
            check_size(name, w, h, after)
            moved(name, before[name], after)
            # The stops stay put and on screen with the page scrolled to its end.
            page.evaluate("window.scrollTo(0, document.documentElement.scrollHeight)")
            scrolled = dict(page.evaluate(MEASURE))
            for sel in STOPS:
                b = scrolled["stops"][sel]
                assert b["top"] and {k: b[k] for k in "xywh"} == {
                    k: after["stops"][sel][k] for k in "xywh"
                }, (name, sel)
        assert cp.console_errors() == []
    finally:
        ctx.close()
        land(srv)
        httpx.post(
            f"{srv.base}/api/v1/sim/uav1/fault",
            headers={"Authorization": f"Bearer {PILOT}", "X-Pilot-Lease": key},
            json={"kind": "clear"},
            timeout=10.0,
        )


def test_the_command_box_reads_whole_and_the_first_page_says_what_to_try(
    browser: Any, srv: ServerProcess
) -> None:
    ctx, cp = open_console(browser, srv.url(), viewport={"width": 1280, "height": 800})
    try:
        page = cp.page
        room, text = page.evaluate(
            """() => {
              const i = document.getElementById('text-input'); const cs = getComputedStyle(i);
              const c = document.createElement('canvas').getContext('2d');
              c.font = `${cs.fontStyle} ${cs.fontWeight} ${cs.fontSize} ${cs.fontFamily}`;
              const room = i.clientWidth - parseFloat(cs.paddingLeft) - parseFloat(cs.paddingRight);
              return [room, c.measureText(i.placeholder).width];
            }"""
        )
        assert text <= room, (text, room)  # the placeholder is not cut
        assert page.is_visible("#hint")
        assert "take off" in (page.text_content("#hint") or "")
        type_command(page, "what is your battery")
        page.wait_for_selector("#hint", state="hidden", timeout=5000)  # first command only
    finally:
        ctx.close()


def test_recordings_download_without_a_token_in_the_link(
    pilot: ConsolePage, srv: ServerProcess
) -> None:
    page = pilot.page

    def ended() -> list[dict[str, Any]]:
        return [f for f in srv.api("GET", "/flights").json()["flights"] if f["ended"]]

    if not srv.api("GET", "/flights").json()["flights"]:  # alone: fly once (the session ends
        # after RECORDER_IDLE_S; after the flights above, the last one's end is waited for)
        page.click("#btn-takeoff")
        ok, truth, _ = wait_until(srv.truth, lambda t: position(t)[2] > 0.5, timeout_s=30)
        assert ok, truth
        land(srv)
    ok, flights, _ = wait_until(ended, bool, timeout_s=90, period_s=1.0)
    assert ok, flights
    page.click("#recordings > summary")
    page.wait_for_selector("#recordings-list a", timeout=15_000)
    links = page.eval_on_selector_all("#recordings-list a", "els => els.map(a => a.href)")
    assert links and all("token" not in href for href in links), links
    with page.expect_download(timeout=30_000) as download:
        page.click("#recordings-list a")
    assert Path(download.value.path()).read_bytes()[:8] == b"\x89MCAP0\r\n"
    assert httpx.get(links[0], timeout=30).status_code == 401  # the link alone is not enough


def _axe(page: Any, context: str | None = None, rules: list[str] | None = None) -> list[str]:
    """axe-core's serious and critical violations in ``context`` (a selector; None: the page)."""
    where = "document" if context is None else repr(context)
    only = f"runOnly: {rules!r}, " if rules else ""
    result = page.evaluate(f"axe.run({where}, {{{only}resultTypes: ['violations']}})")
    return [
        f"{v['id']} ({v['impact']}): {[n['target'] for n in v['nodes']][:4]}"
        for v in result["violations"]
        if v["impact"] in ("serious", "critical")
    ]


def test_drone_picker_contrast_in_dark_mode(browser: Any, srv: ServerProcess) -> None:
    if not AXE.exists():
        pytest.fail(f"{AXE} is missing: make node-deps (npm ci in tests/node)")
    ctx, cp = open_console(
        browser, srv.url(), viewport={"width": 1280, "height": 800}, color_scheme="dark"
    )
    try:
        page = cp.page
        # A fleet shows the picker; here it shows the one drone, as a fleet's would.
        page.evaluate("document.getElementById('drone-select-wrap').hidden = false")
        page.evaluate(AXE.read_text() + "\n;undefined")
        ratio = page.evaluate(
            """() => {
              const lin = (v) => { v /= 255;
                return v <= 0.03928 ? v / 12.92 : ((v + 0.055) / 1.055) ** 2.4; };
              const lum = (c) => { const [r, g, b] = c.match(/\\d+/g).slice(0, 3).map(Number)
                .map(lin); return 0.2126 * r + 0.7152 * g + 0.0722 * b; };
              const cs = getComputedStyle(document.getElementById('drone-select'));
              const [a, b] = [lum(cs.color), lum(cs.backgroundColor)].sort((x, y) => y - x);
              return (a + 0.05) / (b + 0.05);
            }"""
        )
        assert ratio >= 4.5, ratio
        assert _axe(page, "#drone-select-wrap", ["color-contrast"]) == []
    finally:
        ctx.close()


def test_dialog_log_takes_focus_on_a_phone_held_landscape(browser: Any, srv: ServerProcess) -> None:
    if not AXE.exists():
        pytest.fail(f"{AXE} is missing: make node-deps (npm ci in tests/node)")
    ctx, cp = open_console(browser, srv.url(), viewport={"width": 844, "height": 390})
    try:
        page = cp.page
        page.evaluate(
            """() => { for (let i = 0; i < 30; i++)
                uavConsole.dialog.onReply({text: `Reply ${i}`, level: 'info', speak: false}); }"""
        )
        assert page.get_attribute("#dialog", "role") == "log"
        page.focus("#dialog")
        assert page.evaluate("document.activeElement.id") == "dialog"
        page.keyboard.press("PageUp")  # a focused log scrolls from the keyboard
        page.evaluate(AXE.read_text() + "\n;undefined")
        assert _axe(page) == []
    finally:
        ctx.close()


def _stops_and_camera(name: str, w: int, h: int, m: dict[str, Any], live: bool = True) -> None:
    """The camera whole and uncovered on the first screen; live, the stops on it, uncovered,
    and a phone on its side gives the camera half the screen (a replay's timeline takes room
    above it)."""
    cam = m["camera"]
    assert cam["uncovered"], (name, cam)
    assert cam["x"] >= 0 and cam["y"] >= 0 and cam["x"] + cam["w"] <= w + 0.5, (name, cam)
    assert cam["y"] + cam["h"] <= h + 0.5, (name, cam)
    if w < h:
        assert cam["x"] == 0 and abs(cam["w"] - w) < 0.5, (name, cam)
    elif live:
        assert cam["w"] * cam["h"] >= 0.5 * w * h, (name, cam)
    if live:
        for sel, b in m["stops"].items():
            assert b["x"] >= 0 and b["y"] >= 0, (name, sel, b)
            assert b["x"] + b["w"] <= w and b["y"] + b["h"] <= h, (name, sel, b)
            assert b["w"] >= 44 and b["h"] >= 44 and b["top"], (name, sel, b)
    assert not m["scrollX"], name


def test_phones_keep_the_stops_and_camera_with_the_map_training_and_a_replay(
    pilot: ConsolePage, srv: ServerProcess
) -> None:
    """At 390×844 and 844×390 the pilot's page with the Leaflet map, the training panel open
    and the page scrolled to it, and a replay opened from the Recordings menu: the stops and
    the whole camera stay on the first screen (screenshots in docs/screenshots/)."""
    page = pilot.page
    phones = {"phone": SIZES["phone"], "phone-landscape": SIZES["phone-landscape"]}
    page.wait_for_selector("#map.leaflet-container .leaflet-pane", state="attached")
    page.wait_for_selector("#training:not([hidden])", timeout=15_000)
    page.click("#training > summary")
    page.wait_for_selector("#training[open] button[data-fault='link_loss']", timeout=5_000)
    for name, (w, h) in phones.items():
        top = at_size(page, w, h)
        _stops_and_camera(f"{name} training", w, h, top)
        page.screenshot(path=str(SCREENSHOTS / f"tools-{name}.png"))
        page.eval_on_selector("#training", "el => el.scrollIntoView({block: 'center'})")
        there = dict(page.evaluate(MEASURE))
        for sel in STOPS:  # scrolled to the training panel: the stops stay put
            b = there["stops"][sel]
            assert b["top"] and {k: b[k] for k in "xywh"} == {
                k: top["stops"][sel][k] for k in "xywh"
            }, (name, sel)
        page.screenshot(path=str(SCREENSHOTS / f"tools-{name}-training.png"))

    # A replay from the Recordings menu (a flight of this file's server; fly one if none).
    def ended() -> list[dict[str, Any]]:
        return [f for f in srv.api("GET", "/flights").json()["flights"] if f["ended"]]

    page.set_viewport_size({"width": 1280, "height": 800})
    if not ended():
        page.click("#btn-takeoff")
        ok, truth, _ = wait_until(srv.truth, lambda t: position(t)[2] > 0.5, timeout_s=30)
        assert ok, truth
        land(srv)
    ok, flights, _ = wait_until(ended, bool, timeout_s=90, period_s=1.0)
    assert ok, flights
    page.click("#recordings > summary")
    button = f"#recordings-list button[data-replay='{flights[0]['id']}']"
    page.wait_for_selector(button, timeout=15_000)
    with page.context.expect_page() as opened:
        page.click(button)
    replay = opened.value
    try:
        replay.wait_for_selector("#replay-bar:not([hidden])", timeout=30_000)
        replay.wait_for_selector("#map.leaflet-container .leaflet-pane", state="attached")
        for name, (w, h) in phones.items():
            m = at_size(replay, w, h)
            # nothing flies in a replay: the camera whole, the timeline on the first screen
            _stops_and_camera(f"{name} replay", w, h, m, live=False)
            bar = replay.eval_on_selector(
                "#replay-bar",
                "e => { const r = e.getBoundingClientRect(); return [r.y, r.bottom]; }",
            )
            assert bar[0] >= 0 and bar[1] <= h, (name, bar)
            replay.screenshot(path=str(SCREENSHOTS / f"tools-{name}-replay.png"))
    finally:
        replay.close()
