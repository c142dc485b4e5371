"""Replay in the page: a real flight recorded by the console, opened from its Recordings menu.

The pilot types "take off", injects a link loss from the training panel, types "land"; the
recorder closes the flight soon after (``UAVC_RECORDER_IDLE_S``). The Recordings menu's Replay
button opens a tab that replays it read-only: the timeline spans the flight, the dialog's and
the alarm's times are the recording's (read back from the MCAP file), no latency is shown for
the recorded video, and the replay commands nothing.
"""

from __future__ import annotations

import datetime as dt
import time
from pathlib import Path
from typing import Any

import pytest

from server.recorder.mcapfile import read_recording
from tests.browser.conftest import ServerProcess, open_console
from tests.browser.helpers import is_flying, position, type_command, wait_until
from tests.support.loopback import fresh_address

pytestmark = pytest.mark.browser


@pytest.fixture
def recording_server(
    tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch
) -> Any:
    """A server of its own whose flight sessions end 2 s after landing (default 30 s)."""
    monkeypatch.setenv("UAVC_RECORDER_IDLE_S", "2")
    server = ServerProcess(tmp_path_factory.mktemp("uavc-replay-page"), fresh_address())
    server.start()
    try:
        yield server
    finally:
        server.stop()


def iso_s(text: str) -> float:
    return dt.datetime.fromisoformat(text.replace("Z", "+00:00")).timestamp()


def stamp_s(msg: dict[str, Any]) -> float:
    s = msg["header"]["stamp"]
    return float(s.get("sec", s.get("secs"))) + float(s.get("nanosec", s.get("nsecs", 0))) / 1e9


