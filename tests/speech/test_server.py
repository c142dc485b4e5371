"""The whole server on a non-loopback bind, as a phone sees it.

``uav-console serve --host 0.0.0.0`` in a subprocess serves HTTPS/WSS with its own CA (the
simulated drone on a loopback address of its own). httpx verifies the generated CA;
spoken WAV files fly the simulated drone through ``POST /api/v1/speech``; the microphone stream
is spoken to over WSS with the ``websockets`` client. (A remote vehicle joins the bus, whose
certificates tests/bus/test_bus_tls.py checks.)
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import ssl
import stat
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed

from server.http.tls import fingerprint
from server.speech.audio import read_wav, to_wav
from tests.speech.conftest import HAVE_TTS, synthesise
from tests.support.loopback import bus_endpoint, free_port, fresh_address

ROOT = Path(__file__).resolve().parents[2]
PILOT = "speech-pilot-token"
OBSERVER = "speech-observer-token"
SIM_ADDR = fresh_address()

pytestmark = pytest.mark.skipif(not HAVE_TTS, reason="espeak-ng and sox are needed")


@dataclass
class Served:
    port: int
    data: Path
    http: httpx.Client
    proc: subprocess.Popen[bytes]
    log_path: Path
    clips: Path

    @property
    def ca(self) -> Path:
        return self.data / "tls" / "ca.pem"

    @property
    def base(self) -> str:
        return f"https://127.0.0.1:{self.port}"

    def log(self) -> str:
        return self.log_path.read_text(errors="replace")[-4000:]

    def truth(self) -> dict[str, Any]:
        return dict(self.http.get("/api/v1/sim/uav1/truth").json())

    def wait(self, pred: Callable[[dict[str, Any]], bool], timeout: float, what: str) -> None:
        deadline = time.monotonic() + timeout
        last: dict[str, Any] = {}
        while time.monotonic() < deadline:
            last = self.truth()
            if pred(last):
                return
            time.sleep(0.05)
        raise AssertionError(f"{what}: not in {timeout} s; last {last}")

    def clip(self, text: str, **kw: Any) -> bytes:
        name = "".join(c if c.isalnum() else "_" for c in f"{text}{sorted(kw.items())}")
        return synthesise(self.clips / f"{name}.wav", text, **kw).read_bytes()

    def speak(self, wav: bytes, **params: Any) -> httpx.Response:
        headers = {"Content-Type": "audio/wav"}
        return self.http.post("/api/v1/speech", content=wav, params=params, headers=headers)


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Served]:
    data = tmp_path_factory.mktemp("speech-data")
    clips = tmp_path_factory.mktemp("speech-clips")
    port = free_port()
    env = dict(os.environ, UAVC_SIM_BASE_ADDR=SIM_ADDR, UAVC_SIM_SPEED="1")
    env.setdefault("UAVC_VEHICLES", "inline")  # speech, not isolation (tests/isolation)
    env.setdefault("UAVC_BUS_LISTEN", bus_endpoint())  # a bus router off 7447
    log_path = data / "server.log"
    cmd = [
        sys.executable, "-m", "server", "serve", "--host", "0.0.0.0", "--port", str(port),
        "--token", PILOT, "--observer-token", OBSERVER, "--data-dir", str(data),
    ]  # fmt: skip
    with open(log_path, "wb") as log:
        proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT)
    srv = Served(port, data, httpx.Client(), proc, log_path, clips)
    try:
        deadline = time.monotonic() + 60
        while not srv.ca.is_file():
            if proc.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"server did not start:\n{srv.log()}")
            time.sleep(0.1)
        srv.http = httpx.Client(
            base_url=srv.base,
            verify=ssl.create_default_context(cafile=str(srv.ca)),
            headers={"Authorization": f"Bearer {PILOT}"},
            timeout=60.0,
        )
        while True:
            if proc.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"server did not become healthy:\n{srv.log()}")
            with contextlib.suppress(httpx.TransportError):
                ready = srv.http.get("/api/v1/speech/status").json().get("status") == "ready"
                health = srv.http.get("/api/v1/health").json()
                if ready and health["drones"].get("uav1"):
                    break
            time.sleep(0.2)
        yield srv
    finally:
        srv.http.close()
        proc.terminate()
        try:
            proc.wait(15)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def test_https_with_the_generated_ca(served: Served) -> None:
    # httpx trusts the server only through the generated CA ...
    assert served.http.get("/api/v1/health").status_code == 200
    with pytest.raises(httpx.ConnectError, match="CERTIFICATE_VERIFY_FAILED"):
        httpx.get(f"{served.base}/api/v1/health", timeout=10)
    # ... which the page offers for download, without a token.
    ca = httpx.get(f"{served.base}/api/v1/tls/ca.pem", verify=_ws_ssl(served), timeout=10)
    assert ca.status_code == 200 and ca.content == served.ca.read_bytes()
    for key in ("ca-key.pem", "server-key.pem"):
        assert stat.S_IMODE((served.data / "tls" / key).stat().st_mode) == 0o600
    # The start-up lines give an https URL and the certificate's fingerprint.
    fp = fingerprint((served.data / "tls" / "server.pem").read_bytes())
    log = served.log()
    assert "https://" in log and f":{served.port}/?token=" in log and fp in log
    # The certificate names this machine's addresses and the loopback one.
    der = ssl.get_server_certificate(("127.0.0.1", served.port)).encode()
    assert fingerprint(der) == fp


def test_spoken_take_off_and_land_fly_the_drone(served: Served) -> None:
    served.wait(lambda t: not t["flying"], 10, "landed at start")
    r = served.speak(served.clip("take off", voice="en-gb", speed=150))
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["commands"] == [{"action": "takeoff"}] and body["accepted"] is True, body
    assert set(body) >= {"text", "confidence", "commands", "reply", "accepted"}
    served.wait(lambda t: t["flying"] and t["z"] > 0.5, 20, "climbs after the spoken take-off")
    r = served.speak(served.clip("please land", voice="en-gb", speed=170, snr_db=20.0))
    assert r.json()["commands"] == [{"action": "land"}], r.json()
    assert r.json()["accepted"] is True, r.json()
    served.wait(lambda t: not t["flying"], 20, "lands after the spoken land")


def test_a_command_heard_with_middling_confidence_flies_after_a_spoken_yes(
    served: Served,
) -> None:
    served.wait(lambda t: not t["flying"], 20, "landed at start")
    # This voice's "get airborne" is heard right at confidence 0.36 (bench/speech.py's clip):
    # under the threshold, over the floor: read back rather than "please repeat".
    r = served.speak(served.clip("get airborne", voice="en-029", speed=160)).json()
    assert r["accepted"] is False, r
    assert r["reply"].startswith('Did you say "get airborne"? That is: taking off.'), r
    assert r["expects"] == "confirm", r
    assert not served.truth()["flying"]
    r = served.speak(served.clip("yes", voice="en-us", speed=160)).json()
    assert r["text"] == "Yes." and r["accepted"] is True, r
    assert r["commands"] == [{"action": "takeoff"}], r
    served.wait(lambda t: t["flying"] and t["z"] > 0.5, 20, "climbs after the spoken yes")
    r = served.speak(served.clip("yes", voice="en-gb", speed=150)).json()
    assert r["accepted"] is False and r["commands"] == [], r  # nothing is asked any more
    assert r["reply"].startswith("No question is waiting for an answer."), r
    land = served.http.post("/api/v1/command", json={"text": "land"}).json()
    assert land["accepted"] is True, land
    served.wait(lambda t: not t["flying"], 20, "lands")


def test_bad_input_gets_clear_errors_and_nothing_flies(served: Served) -> None:
    wav = {"Content-Type": "audio/wav"}
    r = served.http.post(
        "/api/v1/speech", content=b"take off", headers={"Content-Type": "text/plain"}
    )
    assert r.status_code == 415 and "audio/wav" in r.json()["detail"]
    r = served.http.post("/api/v1/speech", content=b"%PDF-1.4 not audio", headers=wav)
    assert r.status_code == 400 and "not a WAV" in r.json()["detail"]
    assert served.http.post("/api/v1/speech", content=b"", headers=wav).status_code == 400
    ten_min = bytearray(to_wav(np.zeros(160, np.float32)))
    ten_min[40:44] = (600 * 16000 * 2).to_bytes(4, "little")
    r = served.http.post("/api/v1/speech", content=bytes(ten_min), headers=wav)
    assert r.status_code == 413 and "at most 30 s" in r.json()["detail"]
    big = b"RIFF" + b"\0" * (13 * 1024 * 1024)
    assert served.http.post("/api/v1/speech", content=big, headers=wav).status_code == 413
    garbage = np.random.default_rng(3).integers(-32768, 32767, 48000).astype("<i2")
    r = served.speak(to_wav(garbage / 32768.0))
    assert r.status_code == 200 and r.json()["accepted"] is False and r.json()["commands"] == []
    obs = {"Authorization": f"Bearer {OBSERVER}", **wav}
    take_off = served.clip("take off", voice="en-gb", speed=150)
    r = served.http.post("/api/v1/speech", content=take_off, headers=obs)
    assert r.status_code == 403 and "observer" in r.json()["detail"]
    r = served.http.post("/api/v1/speech?execute=false", content=take_off, headers=obs)
    assert r.status_code == 200 and r.json()["commands"] == [{"action": "takeoff"}]
    assert r.json()["accepted"] is False and r.json()["reply"] == ""
    assert not served.truth()["flying"]


def test_twenty_at_once_are_bounded_and_the_server_stays_responsive(served: Served) -> None:
    clip = served.clip("hover", voice="en-us", speed=160)

    async def burst() -> tuple[list[int], float]:
        async with httpx.AsyncClient(
            base_url=served.base,
            verify=ssl.create_default_context(cafile=str(served.ca)),
            headers={"Authorization": f"Bearer {PILOT}", "Content-Type": "audio/wav"},
            timeout=120,
        ) as client:
            posts = [
                asyncio.create_task(client.post("/api/v1/speech?execute=false", content=clip))
                for _ in range(20)
            ]
            await asyncio.sleep(0.3)
            health = await client.get("/api/v1/health")  # answered while decoders are busy
            assert health.status_code == 200
            done = await asyncio.gather(*posts)
            return [r.status_code for r in done], 0.0

    codes, _ = asyncio.run(burst())
    assert set(codes) <= {200, 503}
    assert codes.count(200) >= 1 and codes.count(503) >= 10  # back-pressure, not a pile-up
    r = served.speak(clip, execute="false")  # and it recovers at once
    assert r.status_code == 200
    assert not served.truth()["flying"]


def _ws_ssl(served: Served) -> ssl.SSLContext:
    return ssl.create_default_context(cafile=str(served.ca))


def test_microphone_stream_push_to_talk_over_wss(served: Served) -> None:
    samples = read_wav(served.clip("fly to marker two", voice="en-gb-x-rp", speed=160))
    pcm = (np.clip(samples, -1, 1) * 32767).astype("<i2").tobytes()
    url = f"wss://127.0.0.1:{served.port}/api/v1/speech/stream?token={PILOT}&mode=ptt"

    async def talk() -> list[dict[str, Any]]:
        got: list[dict[str, Any]] = []
        async with connect(url, ssl=_ws_ssl(served)) as ws:
            got.append(json.loads(await ws.recv()))
            # the first 400 ms in one frame: over the transport's 4 KB limit before auth, which
            # the token at the handshake lifted (server/http/ws_guard.py)
            await ws.send(pcm[:12800])
            for i in range(12800, len(pcm), 3200):  # 100 ms frames, as the worklet sends
                await ws.send(pcm[i : i + 3200])
                await asyncio.sleep(0.02)
            await ws.send(json.dumps({"type": "end"}))
            while True:
                msg = json.loads(await asyncio.wait_for(ws.recv(), 60))
                got.append(msg)
                if msg["type"] in ("final", "error"):
                    return got

    msgs = asyncio.run(talk())
    assert msgs[0]["type"] == "ready"
    final = msgs[-1]
    assert final["type"] == "final", msgs
    assert final["commands"] == [{"action": "goto", "marker": 2}], final
    assert final["confidence"] >= 0.5


@pytest.mark.parametrize(
    ("query", "reason"),
    [
        (f"token={OBSERVER}", "observer"),
        ("token=wrong", "token"),
        (f"token={PILOT}&mode=always", "mode"),
    ],
)
def test_microphone_stream_refusals(served: Served, query: str, reason: str) -> None:
    url = f"wss://127.0.0.1:{served.port}/api/v1/speech/stream?{query}"

    async def attempt() -> str:
        try:
            async with connect(url, ssl=_ws_ssl(served)) as ws:
                await ws.recv()
        except ConnectionClosed as exc:
            return exc.rcvd.reason if exc.rcvd else ""
        except Exception as exc:  # a refusal before the handshake completes
            return str(exc)
        return ""

    assert reason in asyncio.run(attempt())


def _stream_url(served: Served, mode: str = "ptt") -> str:
    return f"wss://127.0.0.1:{served.port}/api/v1/speech/stream?token={PILOT}&mode={mode}"


def test_handsfree_stream_cuts_the_utterance_at_the_pause(served: Served) -> None:
    speech = read_wav(served.clip("take off", voice="en-us", speed=150))
    silence = np.zeros(16000, np.float32)
    samples = np.concatenate([silence, speech, silence, silence])
    pcm = (np.clip(samples, -1, 1) * 32767).astype("<i2").tobytes()

    async def talk() -> dict[str, Any]:
        async with connect(_stream_url(served, "handsfree"), ssl=_ws_ssl(served)) as ws:
            assert json.loads(await ws.recv())["type"] == "ready"
            for i in range(0, len(pcm), 3200):
                await ws.send(pcm[i : i + 3200])
                await asyncio.sleep(0.01)
            while True:  # no "end": the pause ends the utterance
                msg = json.loads(await asyncio.wait_for(ws.recv(), 60))
                if msg["type"] in ("final", "error"):
                    return dict(msg)

    final = asyncio.run(talk())
    assert final["type"] == "final" and final["commands"] == [{"action": "takeoff"}], final


async def _frames(ws: Any, samples: np.ndarray) -> None:
    """Send ``samples`` in the worklet's 32 ms frames."""
    pcm = (np.clip(samples, -1, 1) * 32767).astype("<i2").tobytes()
    for i in range(0, len(pcm), 1024):
        await ws.send(pcm[i : i + 1024])
        await asyncio.sleep(0.005)


