"""Spoken command in the real page: end of speech -> the command on the drone's wire.

A real ``serve`` (the vehicle in its own process) flies the simulated AR.Drone of this process
(``drone/sim/probe.py``: it timestamps, as they arrive on its AT socket, each ``AT*REF`` whose
take-off bit rises (a take-off) or falls (a landing)). Headless Chromium opens the console with
a fake microphone that plays one WAV (``--use-fake-device-for-media-stream
--use-file-for-fake-audio-capture``): spoken "take off" and "land" commands (several wordings),
each followed by several seconds of silence, synthesised with espeak-ng (four of its voices)
and, with ``--tts hibari,espeak-ng``, hibari-tts's neural voice too. The page listens
hands-free with the console's default recogniser (``auto``: the offline one here), exactly as
an operator's page does.

The time is taken from the **real end of speech** to the AT command:

* end of speech: the last sample of each utterance above -60 dBFS in the WAV (the TTS output
  before its silent padding). The page's WebSocket sends are logged (time, bytes) by an init
  script; the microphone's clock is the lower envelope of ``send time - samples sent / 16 kHz``
  over all sends (a sample cannot be sent before it was captured; the envelope is the capture
  clock plus the pipeline's least latency), and each utterance is aligned in the stream by its
  onset, so the end of speech has a time on that clock;
* command executed: the simulator receives the take-off (bit 9 rising) or landing (falling)
  ``AT*REF``; the page's and this process's clocks are tied by the best of 7 round trips.

Baseline, same run: the same commands typed into the command box (Enter -> AT*REF). Also shown:
end of speech -> the final recognition reaching the page (the decode's share) and final -> AT.

Usage: ``python bench/speech_latency.py [--tts espeak-ng] [--repeats 1] [--json F]
[--before CHECKOUT]``. The defaults (8 spoken commands, 8 typed) take about 2.5 minutes on an
idle 2-core machine; each further set or repeat adds about a minute. The load average is
printed beside the figures: they are only worth reporting from a quiet machine.

``--offline``: no page, no server: the same utterances through the stream's end-pointer with
Silero and the shipped recogniser in this process, each speculation decoded when it is asked
and told back once its decode's CPU time has passed in the stream (an idle core), for this
end-pointer and the one before it (decode after 0.3 s of silence, decisive end at 0.35 s).
Prints when the decode was asked and when the final was ready after the real end of speech:
what the end-pointer and the decode cost where the machine's load does not decide it.
"""

from __future__ import annotations

import argparse
import base64
import contextlib
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
import wave
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import httpx  # noqa: E402
import numpy as np  # noqa: E402

from bench.loopback import free_port  # noqa: E402
from bench.polling import wait_for  # noqa: E402
from drone.sim.probe import ProbeSim, SimThread  # noqa: E402
from server.language.nlu import default_nlu  # noqa: E402
from server.speech.audio import SAMPLE_RATE, read_wav, to_wav  # noqa: E402
from tests.speech.conftest import synthesise  # noqa: E402

