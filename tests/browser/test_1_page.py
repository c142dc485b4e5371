"""The console page on the real server: loads cleanly, live panels, layout, roles, speech UI."""

from __future__ import annotations

import contextlib
import re
from typing import Any

import pytest
from playwright.sync_api import TimeoutError as PlaywrightTimeout

from tests.browser.conftest import (
    OBSERVER,
    SCREENSHOTS,
    ConsolePage,
    ServerProcess,
    open_console,
    wait_ready,
)
from tests.browser.helpers import NO_SPEECH, SPEECH_STANDIN, refused_jog

pytestmark = pytest.mark.browser

PHONE = {"width": 390, "height": 844}


def wait_for_video(page: Any, timeout_ms: int = 5000) -> None:
    """Wait a little for camera frames so a screenshot shows video (not required for layout)."""
    with contextlib.suppress(PlaywrightTimeout):
        page.wait_for_function(
            "Number(document.querySelector('#camera').dataset.frames || 0) > 2", timeout=timeout_ms
        )


def frames(page: Any) -> int:
    return int(page.eval_on_selector("#camera", "el => Number(el.dataset.frames || 0)"))


# Pages of their own first: the module's shared page (the ``console`` fixture) holds the pilot
# lease from its first test on, and no other page draws beside it meanwhile.
def test_mic_without_speech_recognition_says_so(browser: Any, server: ServerProcess) -> None:
    # No Web Speech API: "auto" picks the console's own (offline) recogniser, and the page says
    # so; with no microphone on this machine, pressing it says why and offers typing.
    ctx, cp = open_console(browser, server.url(), init_script=NO_SPEECH)
    try:
        page = cp.page
        page.wait_for_function("document.body.dataset.recognizer === 'server'", timeout=3000)
        assert "offline" in (page.text_content("#recognizer-label") or "")
        page.click("#mic")
        page.wait_for_selector("#dialog .msg-system", timeout=5000)
        text = page.text_content("#dialog") or ""
        assert "microphone" in text.lower() and "type" in text.lower()
    finally:
        ctx.close()


def test_interim_text_shown_while_speaking(browser: Any, server: ServerProcess) -> None:
    ctx, cp = open_console(browser, server.url(), init_script=SPEECH_STANDIN)
    try:
        page = cp.page
        # "hover" while landed is harmless; the stand-in says "please hover" with interim "please".
        page.evaluate("window.__speech.next = {text: 'please hover', confidence: 0.95}")
        page.click("#mic")
        page.wait_for_function("window.__speech.interimSeen !== undefined", timeout=10_000)
        assert "please" in page.evaluate("window.__speech.interimSeen")
        page.wait_for_selector("#dialog .msg-user", timeout=10_000)
        assert "spoken · confidence 95 %" in (page.text_content("#dialog .msg-user") or "")
    finally:
        ctx.close()


def test_second_pilot_takes_over_and_first_is_told(browser: Any, server: ServerProcess) -> None:
    ctx_a, first = open_console(browser, server.url())
    ctx_b = None
    try:
        a = first.page
        a.wait_for_selector("#role[data-role='pilot']", timeout=10_000)
        a.wait_for_function("uavConsole.haveLease === true", timeout=20_000)
        ctx_b, second = open_console(browser, server.url())
        b = second.page
        # The second pilot sees who holds the controls and is offered the take-over.
        b.wait_for_selector("#takeover:not([hidden])", timeout=20_000)
        assert b.is_disabled("#btn-takeoff") and b.is_disabled("[data-jog='left']")
        assert b.is_enabled("#btn-emergency")  # a stop is never withheld from a pilot
        b.click("#takeover")
        b.wait_for_function("uavConsole.haveLease === true", timeout=20_000)
        assert b.is_enabled("#btn-takeoff") and b.is_hidden("#takeover")
        # The first pilot is told, and its controls are off until it takes over in turn.
        a.wait_for_selector("#takeover:not([hidden])", timeout=20_000)
        assert "took over" in (a.text_content("#banner") or "")
        assert a.is_disabled("#btn-takeoff") and a.is_disabled("#send")
        # The server agrees: the first pilot's jog is refused (a zero twist, a hover, is not:
        # any pilot may hover).
        refused_jog(a, "lease", 0.2, 20_000)
    finally:
        ctx_a.close()
        if ctx_b is not None:
            ctx_b.close()


