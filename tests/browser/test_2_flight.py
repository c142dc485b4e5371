"""Flying the simulated drone from the console; ground truth from GET /api/v1/sim/uav1/truth.

The tests run in file order on the shared server: a low-confidence utterance is not executed,
typed "take off" climbs, "go to marker 2" from the map flies there, a confident spoken command
is executed, the jog pad moves the drone and stops it on release, EMERGENCY STOP cuts the motors.
"""

from __future__ import annotations

import math
import re
import time
from collections.abc import Iterator
from typing import Any

import pytest

from tests.browser.conftest import SCREENSHOTS, ConsolePage, ServerProcess, open_console
from tests.browser.helpers import (
    SPEECH_STANDIN,
    is_flying,
    motors_cut,
    position,
    speed,
    wait_until,
)

pytestmark = pytest.mark.browser

REPEAT = re.compile(r"repeat|again|rephrase|not sure|didn.t (catch|understand)|say that", re.I)


@pytest.fixture(scope="module")
def pilot(browser: Any, server: ServerProcess) -> Iterator[ConsolePage]:
    """One pilot console for the whole flight, with the speech stand-ins installed."""
    ctx, cp = open_console(browser, server.url(), init_script=SPEECH_STANDIN)
    try:
        yield cp
    finally:
        ctx.close()


def say(page: Any, text: str, confidence: float) -> None:
    page.evaluate(
        "([t, c]) => { window.__speech.next = {text: t, confidence: c}; }", [text, confidence]
    )
    page.click("#mic")


def bot_replies(page: Any) -> list[str]:
    return list(
        page.eval_on_selector_all("#dialog .msg-bot .text", "els => els.map(e => e.textContent)")
    )


def last_user_entry(page: Any) -> str:
    """Text of the newest operator entry in the dialog (with its "understood: …" line)."""
    return str(
        page.evaluate(
            "[...document.querySelectorAll('#dialog .msg-user')].pop()?.textContent || ''"
        )
    )


def wait_understood(page: Any, said: str, timeout_ms: int = 8000) -> str:
    """The newest operator entry once it is ``said`` and shows how the server understood it.

    Waiting for the next reply instead raced: a reply to an earlier command ("Reached marker
    2.") could arrive first, and the newest entry was still the earlier one."""
    page.wait_for_function(
        "s => { const e = [...document.querySelectorAll('#dialog .msg-user')].pop();"
        " return !!e && e.textContent.includes(s) && e.dataset.pending === '0'; }",
        arg=said,
        timeout=timeout_ms,
    )
    return last_user_entry(page)


def wait_reply(page: Any, before: int, timeout_ms: int = 8000) -> str:
    page.wait_for_function(
        "n => document.querySelectorAll('#dialog .msg-bot').length > n",
        arg=before,
        timeout=timeout_ms,
    )
    return bot_replies(page)[before]


def test_low_confidence_speech_asks_to_repeat(pilot: ConsolePage, server: ServerProcess) -> None:
    page = pilot.page
    assert not is_flying(server.truth())
    n = len(bot_replies(page))
    say(page, "take off", 0.2)  # under Settings.confirm_floor too: not even "Did you say …?"
    reply = wait_reply(page, n)
    assert REPEAT.search(reply), reply
    entry = wait_understood(page, "take off")
    assert "take off" in entry and "confidence 20 %" in entry
    assert "understood: nothing" in entry  # not executed, so nothing was taken from it
    time.sleep(1.5)  # long enough that a take-off would have left the ground
    assert not is_flying(server.truth())
    assert position(server.truth())[2] < 0.1


def test_typed_take_off_climbs(pilot: ConsolePage, server: ServerProcess) -> None:
    page = pilot.page
    n = len(bot_replies(page))
    page.fill("#text-input", "take off")
    page.press("#text-input", "Enter")
    assert page.input_value("#text-input") == ""
    ok, truth, took = wait_until(server.truth, lambda t: position(t)[2] > 0.5, timeout_s=20)
    assert ok, f"still at z={position(truth)[2]:.2f} m after {took:.1f} s"
    # The dialog shows the exchange: the utterance, how it was understood, and a reply.
    wait_reply(page, n)
    user = wait_understood(page, "take off")
    assert "take off" in user and "understood: takeoff" in user, user
    # The spoken reply went to speechSynthesis (unmuted by default).
    assert page.evaluate("window.__speech.spoken.length") >= 1