async def _until(ws: Any, kinds: tuple[str, ...], text: str = "") -> dict[str, Any]:
    """The next message of one of ``kinds`` (an interim only if its text holds ``text``)."""
    while True:
        msg = json.loads(await asyncio.wait_for(ws.recv(), 60))
        if msg["type"] in kinds and (msg["type"] != "interim" or text in msg["text"].lower()):
            return dict(msg)


def test_handsfree_ends_a_decisive_command_after_a_short_silence(served: Served) -> None:
    """0.35 s of silence after "take off" is all the server gets: a decisive reading ends the
    utterance there (at 0.3 s of silence; the full end of an utterance needs 0.7 s)."""
    speech = read_wav(served.clip("take off", voice="en-us", speed=150, pad_s=0.0))
    quiet = np.zeros(int(0.35 * 16000), np.float32)

    async def talk() -> dict[str, Any]:
        async with connect(_stream_url(served, "handsfree"), ssl=_ws_ssl(served)) as ws:
            assert json.loads(await ws.recv())["type"] == "ready"
            await _frames(ws, np.concatenate([np.zeros(8000, np.float32), speech, quiet]))
            return await _until(ws, ("final", "error"))  # no more audio, no "end"

    final = asyncio.run(talk())
    assert final["type"] == "final" and final["commands"] == [{"action": "takeoff"}], final
    # The final says when each of its stages happened (bench/speech_latency.py's breakdown),
    # in order; it reused the speculation's decode (the speculation's own stamps are there
    # only when its decode ended before the final: a loaded machine may end the utterance at
    # the full silence first, the final then waiting for that decode).
    t = final["timing"]
    stages = ["silence_heard", "silence_scored", "spec_start", "spec_end", "final", "sent"]
    assert {"silence_heard", "silence_scored", "final", "sent"} <= t.keys(), t
    present = [t[k] for k in stages if k in t]
    assert present == sorted(present), t
    assert t["reused"] == 1.0 and t["vad_frames"] > 0, t