HOST = "127.0.27.1"
SIM_ADDR = "127.0.27.31"
TOKEN = "bench-speech-latency-token"
CHROMIUM = os.environ.get("UAVC_CHROMIUM", "/usr/bin/chromium")
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
TAKEOFFS = ["take off", "please take off", "take off now", "could you take off"]
LANDINGS = ["land", "please land", "land now", "land the drone"]
LEAD_S = 2.0  # silence before the first utterance (the microphone starting)
GAP_S = 6.0  # silence after each: the take-off or landing completes, the reply is spoken
TARGET_P50_MS = 600.0  # end of speech -> the drone acting, median, in the browser
SILENT = 2.0**-10  # -60 dBFS: below this a sample is silence (the end-of-speech threshold)
SEND_LOG = """
(() => {
  const log = (window.__pcm = []);
  const finals = (window.__finals = []);
  const said = (window.__said = []);
  const send = WebSocket.prototype.send;
  WebSocket.prototype.send = function (data) {
    const text = typeof data === "string" ? data : "";
    if (text.includes('"/console/utterance"') && text.includes('"publish"'))
      said.push(performance.timeOrigin + performance.now());
    if (data instanceof ArrayBuffer && String(this.url).includes("/speech/stream")) {
      const bytes = new Uint8Array(data);
      let s = "";
      for (let i = 0; i < bytes.length; i += 1) s += String.fromCharCode(bytes[i]);
      log.push([performance.timeOrigin + performance.now(), btoa(s)]);
      window.__pcmSamples = (window.__pcmSamples || 0) + bytes.length / 2;
    }
    return send.call(this, data);
  };
  const Orig = window.WebSocket;
  window.WebSocket = function (url, protocols) {
    const ws = protocols === undefined ? new Orig(url) : new Orig(url, protocols);
    if (String(url).includes("/speech/stream")) {
      ws.addEventListener("message", (ev) => {
        try {
          const msg = JSON.parse(ev.data);
          if (msg.type === "final") finals.push([performance.timeOrigin + performance.now(), msg]);
        } catch (e) {}
      });
    }
    return ws;
  };
  window.WebSocket.prototype = Orig.prototype;
  for (const k of ["CONNECTING", "OPEN", "CLOSING", "CLOSED"]) window.WebSocket[k] = Orig[k];
})();
"""


class EdgeProbe(ProbeSim):
    """The probe simulator, also timestamping landings (the take-off bit falling)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.landing_times: list[float] = []

    def _at(self, data: bytes) -> None:
        was = self._takeoff_held
        super()._at(data)
        if was and not self._takeoff_held:
            self.landing_times.append(time.monotonic())


class EdgeSim(SimThread):
    def __init__(self, addr: str) -> None:
        super().__init__(addr)
        self.sim = EdgeProbe(addr, "indoor", seed=1)

    def first_after(self, action: str, t0: float) -> float | None:
        times = self.sim.takeoff_times if action == "takeoff" else self.sim.landing_times
        return next((t for t in list(times) if t >= t0), None)


@dataclass(frozen=True)
class Utterance:
    text: str
    action: str  # takeoff | land
    voice: str
    start: int  # sample of the WAV where the utterance's audio begins (after the lead/gap)
    onset: int  # first sample above SILENT
    end: int  # last sample above SILENT: the real end of speech


def build_wav(out: Path, tts: str, repeats: int, work: Path) -> list[Utterance]:
    """Alternating take-offs and landings in ``tts``'s voice(s), one WAV; where each lies."""
    nlu = default_nlu()
    voices = ["heart"] if tts == "hibari" else ["en-us", "en-gb", "en-us+f3", "en-gb-x-rp"]
    texts: list[tuple[str, str]] = []
    for _ in range(repeats):
        for up, down in zip(TAKEOFFS, LANDINGS, strict=True):
            texts += [(up, "takeoff"), (down, "land")]
    parts = [np.zeros(int(LEAD_S * SAMPLE_RATE), np.float32)]
    pos = len(parts[0])
    utterances: list[Utterance] = []
    for i, (text, action) in enumerate(texts):
        assert [c["action"] for c in nlu.interpret(text)] == [action], text
        voice = voices[i % len(voices)]
        path = synthesise(work / f"u{i}.wav", text, voice=voice, speed=160, pad_s=0.0, tts=tts)
        clip = read_wav(path.read_bytes())
        loud = np.flatnonzero(np.abs(clip) >= SILENT)
        utterances.append(
            Utterance(text, action, voice, pos, pos + int(loud[0]), pos + int(loud[-1]))
        )
        gap = np.zeros(int(GAP_S * SAMPLE_RATE), np.float32)
        parts += [clip, gap]
        pos += len(clip) + len(gap)
    out.write_bytes(to_wav(np.concatenate(parts)))
    return utterances