def test_replay_a_recorded_flight_from_the_menu(
    browser: Any, recording_server: ServerProcess
) -> None:
    server = recording_server
    ctx, cp = open_console(browser, server.url())
    page = cp.page
    try:
        # -- fly: take off, a link loss, land ------------------------------------------------
        page.wait_for_function("uavConsole.haveLease === true", timeout=10_000)
        type_command(page, "take off")
        ok, truth, _ = wait_until(server.truth, lambda t: is_flying(t) and position(t)[2] > 0.6, 30)
        assert ok, truth
        page.wait_for_selector("#training:not([hidden])", timeout=10_000)
        page.click("#training > summary")
        page.fill("#training input[data-fault='link_loss']", "2")
        page.click("#training button[data-fault='link_loss']")
        page.wait_for_function(
            "(document.querySelector('#alert-banner').dataset.keys || '').includes('uav1:link')",
            timeout=15_000,
        )
        ok, drone, _ = wait_until(
            lambda: server.api("GET", "/drones/uav1").json(), lambda d: d["link_ok"], 20
        )
        assert ok, drone
        page.click("#alert-ack")
        type_command(page, "land")
        ok, truth, _ = wait_until(server.truth, lambda t: not is_flying(t), 30)
        assert ok, truth
        ok, flights, _ = wait_until(
            lambda: server.api("GET", "/flights").json()["flights"],
            lambda fs: len(fs) == 1 and fs[0]["ended"] is not None,
            30,
        )
        assert ok, flights
        (flight,) = flights
        flown_s = iso_s(flight["ended"]) - iso_s(flight["started"])

        # What the recording holds: the operator's words and the link alarm, with their times.
        recording = read_recording(Path(server.data_dir) / "flights" / f"{flight['id']}.mcap")
        said = {
            m["text"]: t / 1e9
            for ch, t, m in recording.decoded()
            if ch.topic == "/console/utterance"
        }
        alarms = [
            m
            for ch, _t, m in recording.decoded()
            if ch.topic == "/console/reply"
            and m.get("alarm") == "link"
            and m.get("level") in ("alert", "warn")
        ]
        assert "take off" in said and alarms, (said, alarms)
        alarm_at = stamp_s(alarms[0])
        replies = {
            m["text"]: stamp_s(m)
            for ch, _t, m in recording.decoded()
            if ch.topic == "/console/reply" and m.get("utterance") == "take off"
        }
        assert replies, "no reply to take off recorded"

        # -- replay it from the menu, in a tab of its own ------------------------------------
        replay_errors: list[str] = []
        ctx.on(
            "console",
            lambda m: (
                replay_errors.append(m.text) if m.type == "error" and m.page is not page else None
            ),
        )
        page.click("#recordings > summary")
        button = f"#recordings-list button[data-replay='{flight['id']}']"
        page.wait_for_selector(button, timeout=10_000)
        with ctx.expect_page() as opened:
            page.click(button)
        replay = opened.value
        replay.wait_for_selector("#replay-bar:not([hidden])", timeout=20_000)
        assert f"replay={flight['id']}" in replay.url and "token" not in replay.url
        replay.wait_for_selector("#role[data-role='observer']", timeout=10_000)
        status = replay.evaluate("uavConsole.replay.status")
        # the timeline spans the flight: its length, plus at most the 10 s pre-roll
        assert flown_s - 2.0 <= status["duration_s"] <= flown_s + 10.5, (status, flown_s)
        total = int(status["duration_s"])
        assert replay.inner_text("#replay-time").endswith(f"{total // 60}:{total % 60:02d}")

        replay.select_option("#replay-speed", "2")
        replay.wait_for_function(
            "Number(document.querySelector('#camera').dataset.frames || 0) > 3", timeout=20_000
        )
        # no latency figure for recorded video
        hud = replay.inner_text(".camera-hud")
        assert "ms" not in hud and "fps" in hud, hud
        assert replay.is_hidden("#cam-latency")

        # The operator's words and the drone's reply, at the recording's times.
        replay.wait_for_function(
            "[...document.querySelectorAll('#dialog .msg-user')]"
            ".some(e => e.dataset.utterance === 'take off')",
            timeout=30_000,
        )
        line = replay.evaluate(
            "(() => { const e = [...document.querySelectorAll('#dialog .msg-user')]"
            ".find(e => e.dataset.utterance === 'take off');"
            " return { at: Number(e.dataset.at), meta: e.querySelector('.meta').textContent,"
            " text: e.textContent }; })()"
        )
        assert abs(line["at"] - said["take off"]) < 1.5, (line, said)
        assert "operator" in line["meta"] and "another console" not in line["text"]
        reply_text, reply_at = next(iter(replies.items()))
        replay.wait_for_function(
            "t => [...document.querySelectorAll('#dialog .msg-bot')]"
            ".some(e => e.dataset.reply === t)",
            arg=reply_text,
            timeout=20_000,
        )
        shown = replay.evaluate(
            "t => { const e = [...document.querySelectorAll('#dialog .msg-bot')]"
            ".find(e => e.dataset.reply === t);"
            " return [Number(e.dataset.at), e.querySelector('time').textContent]; }",
            reply_text,
        )
        assert shown[0] == pytest.approx(reply_at, abs=1e-3)
        assert shown[1] == clock_text(replay, reply_at)

        # The link alarm: raised at the recording's time, not today's.
        replay.wait_for_function(
            "(document.querySelector('#alert-banner').dataset.keys || '').split(' ')"
            ".includes('uav1:link')",
            timeout=30_000,
        )
        banner = replay.inner_text("#alert-text")
        assert f"({clock_text(replay, alarm_at)})" in banner, (banner, alarm_at)
        assert time.time() - alarm_at > 5  # today's clock would have shown another time

        # Read-only: the replay's doors refuse commands; the live drone never moved.
        before = position(server.truth())
        replay.evaluate("uavConsole.act('takeoff')")
        refused = replay.evaluate(
            "uavConsole.api.post('/drones/uav1/takeoff', {}).then(() => 'sent', e => e.status)"
        )
        assert refused == 409
        assert not is_flying(server.truth()) and position(server.truth()) == pytest.approx(before)
        assert [e for e in replay_errors if "409" not in e] == []
        assert cp.console_errors() == []
    finally:
        ctx.close()


def clock_text(page: Any, unix_s: float) -> str:
    """The page's own rendering of a time (its locale and time zone)."""
    return str(
        page.evaluate("s => new Date(s * 1000).toLocaleTimeString([], { hour12: false })", unix_s)
    )