def test_replies_spoken_unless_muted_and_alerts_announced(
    browser: Any, server: ServerProcess
) -> None:
    ctx, cp = open_console(browser, server.url(), init_script=SPEECH_STANDIN)
    try:
        page = cp.page
        say = """t => uavConsole.dialog.onReply({text: t, level: 'info', speak: true,
                                                utterance: '', commands: ''})"""
        page.evaluate(say, "Battery is at 80 percent")
        assert page.evaluate("window.__speech.spoken") == ["Battery is at 80 percent"]
        page.click("#mute")
        assert page.get_attribute("#mute", "aria-pressed") == "true"
        page.evaluate(say, "Climbing 1 meter")
        assert page.evaluate("window.__speech.spoken") == ["Battery is at 80 percent"]
        assert "Climbing 1 meter" in (page.text_content("#dialog") or "")
        # Alerts also go to the assertive live region for screen readers.
        page.evaluate("""() => uavConsole.dialog.onReply({text: 'Battery low, returning home',
                                                          level: 'alert', speak: true})""")
        assert page.text_content("#alerts") == "Battery low, returning home"
        # The mute choice is remembered.
        page.reload()
        page.wait_for_selector("#conn[data-state='open']")
        assert page.get_attribute("#mute", "aria-pressed") == "true"
    finally:
        ctx.close()


def test_phone_viewport_four_essentials_visible(browser: Any, server: ServerProcess) -> None:
    ctx, cp = open_console(
        browser, server.url(), viewport=PHONE, color_scheme="dark", frames=2, telemetry=True
    )
    try:
        page = cp.page
        SCREENSHOTS.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(SCREENSHOTS / "console-phone.png"))
        assert page.evaluate("window.scrollY") == 0
        for sel in (".camera-frame", "#btn-emergency", "#mic", "#text-input"):
            box = page.locator(sel).bounding_box()
            assert box is not None, sel
            assert box["y"] >= 0 and box["y"] + box["height"] <= PHONE["height"], (sel, box)
            assert box["x"] >= 0 and box["x"] + box["width"] <= PHONE["width"], (sel, box)
            # Not covered by anything else: the element itself is what a tap at its centre hits.
            hit = page.evaluate(
                """([sel, x, y]) => { const el = document.elementFromPoint(x, y);
                     return !!el && document.querySelector(sel).contains(el); }""",
                [sel, box["x"] + box["width"] / 2, box["y"] + box["height"] / 2],
            )
            assert hit, f"{sel} is covered"
        # Big enough for a thumb (WCAG 2.5.5 target size 44 px).
        assert page.locator("#btn-emergency").bounding_box()["height"] >= 44  # type: ignore[index]
        assert cp.console_errors() == []
    finally:
        ctx.close()


def test_observer_controls_disabled_and_publishes_refused(
    browser: Any, server: ServerProcess
) -> None:
    ctx, cp = open_console(browser, server.url(OBSERVER))
    try:
        page = cp.page
        # The server refuses what an observer publishes, with a status naming the role.
        refused_jog(page, "observer", 0.5, 5000)
        # The page knows it is an observer and disables every control.
        page.wait_for_selector("#role[data-role='observer']", timeout=5000)
        for sel in (
            "#btn-takeoff",
            "#btn-land",
            "#btn-hover",
            "#btn-emergency",
            "#send",
            "#mic",
            "#handsfree",
            "#text-input",
            "[data-jog='forward']",
            "#map-go",
        ):
            assert page.is_disabled(sel), f"{sel} is enabled for an observer"
        # REST refuses too.
        status = page.evaluate(
            "() => uavConsole.api.action('uav1', 'takeoff').then(() => 200, e => e.status)"
        )
        assert status == 403
    finally:
        ctx.close()
    assert server.api("GET", "/sim/uav1/truth").status_code == 200