@contextlib.contextmanager
def serve(tmp: Path, root: Path = ROOT) -> Iterator[tuple[int, httpx.Client]]:
    """``serve`` (of the checkout at ``root``) on the probe simulator, the drone linked."""
    port = free_port(HOST)
    env = {**os.environ, "UAVC_DATA_DIR": str(tmp / "data"), "PYTHONPATH": str(root)}
    argv = [sys.executable, "-m", "server", "serve", "--host", HOST, "--port", str(port)]
    argv += ["--drone", SIM_ADDR, "--token", TOKEN, "--vehicles", "process"]
    log = open(tmp / "serve.log", "wb")  # noqa: SIM115
    proc = subprocess.Popen(argv, cwd=root, env=env, stdout=log, stderr=log)
    http = httpx.Client(
        base_url=f"http://{HOST}:{port}", headers={"Authorization": f"Bearer {TOKEN}"}, timeout=60
    )
    try:
        wait_for(
            lambda: (
                (d := http.get("/api/v1/drones/uav1").json())["link_ok"]
                and d["vehicle"]["connected"]
            ),
            "serve and its vehicle",
            300,  # a loaded 2-core machine with the bench niced: minutes
        )
        yield port, http
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(20)
        except subprocess.TimeoutExpired:
            proc.kill()
        http.close()
        log.close()
        kept = Path(tempfile.gettempdir()) / "uavc-speech-latency-serve.log"
        kept.write_bytes((tmp / "serve.log").read_bytes())


def clock_offset(page: Any) -> float:
    """page epoch seconds - this process's monotonic seconds (best of 7 round trips)."""
    best: tuple[float, float] | None = None
    for _ in range(7):
        t0 = time.monotonic()
        epoch = float(page.evaluate("performance.timeOrigin + performance.now()")) / 1000
        t1 = time.monotonic()
        if best is None or t1 - t0 < best[0]:
            best = (t1 - t0, epoch - (t0 + t1) / 2)
    assert best is not None
    return best[1]