def test_handsfree_waits_for_the_full_silence_when_the_command_may_go_on(served: Served) -> None:
    """ "Turn left" may go on ("… ninety degrees"): after 0.45 s of silence the server has
    read it (interim text) but not ended the utterance; 0.3 s more silence ends it."""
    speech = read_wav(served.clip("turn left", voice="en-us", speed=150, pad_s=0.0))
    quiet = np.zeros(int(0.45 * 16000), np.float32)

    async def talk() -> tuple[dict[str, Any], dict[str, Any]]:
        async with connect(_stream_url(served, "handsfree"), ssl=_ws_ssl(served)) as ws:
            assert json.loads(await ws.recv())["type"] == "ready"
            await _frames(ws, np.concatenate([np.zeros(8000, np.float32), speech, quiet]))
            first = await _until(ws, ("interim", "final", "error"), "turn")
            await _frames(ws, np.zeros(int(0.3 * 16000), np.float32))
            return first, await _until(ws, ("final", "error"))

    first, final = asyncio.run(talk())
    assert first["type"] == "interim", first
    assert final["type"] == "final", final
    assert final["commands"] == [{"action": "turn", "direction": "left"}], final


def test_twenty_streams_at_once_and_one_that_stops_mid_word(served: Served) -> None:
    speech = read_wav(served.clip("take off", voice="en-us", speed=150))
    half = (speech[: len(speech) // 2] * 32767).astype("<i2").tobytes()

    async def open_one() -> str:
        try:
            async with connect(_stream_url(served), ssl=_ws_ssl(served)) as ws:
                first = json.loads(await asyncio.wait_for(ws.recv(), 30))
                await ws.send(half)  # mid-word ...
                await asyncio.sleep(1.0)
                return str(first["type"])  # ... and gone without "end"
        except ConnectionClosed as exc:
            return f"closed: {exc.rcvd.reason if exc.rcvd else ''}"

    async def burst() -> list[str]:
        return list(await asyncio.gather(*(open_one() for _ in range(20))))

    outcomes = asyncio.run(burst())
    ready = outcomes.count("ready")
    assert 1 <= ready <= 8, outcomes  # Settings: at most 8 microphone streams
    refused = [o for o in outcomes if o != "ready"]
    assert refused and all("too many microphone streams" in o for o in refused), outcomes
    # Every stream is released; nothing was decoded into a command; nothing flies.
    deadline = time.monotonic() + 20
    while served.http.get("/api/v1/speech/status").json()["streams"]:
        assert time.monotonic() < deadline
        time.sleep(0.2)
    assert not served.truth()["flying"]


def test_microphone_stream_honours_the_pilot_lease(served: Served) -> None:
    bridge = f"wss://127.0.0.1:{served.port}/rosbridge?token={PILOT}"

    async def scenario() -> tuple[str, str]:
        async with connect(bridge, ssl=_ws_ssl(served)) as holder:
            call = {"op": "call_service", "id": "l1", "service": "/console/lease"}
            await holder.send(json.dumps({**call, "args": {"action": "acquire"}}))
            while True:
                msg = json.loads(await asyncio.wait_for(holder.recv(), 10))
                if msg.get("id") == "l1":
                    lease = msg["values"]["holder"]
                    break
            # Another pilot page (no lease) may not speak; the holder's page may.
            try:
                async with connect(_stream_url(served), ssl=_ws_ssl(served)) as ws:
                    await ws.recv()
                refused = ""
            except ConnectionClosed as exc:
                refused = exc.rcvd.reason if exc.rcvd else ""
            url = f"{_stream_url(served)}&lease={lease}"
            async with connect(url, ssl=_ws_ssl(served)) as ws:
                ready = json.loads(await asyncio.wait_for(ws.recv(), 30))["type"]
        return refused, ready

    refused, ready = asyncio.run(scenario())
    assert "lease" in refused and ready == "ready"
