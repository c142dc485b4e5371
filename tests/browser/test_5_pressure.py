"""The console under pressure (issue 18), in Chromium against the real server and simulator.

Ground truth comes from the simulator (``GET /api/v1/sim/uav1/truth``) and the audit log file.
The server of this file runs its simulated drone on a loopback address of its own.
Tests run in file order on that one server and leave the drone landed and out of emergency.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from server.store import AuditLog
from tests.browser.conftest import (
    AXE,
    PILOT,
    SIZES,
    ConsolePage,
    ServerProcess,
    _server,
    open_console,
    wait_ready,
)
from tests.browser.helpers import is_flying, position, type_command, wait_until
from tests.support.loopback import fresh_address

pytestmark = pytest.mark.browser


@pytest.fixture(scope="module")
def srv(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    yield from _server(tmp_path_factory, "uavc-pressure", fresh_address())


@pytest.fixture
def pilot(browser: Any, srv: ServerProcess) -> Iterator[ConsolePage]:
    ctx, cp = open_console(browser, srv.url(), viewport={"width": 1280, "height": 800}, lease=True)
    try:
        yield cp
    finally:
        ctx.close()


def bot_texts(page: Any) -> list[str]:
    return list(
        page.eval_on_selector_all("#dialog .msg-bot .text", "e => e.map(x => x.textContent)")
    )


def wait_bot(page: Any, pred: str, timeout_ms: int = 10_000) -> str:
    """Wait for a bot reply whose text satisfies the JS predicate on ``t``; returns it."""
    page.wait_for_function(
        f"""[...document.querySelectorAll('#dialog .msg-bot .text')]
            .some(e => (t => {pred})(e.textContent))""",
        timeout=timeout_ms,
    )
    return next(t for t in reversed(bot_texts(page)) if t)


def ensure_landed_and_reset(page: Any, srv: ServerProcess) -> None:
    srv.api("POST", "/drones/uav1/land")  # safety actions need no lease
    wait_until(srv.truth, lambda t: not is_flying(t), timeout_s=20)
    if srv.truth().get("emergency"):
        page.click("#btn-reset")
        wait_until(srv.truth, lambda t: not t.get("emergency"), timeout_s=10)


def settled(page: Any) -> None:
    """The page's telemetry, map and voice check in (what a layout or an axe check reads)."""
    wait_ready(page, telemetry=True, world=True)
    page.wait_for_function("uavConsole.dialog.voice !== 'unknown'", timeout=10_000)


def next_frames(page: Any) -> None:
    """Two animation frames: styles and layout follow a resize, a scroll or a theme."""
    page.evaluate(
        "() => new Promise((ok) => requestAnimationFrame(() => requestAnimationFrame(ok)))"
    )


def audit_rows(srv: ServerProcess) -> list[Any]:
    log = AuditLog(Path(srv.data_dir) / "audit.db")
    try:
        return list(log.recent(200, drone="uav1"))
    finally:
        log.close()


# ---- 1, 3: Esc closes, Shift+Esc stops; shortcuts disarmed by default and audited ----------
def test_shortcuts_disarmed_by_default_then_armed_and_audited(
    pilot: ConsolePage, srv: ServerProcess
) -> None:
    page = pilot.page
    assert page.get_attribute("#arm-keys", "aria-pressed") == "false"
    page.click("#camera-panel")
    page.keyboard.press("t")  # disarmed: nothing may fly
    page.wait_for_selector("#banner:not([hidden])", timeout=3000)
    assert "Keyboard flying" in (page.text_content("#banner") or "")
    time.sleep(1.5)
    assert not is_flying(srv.truth())
    page.click("#arm-keys")
    assert page.get_attribute("#arm-keys", "aria-pressed") == "true"
    page.click("#camera-panel")
    page.keyboard.press("t")
    ok, truth, _ = wait_until(srv.truth, lambda t: position(t)[2] > 0.5, timeout_s=20)
    assert ok, truth
    page.keyboard.down("w")  # a keyboard jog: audited when it starts and when it ends
    page.wait_for_timeout(300)
    page.keyboard.up("w")
    page.keyboard.press("Space")
    page.keyboard.press("l")
    ok, truth, _ = wait_until(srv.truth, lambda t: not is_flying(t), timeout_s=20)
    assert ok, truth
    keyed = {(r.commands[0]["action"], r.action) for r in audit_rows(srv) if r.source == "keyboard"}
    assert {("takeoff", "executed"), ("hover", "executed"), ("land", "executed")} <= keyed
    jogs = [r.outcome for r in audit_rows(srv) if r.commands and r.commands[0]["action"] == "jog"]
    assert any(o.startswith("jog started +0.30") for o in jogs) and "jog ended" in jogs
    page.reload()
    page.wait_for_selector("#conn[data-state='open']", timeout=15_000)
    assert page.get_attribute("#arm-keys", "aria-pressed") == "false"  # off after every load