def stream_of(page: Any, offset: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The PCM the page sent, and each send's monotonic time and samples sent up to it."""
    log = page.evaluate("window.__pcm")
    chunks = [np.frombuffer(base64.b64decode(b64), "<i2") for _t, b64 in log]
    ends = np.cumsum([len(c) for c in chunks])
    sent = np.array([t / 1000 - offset for t, _b64 in log])
    pcm = np.concatenate(chunks).astype(np.float32) / 32768.0
    return pcm, sent, ends


def captured_at(n: int, sent: np.ndarray, ends: np.ndarray) -> float:
    """When sample ``n`` of the stream was captured: the lower envelope of ``send time -
    (samples sent - n) / 16 kHz`` over the sends of the 2 s around it (a sample is never sent
    before it is captured; a loaded machine's fake microphone may fall behind real time, so
    the envelope is local)."""
    near = np.abs(ends - n) <= 2 * SAMPLE_RATE
    after = near & (ends >= n)
    return float(np.min(sent[after] - (ends[after] - n) / SAMPLE_RATE))


def onsets(pcm: np.ndarray, n: int) -> list[int]:
    """The first sample above SILENT of each of the ``n`` sounds, each after >= 1 s of silence."""
    loud = np.flatnonzero(np.abs(pcm) >= SILENT)
    out: list[int] = []
    last = -(10**9)
    for i in loud:
        if i - last > SAMPLE_RATE:
            out.append(int(i))
        last = int(i)
    return out[:n]


def pct(xs: list[float], q: float) -> float:
    s = sorted(xs)
    return s[min(len(s) - 1, round(q / 100 * (len(s) - 1)))] if s else float("nan")


def reset_landed(sim: EdgeSim, http: httpx.Client) -> None:
    """The drone on the ground before the next set."""
    with contextlib.suppress(httpx.HTTPError):
        http.post("/api/v1/drones/uav1/land")
    wait_for(lambda: not sim.truth.flying, "the drone landed", 60)


def spoken_run(
    pw: Any, port: int, sim: EdgeSim, http: httpx.Client, wav: Path, utts: list[Utterance]
) -> list[dict[str, Any]]:
    """Hands-free in the page while the WAV plays; one row per utterance."""
    args = [
        *CHROMIUM_ARGS,
        "--use-fake-ui-for-media-stream",
        "--use-fake-device-for-media-stream",
        f"--use-file-for-fake-audio-capture={wav}%noloop",
        "--autoplay-policy=no-user-gesture-required",
    ]
    browser = pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=args)
    try:
        page = browser.new_context(viewport={"width": 1280, "height": 800}).new_page()
        page.add_init_script(SEND_LOG)
        # Replies shown, not spoken: hands-free does not listen while the console speaks, and
        # on a busy machine a late reply would silence the next command of this fixed script.
        page.add_init_script("localStorage.setItem('uavc.muted', '1')")
        page.goto(f"http://{HOST}:{port}/?token={TOKEN}")
        wait_for(lambda: page.evaluate("uavConsole.haveLease === true"), "the lease", 120)
        wait_for(
            lambda: page.evaluate("document.body.dataset.recognizer") == "server",
            "the offline recogniser chosen by auto",
            120,
        )
        page.check("#handsfree")
        wait_for(lambda: page.evaluate("document.body.dataset.listening") == "server", "mic", 120)
        # The whole WAV plays (a loaded machine's fake microphone may run slower than real
        # time: its samples are counted, not the wall clock); the last command then has GAP_S
        # to reach the drone.
        samples = utts[-1].end + int(GAP_S * SAMPLE_RATE)
        t_start, wall_s = time.monotonic(), samples / SAMPLE_RATE
        while time.monotonic() - t_start < 3 * wall_s + 60:
            sent = page.evaluate("window.__pcmSamples || 0")
            if sent >= samples or (time.monotonic() - t_start > wall_s + 10 and sent == 0):
                break
            time.sleep(0.5)
        else:
            print(f"the page sent {sent} of {samples} samples; scoring what it sent", flush=True)
        time.sleep(2)
        page.uncheck("#handsfree")
        offset = clock_offset(page)
        pcm, sent, ends = stream_of(page, offset)
        finals = [(t / 1000 - offset, m) for t, m in page.evaluate("window.__finals")]
        said = [t / 1000 - offset for t in page.evaluate("window.__said")]
    finally:
        browser.close()
    starts = onsets(pcm, len(utts))
    end_times = [
        captured_at(s + (u.end - u.onset), sent, ends) for u, s in zip(utts, starts, strict=False)
    ]
    rows: list[dict[str, Any]] = []
    epoch = time.time() - time.monotonic()  # the server's stamps are epoch seconds
    for k, (u, end_t) in enumerate(zip(utts, end_times, strict=False)):
        # What follows this utterance, up to the end of the next one, is its answer.
        limit = end_times[k + 1] if k + 1 < len(end_times) else end_t + GAP_S + 2
        at = sim.first_after(u.action, end_t - 1.0)
        final = next(((t, m) for t, m in finals if end_t - 0.5 <= t < limit), None)
        ok = at is not None and at < limit
        published = next((t for t in said if final is not None and t >= final[0] - 0.001), None)
        stages = stage_times(
            end_t, final[1].get("timing", {}) if final else {}, epoch,
            final[0] if final else None, published, at if ok else None,
        )  # fmt: skip
        rows.append(
            {
                "text": u.text,
                "voice": u.voice,
                "action": u.action,
                "executed": ok,
                "ms": (at - end_t) * 1000 if ok and at is not None else None,
                "final_ms": (final[0] - end_t) * 1000 if final else None,
                "heard": final[1].get("text") if final else None,
                "decode_ms": final[1].get("decode_ms") if final else None,
                "confidence": final[1].get("confidence") if final else None,
                "stages": stages,
            }
        )
    return rows


# The stages of one spoken command, in order: (name, from, to) over the stamps of stage_times.
STAGES = (
    ("speech end -> silence frame at server (VAD lag + audio transport)", "end", "silence_heard"),
    ("VAD scoring of that frame batch", "silence_heard", "silence_scored"),
    ("silence -> speculative decode starts (settle wait + pool queue)", "silence_scored",
     "spec_start"),
    ("speculative decode (VAD-trimmed speech)", "spec_start", "spec_end"),
    ("decode end -> final (commit wait)", "spec_end", "final"),
    ("final: its decode (reused) -> sent", "final", "sent"),
    ("sent -> final in the page", "sent", "page_final"),
    ("page: final -> /console/utterance published", "page_final", "published"),
    ("published -> AT*REF on the wire (rosbridge, dialog, NLU, vehicle)", "published", "at"),
    ("total: speech end -> AT*REF", "end", "at"),
)  # fmt: skip
CPU_STAGES = ("vad_cpu_ms", "spec_cpu_ms", "decode_cpu_ms")


