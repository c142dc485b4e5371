"""``uav-console replay``: the console in Chromium on a recording, with the timeline bar."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import httpx
import pytest

from tests.browser.conftest import ROOT, SCREENSHOTS, START_TIMEOUT_S, open_console
from tests.recorder.synthetic import write_flight
from tests.support.loopback import free_port

pytestmark = pytest.mark.browser
TOKEN = "replay-browser-token"


def test_replay_shows_the_recorded_flight_with_a_timeline(browser: Any, tmp_path: Path) -> None:
    path = write_flight(tmp_path / "flights")
    port = free_port()
    log = (tmp_path / "replay.log").open("wb")
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "server",
            "replay",
            str(path),
            "--port",
            str(port),
            "--token",
            TOKEN,
        ],
        cwd=ROOT,
        stdout=log,
        stderr=subprocess.STDOUT,
    )
    try:
        base = f"http://127.0.0.1:{port}"
        deadline = time.monotonic() + START_TIMEOUT_S
        while True:
            assert proc.poll() is None, (tmp_path / "replay.log").read_text()
            assert time.monotonic() < deadline, "replay did not start"
            try:
                if httpx.get(f"{base}/api/v1/health", timeout=1).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            time.sleep(0.2)
        ctx, cp = open_console(browser, f"{base}/?token={TOKEN}")
        page = cp.page
        try:
            page.wait_for_selector("#replay-bar:not([hidden])", timeout=10_000)
            page.wait_for_function(
                "Number(document.querySelector('#camera').dataset.frames || 0) > 2",
                timeout=10_000,
            )
            page.wait_for_function(
                "document.querySelector('#battery').textContent.includes('%')", timeout=10_000
            )
            page.wait_for_function(
                "document.querySelector('#dialog').textContent.includes('Taking off')",
                timeout=10_000,
            )
            page.wait_for_function("uavConsole.map.drones.size > 0", timeout=10_000)
            trail = page.evaluate("[...uavConsole.map.drones.values()][0].trail.length")
            assert trail > 0
            # The timeline is one row: play, seek, time (console.css .replay-bar, a flex row;
            # a stray merge marker once dropped that rule and stacked them).
            assert page.eval_on_selector("#replay-bar", "e => getComputedStyle(e).display") == (
                "flex"
            )
            SCREENSHOTS.mkdir(parents=True, exist_ok=True)
            page.screenshot(path=str(SCREENSHOTS / "replay.png"))
            page.click("#replay-play")  # pause
            page.wait_for_function(
                "document.querySelector('#replay-play').textContent === 'Play'", timeout=5_000
            )
            page.eval_on_selector(
                "#replay-seek",
                "el => { el.value = '9'; el.dispatchEvent(new Event('change')); }",
            )
            page.wait_for_function(
                "document.querySelector('#replay-time').textContent.startsWith('0:09')",
                timeout=5_000,
            )
            status = httpx.get(
                f"{base}/api/v1/replay", headers={"Authorization": f"Bearer {TOKEN}"}
            ).json()
            assert status["position_s"] == pytest.approx(9.0) and not status["playing"]
            assert page.get_attribute("#role", "data-role") == "observer"  # read-only page
            assert cp.console_errors() == []
        finally:
            ctx.close()
    finally:
        proc.terminate()
        proc.wait(10)
        log.close()


def test_replay_shows_every_input_in_order_with_its_door(browser: Any, tmp_path: Path) -> None:
    """The operator's sentences of a recording, whatever their door (REST, the page's
    microphone, a rosbridge client), in the order said, each with its reply's annotation."""
    path = write_flight(tmp_path / "flights")
    port = free_port()
    log = (tmp_path / "replay.log").open("wb")
    cmd = [sys.executable, "-m", "server", "replay", str(path), "--paused"]
    cmd += ["--port", str(port), "--token", TOKEN]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT)
    auth = {"Authorization": f"Bearer {TOKEN}"}
    try:
        base = f"http://127.0.0.1:{port}"
        deadline = time.monotonic() + START_TIMEOUT_S
        while True:
            assert proc.poll() is None, (tmp_path / "replay.log").read_text()
            assert time.monotonic() < deadline, "replay did not start"
            try:
                if httpx.get(f"{base}/api/v1/health", timeout=1).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            time.sleep(0.2)
        ctx, cp = open_console(browser, f"{base}/?token={TOKEN}")
        page = cp.page
        try:
            page.wait_for_selector("#replay-bar:not([hidden])", timeout=10_000)
            page.wait_for_function("uavConsole.ros.subscriptions.has('/console/utterance')")
            # from the start, four times as fast as it was flown
            httpx.post(f"{base}/api/v1/replay", json={"action": "speed", "speed": 4}, headers=auth)
            httpx.post(f"{base}/api/v1/replay", json={"action": "play"}, headers=auth)
            page.wait_for_function(
                "document.querySelector('#dialog').textContent.includes('Landed')",
                timeout=20_000,
            )
            said = page.eval_on_selector_all(
                "#dialog .msg-user",
                "els => els.map(e => [e.querySelector('.text').textContent,"
                " e.querySelector('.meta')?.textContent || '',"
                " e.querySelector('.understood') !== null])",
            )
            assert said == [
                ["take off", "sent over REST", True],
                ["how high are you", "spoken · confidence 87 %", True],
                ["land", "sent over rosbridge", True],
            ], said
            assert cp.console_errors() == []
        finally:
            ctx.close()
    finally:
        proc.terminate()
        proc.wait(10)
        log.close()