def test_esc_closes_the_popover_and_never_stops_the_drone(
    pilot: ConsolePage, srv: ServerProcess
) -> None:
    page = pilot.page
    page.click("#btn-takeoff")  # the page holds the pilot lease: take off through it
    ok, truth, _ = wait_until(srv.truth, lambda t: position(t)[2] > 0.5, timeout_s=20)
    assert ok, truth
    page.wait_for_function("uavConsole.map.world !== null", timeout=10_000)
    pt = page.evaluate("uavConsole.map.markerPixel(3)")
    page.locator("#map").click(position={"x": pt["x"], "y": pt["y"]})
    page.wait_for_selector("#map-popover:not([hidden])", timeout=3000)
    page.keyboard.press("Escape")
    page.wait_for_selector("#map-popover", state="hidden", timeout=2000)
    time.sleep(1.5)
    truth = srv.truth()
    assert is_flying(truth) and not truth.get("emergency") and position(truth)[2] > 0.4
    # The keyboard emergency is Shift+Esc, shown on the stop button.
    assert "Shift+Esc" in (page.text_content("#btn-emergency") or "")
    page.keyboard.press("Shift+Escape")
    ok, truth, _ = wait_until(srv.truth, lambda t: bool(t.get("emergency")), timeout_s=10)
    assert ok, truth
    # After the stop the console says a Reset is needed ("Landed." alone would mislead).
    reply = wait_bot(page, "t.includes('Reset')")
    assert "Reset" in reply
    assert "Landed." not in bot_texts(page)[-3:]
    page.wait_for_selector("#sb-flight-v:text('Emergency')", timeout=5000)


# ---- 4: refusals said and shown with the way out --------------------------------------------
def test_refused_take_off_shows_its_reason(pilot: ConsolePage, srv: ServerProcess) -> None:
    page = pilot.page
    ok, truth, _ = wait_until(srv.truth, lambda t: bool(t.get("emergency")), timeout_s=2)
    if not ok:  # run alone: make the emergency first
        page.click("#btn-emergency")
        wait_until(srv.truth, lambda t: bool(t.get("emergency")), timeout_s=10)
    page.click("#btn-takeoff")
    page.wait_for_selector("#banner[data-source='refusal']", timeout=5000)
    shown = page.text_content("#banner") or ""
    assert "emergency" in shown and "Reset" in shown
    wait_bot(page, "t.includes('cannot take off')")
    n = len(bot_texts(page))
    type_command(page, "take off")
    page.wait_for_function(
        "n => document.querySelectorAll('#dialog .msg-bot').length > n", arg=n, timeout=8000
    )
    said = bot_texts(page)[n]
    assert not said.startswith("Taking off") and "Reset" in said
    time.sleep(1.0)
    assert not is_flying(srv.truth())
    page.click("#btn-reset")
    ok, truth, _ = wait_until(srv.truth, lambda t: not t.get("emergency"), timeout_s=10)
    assert ok, truth


# ---- 6: alerts you cannot miss ----------------------------------------------------------------
def test_link_loss_raises_a_banner_with_a_tone_until_acknowledged(
    pilot: ConsolePage, srv: ServerProcess
) -> None:
    page = pilot.page
    # Faults need the pilot lease (issue 14): the page holds it, so the fault names its key.
    key = page.evaluate("uavConsole.api.leaseHolder")
    assert key
    r = httpx.post(
        f"{srv.base}/api/v1/sim/uav1/fault",
        headers={"Authorization": f"Bearer {PILOT}", "X-Pilot-Lease": key},
        json={"kind": "link_loss", "duration_s": 3.0},
        timeout=10.0,
    )
    assert r.status_code == 200, r.text
    page.wait_for_selector("#alert-banner:not([hidden])", timeout=10_000)
    assert "link" in (page.text_content("#alert-text") or "").lower()
    assert page.evaluate("uavConsole.alertBanner.tones") >= 1
    page.wait_for_selector("#sb-link[data-level='alert']", timeout=5000)
    # It stays after the link is back, until the operator acknowledges it.
    wait_until(lambda: srv.api("GET", "/drones/uav1").json(), lambda d: d["link_ok"], 15)
    time.sleep(1.0)
    assert page.is_visible("#alert-banner")
    page.click("#alert-ack")
    assert page.is_hidden("#alert-banner")