@pytest.mark.parametrize(
    ("query", "expect"),
    [("", "No token in the address"), ("?token=wrong", "refused this page's token")],
)
def test_missing_or_bad_token_is_explained(
    browser: Any, server: ServerProcess, query: str, expect: str
) -> None:
    ctx = browser.new_context(bypass_csp=True)  # (string predicates need eval; see test_5)
    try:
        page = ctx.new_page()
        page.goto(f"{server.base}/{query}")
        page.wait_for_selector("#banner:not([hidden])", timeout=5000)
        assert expect in (page.text_content("#banner") or "")
        page.wait_for_timeout(500)
        assert page.get_attribute("#conn", "data-state") != "open"  # the server refuses it
    finally:
        ctx.close()


def test_page_loads_without_console_errors(console: ConsolePage) -> None:
    page = console.page
    assert page.title() == "uav-console"
    # Every panel loads the world, learns its role, shows telemetry and video and checks its
    # voice; nothing may log an error on the way.
    page.wait_for_selector("#role[data-role='pilot']", timeout=10_000)
    wait_ready(page, world=True, telemetry=True, frames=2)
    page.wait_for_function("uavConsole.dialog.voice !== 'unknown'", timeout=10_000)
    assert console.console_errors() == []
    assert page.get_attribute("#conn", "data-state") == "open"
    assert page.text_content("#conn") == "Connected"


def test_telemetry_and_camera_update(console: ConsolePage) -> None:
    page = console.page
    page.wait_for_function(
        "document.querySelector('#battery').textContent.includes('%')", timeout=15_000
    )
    battery = page.text_content("#battery") or ""
    assert re.fullmatch(r"\d{1,3} %", battery), battery
    assert re.fullmatch(r"-?\d+\.\d\d m", page.text_content("#altitude") or ""), "altitude"
    assert page.text_content("#ctrl-state") in {"Landed", "Inited", "Flying", "Hovering"}
    # the barometer (navdata option 21, issue 13 §12): read 0 / "–" before
    page.wait_for_function(
        "document.querySelector('#pressure').textContent.includes('hPa')", timeout=5000
    )
    hpa = page.text_content("#pressure") or ""
    assert re.fullmatch(r"\d{3,4}\.\d hPa", hpa) and 1000 < float(hpa.split()[0]) < 1030, hpa
    assert re.fullmatch(r"-?\d+\.\d °C", page.text_content("#temperature") or "")
    page.wait_for_function(
        "/^\\d+ Hz$/.test(document.querySelector('#link').textContent)", timeout=5000
    )
    # Camera: frames keep coming (the video stream, not one stale picture), fps and latency shown.
    first = frames(page)
    page.wait_for_timeout(2000)
    second = frames(page)
    fps = (second - first) / 2.0
    assert fps >= 5, f"only {fps} frames/s reached the page"
    # the HUD refreshes twice a second
    page.wait_for_function(
        "/^\\d+(\\.\\d)? fps$/.test(document.querySelector('#cam-fps').textContent)"
        " && /^\\d+ ms$/.test(document.querySelector('#cam-latency').textContent)",
        timeout=5000,
    )
    assert re.fullmatch(r"\d+(\.\d)? fps", page.text_content("#cam-fps") or "")
    latency = page.text_content("#cam-latency") or ""
    assert re.fullmatch(r"\d+ ms", latency), latency
    assert int(latency.split()[0]) < 2000
    # Link quality and the drone's status from REST reached the telemetry panel.
    assert page.get_attribute("#m-link", "data-level") in {"ok", "warn"}


def test_desktop_layout_everything_on_one_screen(console: ConsolePage) -> None:
    """At 1440 × 900 every panel is on screen at once, no scrolling."""
    page = console.page
    page.wait_for_function("uavConsole.map.world !== null", timeout=10_000)
    for sel in (
        "#camera-panel",
        "#telemetry-panel",
        "#controls-panel",
        "#map-panel",
        "#dialog-panel",
        "#btn-emergency",
        "#text-input",
        "#mic",
        "[data-jog='forward']",
    ):
        box = page.locator(sel).bounding_box()
        assert box is not None, sel
        assert box["y"] >= 0 and box["y"] + box["height"] <= 900, (sel, box)
    assert page.evaluate("document.documentElement.scrollHeight") <= 900
    path = SCREENSHOTS / "console-desktop.png"
    if not path.exists():  # the flight test writes a livelier one (flying, with a dialog) over it
        wait_for_video(page)
        SCREENSHOTS.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(path))