def stage_times(
    end_t: float,
    timing: dict[str, float],
    epoch: float,
    page_final: float | None,
    published: float | None,
    at: float | None,
) -> dict[str, float]:
    """The stamps of one utterance on this process's monotonic clock, ms after its real end of
    speech (the server's epoch stamps moved by ``epoch``), and the CPU ms of the VAD over the
    utterance, the speculative decode and the final's decode (``*_cpu_ms``)."""
    stamps = {"end": end_t, "page_final": page_final, "published": published, "at": at}
    for key in ("silence_heard", "silence_scored", "spec_start", "spec_end", "final", "sent"):
        if key in timing:
            stamps[key] = timing[key] - epoch
    out = {k: (v - end_t) * 1000 for k, v in stamps.items() if v is not None}
    out.update({k: timing[k] for k in (*CPU_STAGES, "vad_frames") if k in timing})
    out["reused"] = timing.get("reused", float("nan"))
    return out


def breakdown(rows: list[dict[str, Any]]) -> None:
    """Median of each stage over the utterances that have both its ends."""
    print("\n| stage | n | p50 ms | p90 ms |")
    print("|---|---|---|---|")
    for name, a, b in STAGES:
        xs = [
            r["stages"][b] - r["stages"][a] for r in rows if a in r["stages"] and b in r["stages"]
        ]
        if xs:
            print(f"| {name} | {len(xs)} | {statistics.median(xs):.0f} | {pct(xs, 90):.0f} |")
    for key in CPU_STAGES:
        xs = [r["stages"][key] for r in rows if key in r["stages"]]
        if xs:
            print(f"| CPU: {key} | {len(xs)} | {statistics.median(xs):.0f} | {pct(xs, 90):.0f} |")
    per_frame = [
        r["stages"]["vad_cpu_ms"] / r["stages"]["vad_frames"]
        for r in rows
        if r["stages"].get("vad_frames")
    ]
    if per_frame:
        print(f"| CPU: VAD per 32 ms frame | {len(per_frame)} | "
              f"{statistics.median(per_frame):.2f} | {pct(per_frame, 90):.2f} |")  # fmt: skip
    reused = [r["stages"].get("reused") == 1.0 for r in rows if "reused" in r["stages"]]
    print(f"finals that reused the speculative decode: {sum(reused)}/{len(reused)}")


def typed_run(pw: Any, port: int, sim: EdgeSim, http: httpx.Client, repeats: int) -> list[float]:
    """The baseline: the same commands typed (Enter -> AT*REF), seconds."""
    browser = pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
    out: list[float] = []
    try:
        page = browser.new_context(viewport={"width": 1280, "height": 800}).new_page()
        page.goto(f"http://{HOST}:{port}/?token={TOKEN}")
        wait_for(lambda: page.evaluate("uavConsole.haveLease === true"), "the lease", 120)
        for _ in range(repeats):
            for up, down in zip(TAKEOFFS, LANDINGS, strict=True):
                for text, action in ((up, "takeoff"), (down, "land")):
                    page.fill("#text-input", text)
                    t0 = time.monotonic()
                    page.press("#text-input", "Enter")
                    try:
                        at = wait_for(lambda a=action, t=t0: sim.first_after(a, t), text, 30, 0.001)
                    except RuntimeError:  # not flown (a starved vehicle process): a miss
                        print(f"typed {text!r}: no AT*REF in 30 s", flush=True)
                        reset_landed(sim, http)
                        continue
                    out.append(at - t0)
                    time.sleep(GAP_S - 1)
    finally:
        browser.close()
    return out


def summary(label: str, ms: list[float], n: int, extra: str = "") -> None:
    p50, p90 = (statistics.median(ms), pct(ms, 90)) if ms else (float("nan"),) * 2
    print(f"| {label} | {len(ms)}/{n} | {p50:.0f} | {p90:.0f} | {extra} |")


