"""Speaking to the drone from Chromium, recognised on the console's own machine (issue 15).

Chromium is launched with a fake microphone that plays a WAV synthesised at run time
(``--use-file-for-fake-audio-capture``), so the whole path runs for real: getUserMedia, the
AudioWorklet's 16 kHz PCM, the authenticated WebSocket, faster-whisper on the server, the final
text down the dialog path, and the simulated drone taking off. The server listens on 0.0.0.0,
so it serves HTTPS with its own CA; Chromium trusts exactly its key
(``--ignore-certificate-errors-spki-list``), as a phone trusts the downloaded CA.
"""

from __future__ import annotations

import base64
import contextlib
import hashlib
import os
import ssl
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import pytest
from cryptography import x509
from cryptography.hazmat.primitives import serialization

from tests.browser.conftest import CHROMIUM, CHROMIUM_ARGS, OBSERVER, PILOT, ROOT
from tests.browser.helpers import wait_until
from tests.speech.conftest import HAVE_TTS, synthesise
from tests.support.loopback import bus_endpoint, free_port, fresh_address

SIM_ADDR = fresh_address()
pytestmark = pytest.mark.skipif(not HAVE_TTS, reason="espeak-ng and sox are needed")


@dataclass
class TlsServer:
    port: int
    data: Path
    proc: subprocess.Popen[bytes]
    http: httpx.Client

    def url(self, token: str = PILOT) -> str:
        return f"https://127.0.0.1:{self.port}/?token={token}"

    def truth(self) -> dict[str, Any]:
        return dict(self.http.get("/api/v1/sim/uav1/truth").json())

    def why(self, page: Any) -> str:
        """What a failure needs to be understood: the page's dialog and notice line, and the
        server's last log lines."""
        log = (self.data / "server.log").read_text(errors="replace").splitlines()[-40:]
        dialog, interim = page.inner_text("#dialog"), page.inner_text("#interim")
        return "\n".join([f"dialog: {dialog!r}", f"interim: {interim!r}", *log])

    def spki_hash(self) -> str:
        cert = x509.load_pem_x509_certificate((self.data / "tls" / "server.pem").read_bytes())
        spki = cert.public_key().public_bytes(
            serialization.Encoding.DER, serialization.PublicFormat.SubjectPublicKeyInfo
        )
        return base64.b64encode(hashlib.sha256(spki).digest()).decode()


@pytest.fixture(scope="module")
def tls_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TlsServer]:
    if os.environ.get("UAVC_SKIP_BROWSER") == "1":
        pytest.skip("UAVC_SKIP_BROWSER=1")
    data = tmp_path_factory.mktemp("speech-browser")
    port = free_port()
    env = dict(os.environ, UAVC_SIM_BASE_ADDR=SIM_ADDR, PYTHONUNBUFFERED="1")
    env.setdefault("UAVC_VEHICLES", "inline")  # speech, not isolation (tests/isolation)
    env.setdefault("UAVC_BUS_LISTEN", bus_endpoint())  # a bus router off 7447
    cmd = [
        sys.executable, "-m", "server", "serve", "--host", "0.0.0.0", "--port", str(port),
        "--token", PILOT, "--observer-token", OBSERVER, "--data-dir", str(data), "--seed", "1",
        "--recognizer", "server",
    ]  # fmt: skip
    log = (data / "server.log").open("wb")
    proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT)
    log.close()
    ca = data / "tls" / "ca.pem"
    deadline = time.monotonic() + 180  # a loaded 2-core machine: imports alone take a minute
    while not ca.is_file():
        assert proc.poll() is None and time.monotonic() < deadline, (
            data / "server.log"
        ).read_text()
        time.sleep(0.1)
    http = httpx.Client(
        base_url=f"https://127.0.0.1:{port}",
        verify=ssl.create_default_context(cafile=str(ca)),
        headers={"Authorization": f"Bearer {PILOT}"},
        timeout=30,
    )
    srv = TlsServer(port, data, proc, http)
    try:
        while True:
            assert proc.poll() is None and time.monotonic() < deadline, (
                data / "server.log"
            ).read_text()
            with contextlib.suppress(httpx.TransportError):
                ready = http.get("/api/v1/speech/status").json().get("status") == "ready"
                if ready and http.get("/api/v1/health").json()["drones"].get("uav1"):
                    break
            time.sleep(0.2)
        yield srv
    finally:
        http.close()
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def launch(chromium: Any, srv: TlsServer, wav: Path) -> Any:
    """A Chromium of its own (fake microphone flags), launched by the session's Playwright
    (``browser.browser_type``): a second ``sync_playwright()`` in the same process refuses to
    start while the session's is running (its event loop is the running one)."""
    args = [
        *CHROMIUM_ARGS,
        "--use-fake-ui-for-media-stream",
        "--use-fake-device-for-media-stream",
        f"--use-file-for-fake-audio-capture={wav}",
        f"--ignore-certificate-errors-spki-list={srv.spki_hash()}",
    ]
    return chromium.launch(executable_path=str(CHROMIUM), headless=True, args=args)