def test_map_marker_offers_go_there(console: ConsolePage) -> None:
    page = console.page
    page.wait_for_function("uavConsole.map.world !== null", timeout=10_000)
    # The page lays itself out again as the first telemetry fills the status bar, which can
    # move the map between reading the marker's pixel and clicking it: read it afresh and
    # click again until the popover opens (a person re-aims the same way).
    for _ in range(5):
        pt = page.evaluate("uavConsole.map.markerPixel(2)")
        assert pt is not None
        page.locator("#map").click(position={"x": pt["x"], "y": pt["y"]})
        try:
            page.wait_for_selector("#map-popover:not([hidden])", timeout=1000)
            break
        except PlaywrightTimeout:
            continue
    assert page.is_visible("#map-popover")
    assert page.text_content("#map-go") == "Go to marker 2"
    page.click("#map-cancel")
    assert page.is_hidden("#map-popover")


def test_shortcuts_documented_and_labelled(console: ConsolePage) -> None:
    page = console.page
    page.click(".shortcuts summary")
    doc = page.text_content(".shortcuts") or ""
    for needle in ("Esc", "EMERGENCY", "Space", "Hover", "W", "Q"):
        assert needle in doc
    # Every button has an accessible name.
    unnamed = page.evaluate("""() => [...document.querySelectorAll('button')].filter(b =>
        !(b.getAttribute('aria-label') || b.textContent.trim())).map(b => b.id)""")
    assert unnamed == []
    assert page.get_attribute("#dialog", "aria-live") == "polite"


def test_keyboard_shortcuts_drive_the_controls(console: ConsolePage) -> None:
    """Shift+Esc (even while typing), Space and L always; T and held WASD once armed; Esc never
    stops. Each action carries its source ("keyboard") for the audit log."""
    page = console.page
    page.evaluate("""() => { window.__acts = []; window.__twists = [];
        uavConsole.act = (a, src) => { window.__acts.push([a, src]); };
        uavConsole.publishTwist = (t) => { window.__twists.push(t); }; }""")
    page.click("#text-input")
    page.keyboard.type("t l")  # typing: shortcuts other than Shift+Esc are off
    page.keyboard.press("Escape")  # closes, never stops
    assert page.evaluate("window.__acts") == []
    page.keyboard.press("Shift+Escape")
    assert page.evaluate("window.__acts") == [["emergency", "keyboard"]]
    page.locator("#text-input").blur()
    page.click("#camera-panel")
    for key in ("Space", "t", "l", "w"):  # disarmed: T and W do nothing
        page.keyboard.press(key)
    assert page.evaluate("window.__acts") == [
        ["emergency", "keyboard"],
        ["hover", "keyboard"],
        ["land", "keyboard"],
    ]
    assert page.evaluate("window.__twists") == []
    page.click("#arm-keys")
    page.click("#camera-panel")
    page.keyboard.press("t")
    assert page.evaluate("window.__acts")[-1] == ["takeoff", "keyboard"]
    page.keyboard.down("w")
    page.wait_for_timeout(350)  # ~10 Hz while held
    page.keyboard.up("w")
    twists = page.evaluate("window.__twists")
    assert len(twists) >= 3
    assert all(t["linear"]["x"] == pytest.approx(0.3) for t in twists[:-1])
    assert twists[-1] == {"linear": {"x": 0, "y": 0, "z": 0}, "angular": {"x": 0, "y": 0, "z": 0}}
    page.reload()  # the real hooks again for the later tests on this shared page
    wait_ready(page, lease=True)