def test_did_you_say_is_answered_with_the_buttons(
    pilot: ConsolePage, server: ServerProcess
) -> None:
    """A spoken "land" heard at 0.4 (between Settings.confirm_floor and the threshold) is read
    back with Yes / No buttons: No keeps the drone flying and closes the buttons, Yes lands it."""
    page = pilot.page
    ensure_flying(page, server)
    n = len(bot_replies(page))
    say(page, "land", 0.4)
    assert wait_reply(page, n).startswith('Did you say "land"?')
    answers = page.locator("#dialog .msg-bot").nth(n).locator(".answers button")
    assert answers.all_text_contents() == ["Yes, do it", "No"]
    SCREENSHOTS.mkdir(parents=True, exist_ok=True)
    page.locator(".panel-dialog").screenshot(path=str(SCREENSHOTS / "did-you-say.png"))
    n = len(bot_replies(page))
    answers.nth(1).click()
    assert wait_reply(page, n) == "OK, I will not do that."
    assert "answered with a button" in wait_understood(page, "no")
    assert answers.nth(0).is_disabled() and answers.nth(1).is_disabled()
    time.sleep(1.0)
    assert is_flying(server.truth()) and position(server.truth())[2] > 0.5

    n = len(bot_replies(page))
    say(page, "land", 0.4)
    assert wait_reply(page, n).startswith('Did you say "land"?')
    asked = page.locator("#dialog .msg-bot").nth(n)
    asked.locator(".answers button").first.click()
    wait_reply(page, n + 1)
    assert "understood: land" in wait_understood(page, "yes")
    ok, truth, took = wait_until(server.truth, lambda t: not is_flying(t), timeout_s=15)
    assert ok, f"still flying {took:.0f} s after the yes: {truth}"
    assert asked.locator(".answers button").first.is_disabled()


def test_map_go_to_marker_2(pilot: ConsolePage, server: ServerProcess) -> None:
    """Clicking marker 2 on the map offers "go there"; taking it flies the drone in front of it."""
    page = pilot.page
    ensure_flying(page, server)
    world = server.api("GET", "/world").json()
    marker = next(m for m in world["markers"] if m["id"] == 2)
    mx, my = marker["position"]["x"], marker["position"]["y"]
    yaw = marker["yaw_rad"]
    n = len(bot_replies(page))
    pt = page.evaluate("uavConsole.map.markerPixel(2)")
    page.locator("#map").click(position={"x": pt["x"], "y": pt["y"]})
    page.click("#map-go")  # sends "go to marker 2" (POST /api/v1/command)
    wait_reply(page, n)
    user = wait_understood(page, "go to marker 2")
    assert "go to marker 2" in user and "goto(marker=2)" in user, user

    # The task flies to a stand-off pose in front of the marker, facing it (about 1 m away).
    def near(t: dict[str, Any]) -> bool:
        x, y, _ = position(t)
        along = (x - mx) * math.cos(yaw) + (y - my) * math.sin(yaw)
        across = -(x - mx) * math.sin(yaw) + (y - my) * math.cos(yaw)
        return 0.4 < along < 1.6 and abs(across) < 0.35 and speed(t) < 0.3

    ok, truth, took = wait_until(server.truth, near, timeout_s=45, period_s=0.25)
    assert ok, f"not in front of marker 2 after {took:.0f} s: {truth}; dialog: {bot_replies(page)}"
    # The map marks the target while the task runs, then the camera sees the marker.
    page.wait_for_timeout(500)
    SCREENSHOTS.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=str(SCREENSHOTS / "console-desktop.png"))


def test_confident_speech_is_executed(pilot: ConsolePage, server: ServerProcess) -> None:
    """A spoken "turn left 90 degrees" at confidence 0.9 turns the drone counter-clockwise."""
    page = pilot.page
    ensure_flying(page, server)
    yaw0 = float(server.truth()["yaw_rad"])
    n = len(bot_replies(page))
    say(page, "turn left 90 degrees", 0.9)
    wait_reply(page, n)
    user = wait_understood(page, "turn left 90 degrees")
    assert "confidence 90 %" in user and "turn(" in user, user

    def turned(t: dict[str, Any]) -> float:
        return math.degrees(math.remainder(float(t["yaw_rad"]) - yaw0, math.tau))

    ok, truth, took = wait_until(
        server.truth, lambda t: abs(turned(t) - 90) < 10 and speed(t) < 0.2, timeout_s=20
    )
    assert ok, f"turned {turned(truth):.0f}° in {took:.0f} s; dialog: {bot_replies(page)}"