def open_page(chromium: Any, srv: TlsServer, wav: Path, viewport: dict[str, int]) -> Any:
    browser = launch(chromium, srv, wav)
    # The page's CSP has no 'unsafe-eval'; Playwright's string predicates need eval
    # (as in conftest.open_console; test_5_csp.py checks the page under its CSP).
    ctx = browser.new_context(viewport=viewport, service_workers="block", bypass_csp=True)
    page = ctx.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(srv.url())
    page.wait_for_selector("#conn[data-state='open']", timeout=20_000)
    assert page.evaluate("window.isSecureContext") is True
    page.wait_for_function("document.body.dataset.recognizer === 'server'")
    assert "offline" in page.inner_text("#recognizer-label")
    assert page.is_visible("#ca-download")  # the phone can fetch the CA from the page
    page.select_option("#recognizer", "server")
    return browser, page, errors


def hold_mic_and_fly(chromium: Any, srv: TlsServer, wav: Path, viewport: dict[str, int]) -> Any:
    browser, page, errors = open_page(chromium, srv, wav, viewport)
    hold_mic(page)
    return browser, page, errors


def hold_mic(page: Any) -> None:
    """Push-to-talk: hold the microphone while the fake device plays the command."""
    mic = page.locator("#mic")
    mic.scroll_into_view_if_needed()
    box = mic.bounding_box()
    assert box is not None
    page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    page.mouse.down()
    page.wait_for_function("document.body.dataset.listening === 'server'")  # the mic is live
    page.wait_for_timeout(3200)
    page.mouse.up()


