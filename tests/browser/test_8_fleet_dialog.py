"""One dialog for a fleet: each line says which drone once, the operator's sentence is shown
once as theirs (however many drones answer it), repeated state lines fold."""

from __future__ import annotations

from typing import Any

import pytest

from tests.browser.conftest import ConsolePage, ServerProcess, open_console
from tests.browser.helpers import is_flying, type_command, wait_until

pytestmark = pytest.mark.browser

LINES = """() => [...document.querySelectorAll('#dialog .msg')].map(e => ({
  kind: e.classList.contains('msg-user') ? 'user' : e.classList.contains('msg-bot') ? 'bot' : 'sys',
  who: e.querySelector('.who')?.textContent || '',
  text: e.querySelector('.text')?.textContent || '',
  meta: e.querySelector('.meta')?.textContent || '',
  understood: [...e.querySelectorAll('.understood')].map(u => u.textContent),
  count: e.querySelector('.count')?.textContent || '',
}))"""


def test_all_drones_commands_show_once_and_name_their_drones(
    browser: Any, fleet_server: ServerProcess
) -> None:
    ctx, cp = open_console(browser, fleet_server.url())
    page = cp.page
    try:
        page.wait_for_selector("#drone-select-wrap:not([hidden])", timeout=10_000)
        page.wait_for_function("uavConsole.haveLease === true", timeout=10_000)
        type_command(page, "all drones take off")
        for name in ("uav1", "uav2"):
            ok, truth, _ = wait_until(lambda n=name: fleet_server.truth(n), is_flying, 30)
            assert ok, (name, truth)
        # both drones answered: one line, theirs, understood by both
        page.wait_for_function(
            "[...document.querySelectorAll('#dialog .msg-user .understood')]"
            ".some(u => u.textContent.includes('uav1') && u.textContent.includes('uav2'))",
            timeout=15_000,
        )
        type_command(page, "all drones land")
        for name in ("uav1", "uav2"):
            ok, truth, _ = wait_until(
                lambda n=name: fleet_server.truth(n), lambda t: not is_flying(t), 30
            )
            assert ok, (name, truth)
        page.wait_for_function(
            "[...document.querySelectorAll('#dialog .msg-user')]"
            ".filter(e => e.dataset.utterance === 'all drones land')"
            ".some(e => (e.dataset.answeredBy || '').split(' ').length === 2)",
            timeout=15_000,
        )
        lines = page.evaluate(LINES)
        users = [x for x in lines if x["kind"] == "user"]
        assert [u["text"] for u in users] == ["all drones take off", "all drones land"], lines
        assert all(u["meta"] == "typed" for u in users), users
        assert not any("another console" in x["meta"] for x in lines)
        for u in users:
            (understood,) = u["understood"]
            assert understood.endswith("uav1, uav2") or understood.endswith("uav2, uav1"), u
        bots = [x for x in lines if x["kind"] == "bot"]
        assert bots and all(b["who"] in ("uav1", "uav2") for b in bots), bots
        # the drone is named once: in the tag, not again at the start of the text
        assert not any(b["text"].lower().startswith(("uav1", "uav2")) for b in bots), bots
        assert {b["who"] for b in bots} == {"uav1", "uav2"}
        assert cp.console_errors() == []
    finally:
        ctx.close()


def test_repeated_state_lines_fold_per_drone(console: ConsolePage) -> None:
    """A drone saying "Hovering" again and again is one line with a count; another drone's
    line, an alarm or the operator speaking in between keep their own lines. (The dialog
    panel of the shared server's page, told it shows a fleet, fed replies as rosbridge
    delivers them.)"""
    cp = console
    page = cp.page
    page.evaluate("uavConsole.dialog.clear(); uavConsole.dialog.setFleet(true)")
    page.evaluate(
        """() => {
          const d = uavConsole.dialog;
          const say = (drone, text, level = 'info') => d.onReply(
            { drone, text, level, speak: false, header: { stamp: { sec: 1780000000 } } });
          for (let i = 0; i < 12; i++) { say('uav1', 'Hovering'); say('uav2', 'uav2: Hovering'); }
          say('uav1', 'Battery low: 24 %.', 'warn');
          say('uav1', 'Battery low: 24 %.', 'warn');
          d.addUtterance('uav1 land', { drone: 'uav2' });
          say('uav1', 'Hovering');
        }"""
    )
    lines = page.evaluate(LINES)
    shown = [(x["who"], x["text"], x["count"]) for x in lines]
    assert shown == [
        ("uav1", "Hovering", " ×12"),
        ("uav2", "Hovering", " ×12"),
        ("uav1", "Battery low: 24 %.", ""),
        ("uav1", "Battery low: 24 %.", ""),  # a warning is never folded away
        ("", "uav1 land", ""),  # names its drone itself: no second tag
        ("uav1", "Hovering", ""),  # the operator spoke since: a new line
    ], shown
    assert cp.console_errors() == []