def ensure_flying(page: Any, server: ServerProcess) -> None:
    """Bring the drone up with the Take off button if an earlier step left it on the ground."""
    truth = server.truth()
    if truth.get("emergency"):
        page.click("#btn-reset")
        wait_until(server.truth, lambda t: not t.get("emergency"), timeout_s=3)
    if not is_flying(truth) or position(truth)[2] < 0.4:
        page.click("#btn-takeoff")
        ok, truth, took = wait_until(server.truth, lambda t: position(t)[2] > 0.5, timeout_s=15)
        assert ok, f"the Take off button did not lift the drone in {took:.0f} s: {truth}"
        wait_until(server.truth, lambda t: speed(t) < 0.15, timeout_s=5)


def jog_towards_room_centre(truth: dict[str, Any], centre: tuple[float, float]) -> str:
    """The jog direction (body frame) that points most nearly at the middle of the room."""
    x, y, _ = position(truth)
    yaw = float(truth["yaw_rad"])
    dx, dy = centre[0] - x, centre[1] - y
    fwd = dx * math.cos(yaw) + dy * math.sin(yaw)
    left = -dx * math.sin(yaw) + dy * math.cos(yaw)
    options = {"forward": fwd, "backward": -fwd, "left": left, "right": -left}
    return max(options, key=lambda k: options[k])


def test_jog_moves_and_stops_on_release(pilot: ConsolePage, server: ServerProcess) -> None:
    page = pilot.page
    ensure_flying(page, server)
    bounds = server.api("GET", "/world").json()["bounds"]
    centre = ((bounds["x_min"] + bounds["x_max"]) / 2, (bounds["y_min"] + bounds["y_max"]) / 2)
    start = server.truth()
    x0, y0, _ = position(start)
    direction = jog_towards_room_centre(start, centre)
    box = page.locator(f"[data-jog='{direction}']").bounding_box()
    assert box is not None
    page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    page.mouse.down()
    try:
        assert page.get_attribute("body", "data-jogging") == direction
        ok, truth, _ = wait_until(
            server.truth,
            lambda t: math.hypot(position(t)[0] - x0, position(t)[1] - y0) > 0.25,
            timeout_s=5,
        )
    finally:
        page.mouse.up()
    assert ok, f"jog {direction} moved the drone only to {position(truth)} from {(x0, y0)}"
    # It moved the way the button says: towards the centre, as chosen.
    x, y, _ = position(truth)
    assert math.hypot(centre[0] - x, centre[1] - y) < math.hypot(centre[0] - x0, centre[1] - y0)
    assert page.get_attribute("body", "data-jogging") == ""
    # Released: the zero Twist hovers it; it comes to rest within a few seconds.
    ok, truth, _ = wait_until(server.truth, lambda t: speed(t) < 0.1, timeout_s=6)
    assert ok, f"still moving at {speed(truth):.2f} m/s after release"
    x1, y1, _ = position(truth)
    time.sleep(1.0)
    x2, y2, _ = position(server.truth())
    assert math.hypot(x2 - x1, y2 - y1) < 0.15


def test_emergency_stop_cuts_the_motors(pilot: ConsolePage, server: ServerProcess) -> None:
    page = pilot.page
    ensure_flying(page, server)
    t0 = time.monotonic()
    page.click("#btn-emergency")
    ok, truth, took = wait_until(server.truth, motors_cut, timeout_s=3, period_s=0.02)
    assert ok, f"motors still on {took:.1f} s after EMERGENCY STOP: {truth}"
    # One round trip: the REST call and the next AT datagram (30 ms); generous for a busy CI.
    assert time.monotonic() - t0 < 1.0
    assert "EMERGENCY STOP" in (page.text_content("#dialog") or "")
    server.api("POST", "/drones/uav1/reset")