def test_phone_over_https_holds_the_microphone_and_the_drone_takes_off(
    browser: Any, tls_server: TlsServer, tmp_path: Path
) -> None:
    wav = synthesise(tmp_path / "takeoff.wav", "take off", voice="en-us", speed=150, pad_s=1.0)
    subprocess.run(["sox", str(wav), str(tmp_path / "fake.wav"), "pad", "0", "4"], check=True)
    own, page, errors = hold_mic_and_fly(
        browser.browser_type, tls_server, tmp_path / "fake.wav", {"width": 390, "height": 844}
    )
    try:
        # The phone's utterance reaches the dialog as speech, recognised on the server.
        try:
            page.wait_for_function(
                "[...document.querySelectorAll('#dialog .msg-user')]"
                ".some(e => /spoken/.test(e.textContent) && /takeoff/.test(e.textContent))",
                timeout=60_000,
            )
        except Exception as exc:
            raise AssertionError(tls_server.why(page)) from exc
        ok, last, _ = wait_until(tls_server.truth, lambda t: t["flying"] and t["z"] > 0.5, 30.0)
        assert ok, (last, errors, tls_server.why(page))
        assert "take off" in page.inner_text("#dialog").lower()
        # Hands-free can be switched on and off on the phone (its VAD path is tested over
        # WSS in tests/speech/test_server.py).
        page.check("#handsfree")
        page.wait_for_function("document.body.dataset.listening === 'server'")
        # Hands-free does not hear the console's own spoken reply ("Did you say …?" from a
        # loudspeaker): while the server's voice plays, and 0.3 s after, the microphone streams
        # silence. Replies are muted here so that only this stand-in reply speaks.
        page.evaluate("window.uavConsole.dialog.muted = true")
        page.wait_for_function("window.uavConsole.serverSpeaking === 0")  # earlier replies end
        page.wait_for_timeout(400)
        counted = "window.uavConsole.speech.server.mutedChunks"
        before = page.evaluate(counted)
        page.evaluate("window.uavConsole.serverSpeaking += 1")
        page.wait_for_function(f"{counted} > {before} + 10")
        # The page says it is not listening, and how to talk over the reply.
        assert page.evaluate("document.body.dataset.speechPaused") == "1"
        assert "press the microphone" in page.inner_text("#interim")
        # Pressing the microphone interrupts: the console's voice stops (hush) and the
        # microphone is heard again at once, still hands-free, while that reply lasts.
        page.click("#mic")
        assert page.evaluate("document.body.dataset.listening") == "server"
        assert page.evaluate("typeof window.uavConsole.hushedAt") == "number"
        page.wait_for_function("document.body.dataset.speechPaused === ''")
        heard = page.evaluate(counted)
        page.wait_for_timeout(600)
        assert page.evaluate(counted) == heard
        page.evaluate("window.uavConsole.serverSpeaking -= 1")
        page.wait_for_timeout(300)
        # The next reply mutes the microphone again; its end and 0.3 s after, it listens.
        before = page.evaluate(counted)
        page.evaluate("window.uavConsole.serverSpeaking += 1")
        page.wait_for_function(f"{counted} > {before} + 10")
        page.evaluate("window.uavConsole.serverSpeaking -= 1")
        page.wait_for_timeout(600)
        muted = page.evaluate(counted)
        page.wait_for_timeout(600)
        assert page.evaluate(counted) == muted  # listening again
        assert page.evaluate("document.body.dataset.speechPaused") == ""
        # The same with a real spoken reply (the server's voice: this Chromium has none): the
        # press stops it playing.
        page.evaluate("window.uavConsole.dialog.muted = false")
        page.fill("#text-input", "help")
        page.press("#text-input", "Enter")
        page.wait_for_function("window.uavConsole.serverSpeaking > 0", timeout=15_000)
        page.wait_for_function("document.body.dataset.speechPaused === '1'")
        page.click("#mic")
        page.wait_for_function("window.uavConsole.serverSpeaking === 0", timeout=3000)
        page.wait_for_function("document.body.dataset.speechPaused === ''")
        assert page.evaluate("document.body.dataset.listening") == "server"
        page.uncheck("#handsfree")
        page.wait_for_function("document.body.dataset.listening === ''")
        assert errors == []
    finally:
        own.close()
        tls_server.http.post("/api/v1/drones/uav1/land")


FALLBACK = "this console's offline recogniser listens instead"