def test_voice_state_is_said_honestly(browser: Any, srv: ServerProcess) -> None:
    # Chromium here has no voices: the page says so and the server speaks (espeak-ng).
    ctx, cp = open_console(browser, srv.url())
    try:
        page = cp.page
        page.wait_for_function("uavConsole.dialog.voice !== 'unknown'", timeout=10_000)
        voice = page.evaluate("uavConsole.dialog.voice")
        assert voice in ("server", "none")
        assert "no voices" in (page.text_content("#voice-note") or "")
        assert (page.text_content("#mute .label") or "") != "Voice on"
        if voice == "server":  # the reply is fetched as WAV and played with Web Audio
            page.evaluate("uavConsole.dialog.onReply({text: 'Battery low.', level: 'warn'})")
            page.wait_for_function("(uavConsole.spokenByServer || 0) >= 1", timeout=10_000)
    finally:
        ctx.close()
    with_voices = """Object.defineProperty(window, "speechSynthesis", { configurable: true, value: {
        getVoices() { return [{ name: "v", lang: "en-US" }]; }, speak() {}, cancel() {},
        addEventListener() {} } });"""
    ctx, cp = open_console(browser, srv.url(), init_script=with_voices)
    try:
        cp.page.wait_for_function("uavConsole.dialog.voice === 'browser'", timeout=10_000)
        assert cp.page.text_content("#mute .label") == "Voice on"
        assert cp.page.is_hidden("#voice-note")
    finally:
        ctx.close()


# ---- 7: help that helps -----------------------------------------------------------------------
def test_help_and_did_you_mean(pilot: ConsolePage) -> None:
    page = pilot.page
    type_command(page, "what can you do?")
    assert "take off" in wait_bot(page, "t.includes('Say')")
    type_command(page, "turn arround")
    reply = wait_bot(page, "t.includes('Did you mean')")
    assert "“turn around”" in reply and "None" not in reply


# ---- 2, 9: the stop in one place at every size; the phone layout -----------------------------
def test_stop_stays_put_and_visible_at_every_size(browser: Any, srv: ServerProcess) -> None:
    """One page resized through every size (the layout is CSS media queries on the viewport,
    as when a tablet or phone is turned), checked at each."""
    w, h = SIZES["desktop"]
    ctx, cp = open_console(browser, srv.url(), viewport={"width": w, "height": h})
    try:
        page = cp.page
        settled(page)
        for name, (w, h) in SIZES.items():
            page.set_viewport_size({"width": w, "height": h})
            page.evaluate("window.scrollTo(0, 0)")
            next_frames(page)
            _check_the_stop_at(page, name, w, h)
        assert cp.console_errors() == []
    finally:
        ctx.close()


# Labels cut short ("Emerg…"). The task and the control loop's figures are one line by design
# (their whole text in their title; the status bar's task also in the Task tile): not labels.
CUT_LABELS = """[...document.querySelectorAll('.sb-value, .metric-value')]
    .filter(e => !['sb-task-v', 'task', 'loop'].includes(e.id))
    .filter(e => e.offsetParent && e.scrollWidth > e.clientWidth + 1).map(e => e.id)"""