# The end-pointer before this one: the decode asked at 0.3 s of silence, a decisive end at 0.35 s.
BEFORE_ENDPOINTER = {"listen_s": 0.3, "commit_s": 0.35}


def offline(tts_sets: list[str], repeats: int) -> int:
    """End of speech -> final on an idle core, this end-pointer and the one before it."""
    from server.speech.model import load_whisper, resolve
    from server.speech.recognizer import THRESHOLD, Recognizer, SileroStream
    from server.speech.service import decisive
    from server.speech.stream import Final, Speculation, StreamSession

    nlu = default_nlu()
    recognizer = Recognizer(load_whisper(resolve(None), workers=1), nlu, reuse=False)
    recognizer.warm_up()
    rows: dict[str, list[tuple[float, float, float]]] = {"now": [], "before": []}
    print("| set | text | end-pointer | decode asked ms | decode CPU ms | final ms | reading |")
    print("|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as td:
        for tts in tts_sets:
            wav = Path(td) / f"{tts}.wav"
            utts = build_wav(wav, tts, repeats, Path(td))
            with wave.open(str(wav)) as w:  # longer than read_wav's 30 s per request
                frames = w.readframes(w.getnframes())
            audio = np.frombuffer(frames, "<i2").astype(np.float32) / 32768
            for u in utts:
                first = u.start - SAMPLE_RATE  # a second of the silence before it
                clip = audio[first : u.end + 2 * SAMPLE_RATE]
                pcm = (np.clip(clip, -1, 1) * 32767).astype("<i2").tobytes()
                end_s = (u.end - first) / SAMPLE_RATE
                for name, opts in (("now", {}), ("before", BEFORE_ENDPOINTER)):
                    session = StreamSession("handsfree", score=SileroStream(), **opts)
                    asked = done = final = 0.0
                    spec: Speculation | None = None
                    told, sure, text = True, False, ""
                    for i in range(0, len(pcm), 1024):  # the page's 32 ms frames
                        now = (i + 1024) / 2 / SAMPLE_RATE
                        events = session.feed(pcm[i : i + 1024])
                        if spec is not None and not told and now >= done:
                            told = True
                            events += session.decided(spec.serial, sure)
                        for ev in events:
                            if isinstance(ev, Speculation):
                                c0 = time.process_time()
                                rec = recognizer.recognize(ev.samples, vad=False)
                                cpu = time.process_time() - c0
                                spec, asked, done, told = ev, now, now + cpu, False
                                sure, text = decisive(rec, nlu, THRESHOLD), rec.text
                            elif isinstance(ev, Final) and not final:
                                final = max(now, done)
                        if final:
                            break
                    row = ((asked - end_s) * 1000, (done - asked) * 1000, (final - end_s) * 1000)
                    rows[name].append(row)
                    print(f"| {tts} | {u.text} | {name} | {row[0]:.0f} | {row[1]:.0f} | "
                          f"{row[2]:.0f} | {text!r} |")  # fmt: skip
    print("\n| end-pointer | n | decode asked p50 ms | decode CPU p50 ms | final p50 ms |")
    print("|---|---|---|---|---|")
    for name, xs in rows.items():
        a, c, f = (statistics.median(x[k] for x in xs) for k in range(3))
        print(f"| {name} | {len(xs)} | {a:.0f} | {c:.0f} | {f:.0f} |")
    print(f"load: {os.getloadavg()} (CPU times, not wall: the load does not decide them)")
    return 0


def main(argv: list[str] | None = None) -> int:
    from playwright.sync_api import sync_playwright

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--tts", default="espeak-ng", help="voice sets, comma-separated (hibari, espeak-ng)"
    )
    ap.add_argument("--repeats", type=int, default=1, help="each wording this many times")
    ap.add_argument("--typed", type=int, default=1, help="typed baseline repeats (0: none)")
    ap.add_argument("--json", type=Path)
    ap.add_argument(
        "--before",
        type=Path,
        help="also serve this checkout (e.g. `git worktree add /tmp/main main`) in the same run",
    )
    ap.add_argument(
        "--offline", action="store_true", help="the end-pointer on an idle core (see above)"
    )
    args = ap.parse_args(argv)
    if args.offline:
        return offline(args.tts.split(","), args.repeats)
    print(f"load before: {os.getloadavg()} on {os.cpu_count()} cores (shared machine)")
    results: dict[str, Any] = {}
    servers = [("", ROOT)] + ([(" (before)", args.before)] if args.before else [])
    with tempfile.TemporaryDirectory() as td, EdgeSim(SIM_ADDR) as sim, sync_playwright() as pw:
        wavs = {tts: build_wav(Path(td) / f"{tts}.wav", tts, args.repeats, Path(td))
                for tts in args.tts.split(",")}  # fmt: skip
        for suffix, root in servers:
            data = Path(td) / f"serve{len(results)}"
            data.mkdir()
            with serve(data, root) as (port, http):
                # Load the model (the page's first stream would) before anything is timed.
                http.post(
                    "/api/v1/speech?execute=false",
                    content=to_wav(np.zeros(SAMPLE_RATE, np.float32)),
                    headers={"Content-Type": "audio/wav"},
                )
                for tts, utts in wavs.items():
                    reset_landed(sim, http)
                    wav = Path(td) / f"{tts}.wav"
                    results[tts + suffix] = spoken_run(pw, port, sim, http, wav, utts)
                    print(f"load after {tts}{suffix}: {os.getloadavg()}", flush=True)
                    breakdown(results[tts + suffix])
                    if args.json:  # what was measured survives a later failure
                        args.json.write_text(json.dumps(results, indent=1))
                if args.typed and not suffix:
                    reset_landed(sim, http)
                    results["typed"] = [
                        x * 1000 for x in typed_run(pw, port, sim, http, args.typed)
                    ]
    print(f"load after: {os.getloadavg()}")
    print("\n| end of speech -> AT*REF on the drone | executed | p50 ms | p90 ms | "
          "end of speech -> final text in the page p50 / p90 ms |")  # fmt: skip
    print("|---|---|---|---|---|")
    for tts, rows in results.items():
        if tts == "typed":
            continue
        ms = [r["ms"] for r in rows if r["ms"] is not None]
        fin = [r["final_ms"] for r in rows if r["final_ms"] is not None]
        summary(f"spoken, hands-free, {tts}", ms, len(rows),
                f"{statistics.median(fin):.0f} / {pct(fin, 90):.0f}" if fin else "-")  # fmt: skip
        for r in rows:
            if not r["executed"]:
                print(f"|   missed: {r['text']!r} ({r['voice']}) heard {r['heard']!r} | | | | |")
    spoken = {k: v for k, v in results.items() if k != "typed" and "(before)" not in k}
    for tts, rows in spoken.items():
        print(f"\nwhere the time goes, {tts} (ms after the real end of speech; load above):")
        breakdown(rows)
    allms = [r["ms"] for rows in spoken.values() for r in rows if r["ms"] is not None]
    if len(spoken) > 1:
        summary("spoken, all voices", allms, sum(len(v) for v in spoken.values()))
    before = {k: v for k, v in results.items() if "(before)" in k}
    old = [r["ms"] for rows in before.values() for r in rows if r["ms"] is not None]
    if len(before) > 1:
        summary("spoken, all voices (before)", old, sum(len(v) for v in before.values()))
    if "typed" in results:
        summary("typed (baseline): Enter -> AT*REF", results["typed"], len(results["typed"]))
        if allms and results["typed"]:
            ratio = statistics.median(allms) / statistics.median(results["typed"])
            print(f"\nspoken p50 / typed p50: {ratio:.1f}x")
    if allms and old:
        ratio = statistics.median(old) / statistics.median(allms)
        print(f"spoken p50, before / now: {ratio:.1f}x")
    if allms:
        met = "met" if statistics.median(allms) <= TARGET_P50_MS else "NOT met"
        print(f"target: spoken p50 <= {TARGET_P50_MS:.0f} ms: {met}")
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