def test_auto_listens_offline_and_leaves_a_failing_browser_recogniser_saying_so_once(
    browser: Any, tls_server: TlsServer, tmp_path: Path
) -> None:
    """`auto` (the Recogniser setting's default) listens with this console's recogniser unless
    the browser's is known to work on this device; Chromium here has the Web Speech API and no
    service behind it (it fails with "audio-capture" or "network"): the page switches to the
    offline recogniser, says so once, and the next press flies."""
    wav = synthesise(tmp_path / "takeoff.wav", "take off", voice="en-us", speed=150, pad_s=1.0)
    subprocess.run(["sox", str(wav), str(tmp_path / "fake.wav"), "pad", "0", "4"], check=True)
    ok, last, _ = wait_until(tls_server.truth, lambda t: not t["flying"], 30.0)
    assert ok, last  # an earlier test's landing is over
    own = launch(browser.browser_type, tls_server, tmp_path / "fake.wav")
    try:
        ctx = own.new_context(
            viewport={"width": 1280, "height": 800}, service_workers="block", bypass_csp=True
        )
        page = ctx.new_page()
        errors: list[str] = []
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.goto(tls_server.url())
        page.wait_for_selector("#conn[data-state='open']", timeout=20_000)
        page.select_option("#recognizer", "auto")
        assert page.evaluate("document.body.dataset.recognizer") == "server"
        assert "offline" in page.inner_text("#recognizer-label")
        # A pilot with the lease, over HTTPS, with a microphone: hands-free is there.
        page.wait_for_function("!document.getElementById('handsfree').disabled")
        assert page.inner_text("#handsfree-why") == ""
        # The browser's recogniser once returned text on this device: auto picks it.
        page.evaluate("localStorage.setItem('uavc.browserSpeech', 'works')")
        page.reload()
        page.wait_for_selector("#conn[data-state='open']", timeout=20_000)
        page.wait_for_function("document.body.dataset.recognizer === 'browser'")
        assert "browser" in page.inner_text("#recognizer-label")
        # Hands-free says why it is off with the browser's recogniser.
        assert page.is_disabled("#handsfree")
        assert "this console's recogniser" in page.inner_text("#handsfree-why")
        page.click("#mic")  # a tap: the browser's recogniser starts here and fails
        page.wait_for_function("document.body.dataset.recognizer === 'server'", timeout=20_000)
        assert page.evaluate("localStorage.getItem('uavc.browserSpeech')") == "failed"
        dialog = "document.getElementById('dialog').textContent"
        page.wait_for_function(f"{dialog}.includes({FALLBACK!r})")
        assert page.evaluate("document.body.dataset.listening") == ""
        assert not page.is_disabled("#handsfree")
        # Hold the microphone: the offline recogniser hears the command and the drone flies.
        hold_mic(page)
        try:
            page.wait_for_function(
                "[...document.querySelectorAll('#dialog .msg-user')]"
                ".some(e => /spoken/.test(e.textContent) && /takeoff/.test(e.textContent))",
                timeout=60_000,
            )
        except Exception as exc:
            raise AssertionError(tls_server.why(page)) from exc
        ok, last, _ = wait_until(tls_server.truth, lambda t: t["flying"] and t["z"] > 0.5, 30.0)
        assert ok, (last, errors, tls_server.why(page))
        assert page.evaluate(f"{dialog}.split({FALLBACK!r}).length - 1") == 1  # said once
        # An observer is told why hands-free is off.
        watcher = ctx.new_page()
        watcher.goto(tls_server.url(OBSERVER))
        watcher.wait_for_selector("#conn[data-state='open']", timeout=20_000)
        watcher.wait_for_function("document.getElementById('handsfree-why').textContent !== ''")
        assert "observers" in watcher.inner_text("#handsfree-why")
        assert watcher.is_disabled("#handsfree")
        assert errors == []
    finally:
        own.close()
        tls_server.http.post("/api/v1/drones/uav1/land")


def test_handsfree_flies_a_spoken_command_ended_by_its_short_pause(
    browser: Any, tls_server: TlsServer, tmp_path: Path
) -> None:
    """Hands-free through the fake microphone: "take off" once, then silence. The server's
    end-pointer ends the utterance at the pause (a decisive reading after 0.3 s, else 0.7 s of
    silence: server/speech/stream.py), with no press or release, and the drone takes off."""
    wav = synthesise(tmp_path / "takeoff.wav", "take off", voice="en-us", speed=150, pad_s=1.0)
    fake = tmp_path / "fake.wav"
    subprocess.run(["sox", str(wav), str(fake), "pad", "1", "6"], check=True)
    ok, last, _ = wait_until(tls_server.truth, lambda t: not t["flying"], 30.0)
    assert ok, last  # an earlier test's landing is over
    own = launch(browser.browser_type, tls_server, Path(f"{fake}%noloop"))
    try:
        ctx = own.new_context(
            viewport={"width": 1280, "height": 800}, service_workers="block", bypass_csp=True
        )
        page = ctx.new_page()
        errors: list[str] = []
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.goto(tls_server.url())
        page.wait_for_selector("#conn[data-state='open']", timeout=20_000)
        page.evaluate("window.uavConsole.dialog.muted = true")  # no reply to pause the mic
        page.wait_for_function("!document.getElementById('handsfree').disabled")
        page.check("#handsfree")
        page.wait_for_function("document.body.dataset.listening === 'server'")
        try:
            page.wait_for_function(
                "[...document.querySelectorAll('#dialog .msg-user')]"
                ".some(e => /spoken/.test(e.textContent) && /takeoff/.test(e.textContent))",
                timeout=60_000,
            )
        except Exception as exc:
            raise AssertionError(tls_server.why(page)) from exc
        ok, last, _ = wait_until(tls_server.truth, lambda t: t["flying"] and t["z"] > 0.5, 30.0)
        assert ok, (last, errors, tls_server.why(page))
        assert page.evaluate("document.body.dataset.listening") == "server"  # still listening
        page.uncheck("#handsfree")
        assert errors == []
    finally:
        own.close()
        tls_server.http.post("/api/v1/drones/uav1/land")