def _check_the_stop_at(page: Any, name: str, w: int, h: int) -> None:
    rect = """(() => { const r = document.getElementById('btn-emergency')
        .getBoundingClientRect(); return [r.x, r.y, r.width, r.height]; })()"""
    before = page.evaluate(rect)
    x, y, bw, bh = before
    assert x >= 0 and y >= 0 and x + bw <= w and y + bh <= h, (name, before)
    assert bw >= 44 and bh >= 44, (name, before)
    # The dialog grows; the page scrolls to its end: the stop does not move.
    page.evaluate(
        """() => { for (let i = 0; i < 40; i++)
            uavConsole.dialog.onReply({text: `Reply ${i}`, level: 'info', speak: false}); }"""
    )
    page.evaluate("window.scrollTo(0, document.body.scrollHeight)")
    next_frames(page)
    assert page.evaluate(rect) == before, name
    # The command box and the state are on screen too (a phone held landscape hid them).
    for sel in ("#text-input", "#sb-flight"):
        box = page.locator(sel).bounding_box()
        assert box is not None and box["y"] >= 0 and box["y"] + box["height"] <= h, (name, sel, box)
    # No state label is cut at any size.
    cut = page.evaluate(CUT_LABELS)
    assert cut == [], name
    # The stop is the topmost element at its centre (nothing covers it).
    top = page.evaluate(
        f"""document.elementFromPoint({x + bw / 2}, {y + bh / 2})
            ?.closest('#btn-emergency') !== null"""
    )
    assert top, name


def test_phone_upright_layout(browser: Any, srv: ServerProcess) -> None:
    ctx, cp = open_console(browser, srv.url(), viewport={"width": 390, "height": 844})
    try:
        page = cp.page
        settled(page)
        # Touch targets of at least 44 × 44 px, for everything visible that can be pressed.
        small = page.evaluate(
            """() => [...document.querySelectorAll(
                  'button, select, input:not([type=range]), summary, [role=application]')]
                .filter(e => e.offsetParent !== null || getComputedStyle(e).position === 'fixed')
                .map(e => [e.id || e.textContent.trim().slice(0, 20), e.getBoundingClientRect()])
                .filter(([, r]) => r.width > 0 && (r.width < 44 || r.height < 44))
                .map(([n, r]) => `${n} ${Math.round(r.width)}x${Math.round(r.height)}`)"""
        )
        assert small == []
        assert (
            page.evaluate(
                "parseFloat(getComputedStyle(document.getElementById('text-input')).fontSize)"
            )
            >= 16
        )
        # State labels are not cut ("Emerg…").
        cut = page.evaluate(CUT_LABELS)
        assert cut == []
        # The newest reply is visible above the dock.
        page.evaluate(
            "uavConsole.dialog.onReply({text: 'Newest reply here', level: 'info', speak: false})"
        )
        last = page.locator("#last-reply")
        assert last.is_visible() and last.text_content() == "Newest reply here"
        box = last.bounding_box()
        assert box is not None and box["y"] + box["height"] <= 844
        # The map starts within the first screen and a half (it was two screens down).
        assert (
            page.evaluate("document.getElementById('map').getBoundingClientRect().top") < 844 * 1.5
        )
    finally:
        ctx.close()


# ---- 10: accessibility --------------------------------------------------------------------------
def test_axe_finds_no_serious_or_critical_violation(browser: Any, srv: ServerProcess) -> None:
    """axe-core on one page in light and dark at desktop size, then light on a phone."""
    if not AXE.exists():
        pytest.fail(f"{AXE} is missing: make node-deps (npm ci in tests/node)")
    w, h = SIZES["desktop"]
    ctx, cp = open_console(browser, srv.url(), viewport={"width": w, "height": h})
    try:
        page = cp.page
        settled(page)
        page.evaluate("uavConsole.dialog.addSystem('Reconnected.')")
        page.evaluate(
            """uavConsole.dialog.onReply(
                {text: 'Battery is at 80 percent.', level: 'warn', speak: false})"""
        )
        # Evaluated over the DevTools protocol, not as an inline <script>: a page whose CSP
        # forbids inline scripts is checked as it is served.
        page.evaluate(AXE.read_text() + "\n;undefined")
        for scheme, size in (("light", "desktop"), ("dark", "desktop"), ("light", "phone")):
            w, h = SIZES[size]
            page.set_viewport_size({"width": w, "height": h})
            page.emulate_media(color_scheme=scheme)
            next_frames(page)  # the theme's colours applied
            result = page.evaluate("axe.run(document, {resultTypes: ['violations']})")
            bad = [
                f"{v['id']} ({v['impact']}): {[n['target'] for n in v['nodes']][:4]}"
                for v in result["violations"]
                if v["impact"] in ("serious", "critical")
            ]
            assert bad == [], (scheme, size)
    finally:
        ctx.close()