def test_page_logic_units(console: ConsolePage) -> None:
    """The console's pure functions, run in the page's own module system."""
    page = console.page
    result = page.evaluate(
        """async () => {
        const c = await import('/static/js/controls.js');
        const d = await import('/static/js/dialog.js');
        const t = await import('/static/js/telemetry.js');
        const s = await import('/static/js/session.js');
        const u = await import('/static/js/util.js');
        return {
          cancel: c.twistFor(new Set(['forward', 'backward', 'up']), 0.4),
          clamp: c.twistFor(new Set(['yaw_left']), 3),
          described: d.describeCommands([{action: 'takeoff'}, {action: 'goto', marker: 2},
                                         {action: 'patrol', markers: [1, 3]}]),
          nothing: d.describeCommands([]),
          loop: t.loopHealth({controller: {rate_hz: 99.9, overruns: 2, stalls: 0,
                                           period_error_p99_s: 0.0044}}),
          noLoop: t.loopHealth({name: 'uav1'}),
          link: [t.linkFlag({link_ok: false}), t.linkFlag({link: true}), t.linkFlag({})],
          role: [s.roleFromStatus('authenticated as observer'), s.roleFromStatus('hello')],
          refused: s.refusedRole('observer may not publish to /cmd_vel'),
          lease: [s.leaseNews('pilot lease lost: another pilot took over'),
                  s.leaseNews('publish refused: another pilot (c7) holds the pilot lease'),
                  s.leaseNews('authenticated as pilot')],
          topic: [u.droneTopic('/cmd_vel', 'uav2', true), u.droneTopic('/cmd_vel', 'uav1', false)],
          yaw: u.quaternionYaw({x: 0, y: 0, z: Math.sin(0.5), w: Math.cos(0.5)}),
          stamp: u.stampSeconds({secs: 10, nsecs: 5e8}),
        };
      }"""
    )
    assert result["cancel"]["linear"] == {"x": 0, "y": 0, "z": 0.4}
    assert result["clamp"]["angular"]["z"] == 1
    assert result["described"] == "takeoff → goto(marker=2) → patrol(markers=1,3)"
    assert result["nothing"] == "nothing"
    loop = result["loop"]
    assert loop["p99_ms"] == pytest.approx(4.4) and loop["overruns"] == 2 and not loop["stalled"]
    assert result["noLoop"] is None
    assert result["link"] == [False, True, None]
    assert result["role"] == ["observer", None]
    assert result["refused"] == "observer"
    assert result["lease"] == ["lost", "lost", None]
    assert result["topic"] == ["/uav2/cmd_vel", "/cmd_vel"]
    assert result["yaw"] == pytest.approx(1.0)
    assert result["stamp"] == pytest.approx(10.5)


def test_map_draws_the_outdoor_gps_field(console: ConsolePage) -> None:
    from drone.sim.world import load_world

    page = console.page
    outdoor = load_world("outdoor").to_dict()
    page.evaluate("w => uavConsole.map.setWorld(w)", outdoor)
    page.evaluate("""() => uavConsole.map.onFleet({drones: [
        {name: 'uav1', role: 'patrolling', position: {x: -15, y: -15, z: 5}, yaw_deg: 90,
         battery: 70, link: true},
        {name: 'uav2', role: 'charging', position: {x: 1.5, y: 0, z: 0}, yaw_deg: 0,
         battery: 20, link: true}]})""")
    page.wait_for_function("uavConsole.map.dirty === false", timeout=3000)
    assert "outdoor" in (page.text_content("#map-caption") or "")
    assert page.evaluate("uavConsole.map.drones.get('uav2').role") == "charging"
    # Waypoints are drawn where the world says: wp1's diamond sits on wp1's map point, on the
    # Web Mercator map around the world's GPS origin (map.js Frame).
    wp = outdoor["waypoints"][0]["position"]
    where = page.evaluate(
        """([x, y]) => { const m = uavConsole.map, p = m.pixelOf(x, y);
            const box = m.container.getBoundingClientRect();
            const r = document.querySelector('.map-waypoint').getBoundingClientRect();
            return [p.x, p.y, r.left + r.width / 2 - box.left, r.top + r.height / 2 - box.top,
                    m.container.dataset.crs]; }""",
        [wp["x"], wp["y"]],
    )
    assert where[0] == pytest.approx(where[2], abs=1.5) and where[1] == pytest.approx(
        where[3], abs=1.5
    )
    assert where[4] == "geo"
    assert page.locator(".map-label[data-drone='uav1']").text_content().startswith("uav1")
    assert console.console_errors() == []