def test_focus_ring_contrast_and_map_keyboard(pilot: ConsolePage) -> None:
    page = pilot.page
    ratio = page.evaluate(
        """() => {
          const lum = (c) => { const [r, g, b] = c.match(/\\d+/g).slice(0, 3).map(Number).map(v => {
              v /= 255; return v <= 0.03928 ? v / 12.92 : ((v + 0.055) / 1.055) ** 2.4; });
            return 0.2126 * r + 0.7152 * g + 0.0722 * b; };
          const b = document.getElementById('btn-land'); b.focus({focusVisible: true});
          const ring = getComputedStyle(b).outlineColor;
          const bgs = [getComputedStyle(document.body).backgroundColor,
                       getComputedStyle(document.querySelector('.panel')).backgroundColor];
          return Math.min(...bgs.map(bg => {
            const [a, c] = [lum(ring), lum(bg)].sort((x, y) => y - x);
            return (a + 0.05) / (c + 0.05); }));
        }"""
    )
    assert ratio >= 3.0
    page.focus("#map")
    page.keyboard.press("ArrowRight")
    page.keyboard.press("Enter")
    page.wait_for_selector("#map-popover:not([hidden])", timeout=2000)
    assert page.text_content("#map-go") == "Go to marker 0"
    page.keyboard.press("Escape")
    page.wait_for_selector("#map-popover", state="hidden", timeout=2000)
    heading = page.text_content("#heading") or ""
    assert heading.endswith("°") and 0 <= int(heading[:-1]) <= 359


def test_status_bar_and_labels_agree(pilot: ConsolePage, srv: ServerProcess) -> None:
    page = pilot.page
    ensure_landed_and_reset(page, srv)
    page.wait_for_selector("#sb-flight-v:text('Landed')", timeout=10_000)
    assert page.text_content("#ctrl-state") == "Landed"
    assert page.text_content("#sb-drone-v") == "uav1"
    assert page.text_content("#sb-battery-v") == page.text_content("#battery")
    assert "idle" in (page.text_content("#sb-task-v") or "")


# ---- 5: stale data greys out; after a reconnect the console says what was lost ------------------
def test_page_logic_of_the_status_bar(pilot: ConsolePage) -> None:
    """One label per flight state; the task with its next step; what a reconnection lost."""
    out = pilot.page.evaluate(
        """async () => {
          const m = await import('/static/js/status.js');
          const c = await import('/static/js/controls.js');
          const t = await import('/static/js/telemetry.js');
          return {
            labels: [m.flightLabel('HOVERING'), m.flightLabel(4), m.flightLabel('EMERGENCY'),
                     m.flightLabel('LANDED', {emergency: true}), m.flightLabel(6)],
            task: m.taskText({name: 'patrol', state: 'running', progress: 0.4,
                              detail: 'marker 3', queued: 1}),
            idle: m.taskText({name: '', state: 'idle'}),
            lost: m.lostWhileAway(
              {drone: 'uav1', flight: 'Hovering', task: {name: 'patrol', state: 'running'}},
              {drone: 'uav1', flight: 'Landed', task: {name: '', state: 'idle'}}),
            same: m.lostWhileAway({flight: 'Landed', task: null}, {flight: 'Landed', task: null}),
            esc: [c.escapeMeaning({key: 'Escape', shiftKey: false}),
                  c.escapeMeaning({key: 'Escape', shiftKey: true}), c.escapeMeaning({key: 'x'})],
            moving: ['t', 'w', 'arrowup', 'q', 'l', ' '].map(k => c.MOVING_KEYS.has(k)),
            bearings: [0, 90, 180, -90, 45].map(t.compassBearing),
          };
        }"""
    )
    assert out["labels"] == ["Hovering", "Hovering", "Emergency", "Emergency", "Taking off"]
    assert out["task"] == "patrol · running 40 % — next: marker 3 · then 1 more"
    assert out["idle"] == "idle"
    assert out["lost"] == [
        "The patrol no longer runs.",
        "The drone went from hovering to landed.",
    ]
    assert out["same"] == []
    assert out["esc"] == ["close", "emergency", None]
    assert out["moving"] == [True, True, True, True, False, False]
    # Map frame yaw (REP 103, 0 = +x = east) as a compass bearing (0 = north = +y).
    assert out["bearings"] == [90, 0, 270, 180, 45]
