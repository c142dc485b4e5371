"""Offline speech: spoken-command exact match, latency and real-time factor, with and without
grammar guidance, and what decoding costs the 100 Hz control loop.

1. Accuracy and latency. Utterances drawn (seeded, stratified by action) from the hand-labelled
   NLU set ``tests/data/nlu_labelled.jsonl`` are synthesised with espeak-ng in 6+ voices and
   accents at 3 speeds (130/160/190 words per minute), clean and with white noise at 20 dB and
   10 dB SNR (seeded): 36 utterances x 9 conditions = 324 clips (``--quick``: 12 x 9 = 108).
   Each clip is recognised by the shipped tiny.en (int8, CPU) three times: grammar-guided
   (vocabulary prompt and token constraint, 15 s encoder window, 4 beams each snapped to the
   grammars: the product), unguided (the same recogniser, no prompt, no constraint, its first
   transcript to the NLU: the baseline), and guided as it was before the window and the beams
   (Whisper's 30 s window, greedy: the reference for what those two bring).
   * exact = the commands that would be executed (confidence >= 0.5, else "please repeat")
     equal the labelled ones; for a labelled non-command, nothing executed; the drone is taken
     to be flying, so a spoken emergency under its bar (server.dialog.confirm) hovers and asks
     instead of cutting the motors;
   * wrong = something executed that differs from the label; wrong flown = such a thing that
     moves the drone (not a question or a description): the dangerous outcome;
   * latency = end of speech (the whole clip handed over) -> commands: VAD + decode + snap + NLU;
   * RTF = that time / clip duration.
   Targets: >= 90 % exact clean, >= 80 % at 10 dB, p50 <= 400 ms.
2. The microphone stream, end of speech -> command: clips fed in real time (20 ms chunks)
   through the stream session and a one-decoder pool as the server's stream route does;
   push-to-talk released 0.5 s after the speech ends, and hands-free; with the end-pointer's
   speculative decode at 0.3 s of silence, the early end on a decisive reading and the reuse
   of its result (the product) vs a decode only at the end (hands-free's 0.7 s of silence, the
   release), same clips, same run. ``bench/speech_latency.py`` measures the same in the page,
   end of speech to the command on the drone's wire.
4. Spoken replies: synthesis time of typical replies with hibari-tts's neural voice (the
   server's first choice, server/speech/synth.py) and with espeak-ng, one after another.
3. The 100 Hz control loop (drone/control/loop.py, sleep+spin as flown) alone, then while 3
   streams keep decoding through the server's bounded pool (one decoder per core less one),
   then through an unbounded one (3 decoders at once): period error p99, overruns; in this
   process, and in a process of its own set up as a vehicle process is (real-time control
   thread where permitted, GIL held through the spin, 0.1 ms switch interval).

    .venv/bin/python bench/speech.py [--quick] [--json out.json] [--skip-loop] [--skip-stream]
        [--skip-voice] [--asr-model DIR] [--window-s 15] [--beams 4]
        [--tts espeak-ng|flite|hibari] [--rows all|guided] [--seed 15] [--progress FILE]

``--rows guided`` runs section 1 with the product's recogniser only (a third of the time);
``--seed`` draws another set of utterances (15: the set the recogniser was tuned on; any other:
utterances it was not).

``--tts flite`` synthesises section 1's clips with Debian's flite voices instead (slt, rms, awb,
kal16; same utterances, speeds and noise), ``--tts hibari`` with hibari-tts's neural voice
(distilled from Kokoro-82M; the one voice its wheel holds): espeak-ng's formant voices are
harder for Whisper than recorded or less robotic speech, and these rows say by how much.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import random
import sys
import tempfile
import threading
import time
from collections import defaultdict
from dataclasses import replace
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from drone.control.loop import ControlLoop, LoopStats  # noqa: E402
from drone.control.pid import PaperPID, Setpoint  # noqa: E402
from server.dialog.confirm import EMERGENCY_CONFIDENCE, to_read_back  # noqa: E402
from server.language.nlu import default_nlu  # noqa: E402
from server.settings import Settings  # noqa: E402
from server.speech.audio import SAMPLE_RATE, read_wav  # noqa: E402
from server.speech.model import default_workers, load_whisper, resolve  # noqa: E402
from server.speech.pool import DecoderPool  # noqa: E402
from server.speech.recognizer import (  # noqa: E402
    BEAMS,
    Recognition,
    Recognizer,
    SileroStream,
    speech_span,
)
from server.speech.service import decisive  # noqa: E402
from server.speech.stream import Final, Speculation, StreamSession  # noqa: E402
from server.speech.window import MIN_S  # noqa: E402
from server.vehicles.host import VEHICLE_SWITCH_INTERVAL_S, raise_priority  # noqa: E402
from tests.speech.conftest import HIBARI_VOICES, synthesise  # noqa: E402

VOICES = ["en-us", "en-gb", "en-gb-scotland", "en-gb-x-rp", "en-029", "en-us+f3", "en-us-nyc"]
# --tts flite: Debian's CMU Flite, whose voices are less robotic than espeak-ng's formant
# synthesis (the accuracy set is espeak-ng's; this one tells what the voices cost).
FLITE_VOICES = ["slt", "rms", "awb", "kal16"]
TTS_VOICES = {"espeak-ng": VOICES, "flite": FLITE_VOICES, "hibari": list(HIBARI_VOICES)}
SPEEDS = [130, 160, 190]
NOISE: list[float | None] = [None, 20.0, 10.0]
THRESHOLD = Settings().confidence_threshold
CONFIRM_FLOOR = Settings().confirm_floor  # from here to THRESHOLD: "Did you say …?"
BEFORE = "guided, 30 s window, greedy (before)"
NOT_FLOWN = frozenset({"query", "describe", "help", "cancel"})  # answered or stopped, not flown
REPLIES = [  # typical spoken replies (server/dialog/replies.py, confirm.py)
    "Taking off.",
    "Taking off, then flying to marker 2.",
    "Battery low: 18 percent. Returning home.",
    "Reached marker 3.",
    'Did you say "fly to marker 7"? That is: flying to marker 7. Say yes to do it, or say the '
    "command again.",
    "I see a brown door far ahead and an orange person close on the right.",
]


def pick_utterances(n: int, seed: int = 15) -> list[dict[str, Any]]:
    """``n`` labelled utterances, round-robin over actions (seed 15: the tuning set)."""
    rows = [json.loads(line) for line in (ROOT / "tests/data/nlu_labelled.jsonl").open()]
    by_action: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for row in rows:
        by_action[row["commands"][0]["action"] if row["commands"] else "none"].append(row)
    rng = random.Random(seed)
    for group in by_action.values():
        rng.shuffle(group)
    out: list[dict[str, Any]] = []
    while len(out) < n:  # round-robin over actions: every kind of command is spoken
        for action in sorted(by_action):
            if by_action[action] and len(out) < n:
                out.append(by_action[action].pop())
    return out


def canon(commands: list[dict[str, Any]]) -> str:
    def norm(v: Any) -> Any:
        return round(v, 3) if isinstance(v, float) else v

    return json.dumps([{k: norm(v) for k, v in c.items()} for c in commands], sort_keys=True)


def pct(xs: list[float], q: float) -> float:
    xs = sorted(xs)
    return xs[min(len(xs) - 1, int(q * (len(xs) - 1) + 0.5))] if xs else float("nan")


def report(results: dict[str, list[dict[str, Any]]]) -> dict[str, Any]:
    """Print the tables for per-clip results (also for a partial run: ``--report``)."""
    print("\n## Spoken commands: exact match (executed commands == label)")
    print(
        "| recogniser | clean | 20 dB | 10 dB | all | understood (any conf.) | wrong executed "
        "| wrong flown | latency p50 ms | p95 ms | RTF p50 |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    summary: dict[str, Any] = {}
    for name, rows in results.items():

        def rate(key: str, pred: Any = lambda r: True, rows: list[dict[str, Any]] = rows) -> float:
            sel = [r for r in rows if pred(r)]
            return 100.0 * sum(r.get(key, False) for r in sel) / max(1, len(sel))

        s = {
            "clean": rate("exact", lambda r: r["snr"] is None),
            "20dB": rate("exact", lambda r: r["snr"] == 20.0),
            "10dB": rate("exact", lambda r: r["snr"] == 10.0),
            "all": rate("exact"),
            "understood": rate("understood"),
            "wrong": rate("wrong"),
            "wrong_flown": rate("wrong_flown"),
            "p50_ms": pct([r["ms"] for r in rows], 0.5),
            "p95_ms": pct([r["ms"] for r in rows], 0.95),
            "rtf_p50": pct([r["rtf"] for r in rows], 0.5),
        }
        summary[name] = s
        print(
            f"| {name} | {s['clean']:.1f} % | {s['20dB']:.1f} % | {s['10dB']:.1f} % | "
            f"{s['all']:.1f} % | {s['understood']:.1f} % | {s['wrong']:.1f} % | "
            f"{s['wrong_flown']:.1f} % | {s['p50_ms']:.0f} | {s['p95_ms']:.0f} | "
            f"{s['rtf_p50']:.2f} |"
        )
    print(
        f'\n## Read back ("Did you say …?", confidence {CONFIRM_FLOOR:g} to {THRESHOLD:g}) and '
        'run on a "yes"'
    )
    print("| recogniser | right read back | other read back | exact or right after a yes: clean "
          "| 20 dB | 10 dB | all |")  # fmt: skip
    print("|---|---|---|---|---|---|---|")
    for name, rows in results.items():

        def after_yes(pred: Any, rows: list[dict[str, Any]] = rows) -> float:
            sel = [r for r in rows if pred(r)]
            won = sum(r["exact"] or r.get("read_back_right", False) for r in sel)
            return 100.0 * won / max(1, len(sel))

        right = 100.0 * sum(r.get("read_back_right", False) for r in rows) / max(1, len(rows))
        other = (
            100.0
            * sum(r.get("read_back", False) and not r.get("read_back_right", False) for r in rows)
            / max(1, len(rows))
        )
        yes = {
            "clean": after_yes(lambda r: r["snr"] is None),
            "20dB": after_yes(lambda r: r["snr"] == 20.0),
            "10dB": after_yes(lambda r: r["snr"] == 10.0),
            "all": after_yes(lambda r: True),
        }
        summary[name] |= {"read_back_right": right, "read_back_other": other, "after_yes": yes}
        print(
            f"| {name} | {right:.1f} % | {other:.1f} % | {yes['clean']:.1f} % | "
            f"{yes['20dB']:.1f} % | {yes['10dB']:.1f} % | {yes['all']:.1f} % |"
        )
    g = summary["guided"]
    guided = results["guided"]
    why: dict[str, int] = defaultdict(int)
    for r in guided:
        why[r.get("doubt") or "-"] += 1
    hovered = sum(r.get("hover_ask", False) for r in guided)
    print(
        "\nguided: read back as doubtful (server.speech.recognizer.doubt): "
        + ", ".join(f"{k} {v}" for k, v in sorted(why.items()) if k != "-")
        + f"; spoken emergencies under their bar, hovered and asked: {hovered}"
    )
    b = summary.get("unguided (baseline)")
    if b is not None:
        ratio = f"{g['all'] / b['all']:.2f}x" if b["all"] else "n/a (baseline 0 %)"
        print(
            f"guided / baseline exact: {ratio}; wrong executed {g['wrong']:.1f} % vs "
            f"{b['wrong']:.1f} %; latency p50 ratio {g['p50_ms'] / b['p50_ms']:.2f}"
        )
    if BEFORE in summary:
        o = summary[BEFORE]
        print(
            f"guided vs {BEFORE}: exact {g['all']:.1f} vs {o['all']:.1f} %, wrong executed "
            f"{g['wrong']:.1f} vs {o['wrong']:.1f} %, latency p50 {g['p50_ms']:.0f} vs "
            f"{o['p50_ms']:.0f} ms ({o['p50_ms'] / g['p50_ms']:.2f}x faster)"
        )
    print("\n### guided, by voice and by speed (exact %)")
    by: dict[str, list[bool]] = defaultdict(list)
    for r in results["guided"]:
        by[f"voice {r['voice']}"].append(r["exact"])
        by[f"speed {r['speed']} wpm"].append(r["exact"])
    print(" · ".join(f"{k}: {100 * sum(v) / len(v):.0f}" for k, v in sorted(by.items())))
    for r in (r for r in results["guided"] if r["wrong"]):
        print(f"- wrong: {r['text']!r} -> {r['heard']!r} ({r['confidence']:.2f})")
    misses = [r for r in results["guided"] if not r["exact"]][:12]
    if misses:
        print("\n### some guided misses (label -> heard, confidence)")
        for r in misses:
            snr = "clean" if r["snr"] is None else f"{r['snr']:.0f} dB"
            print(
                f"- {r['text']!r} [{r['voice']}, {r['speed']} wpm, {snr}] -> "
                f"{r['heard']!r} ({r['confidence']:.2f})"
            )
    return summary


def stream_finals(recognizer: Recognizer, samples: Any) -> list[Any]:
    """The recognitions the page's hands-free stream gets for one clip (and 1 s of silence
    after it): fed in 32 ms frames through the server's end-pointer, each speculation decoded
    at once and told back (a decode of no time: the earliest end, the likeliest cut)."""
    session = StreamSession("handsfree", score=SileroStream())
    audio = np.concatenate([samples, np.zeros(SAMPLE_RATE, np.float32)])
    pcm = (np.clip(audio, -1, 1) * 32767).astype("<i2").tobytes()
    done: dict[int, Any] = {}
    out: list[Any] = []
    pending = [e for i in range(0, len(pcm), 1024) for e in session.feed(pcm[i : i + 1024])]
    pending += session.end()
    while pending:
        ev = pending.pop(0)
        if isinstance(ev, Speculation):
            r = recognizer.recognize(ev.samples, vad=False)
            done[id(ev.samples)] = r
            pending[:0] = session.decided(ev.serial, decisive(r, recognizer.nlu, THRESHOLD))
        elif isinstance(ev, Final):
            known = done.get(id(ev.samples))
            out.append(known or recognizer.recognize(ev.samples, vad=not ev.trimmed))
    return out


def bench_accuracy(
    recognizer: Recognizer,
    quick: bool,
    tts: str = "espeak-ng",
    rows: str = "all",
    seed: int = 15,
    progress: Path | None = None,
    via: str = "whole",
) -> dict[str, Any]:
    utterances = pick_utterances(12 if quick else 36, seed)
    voices = TTS_VOICES[tts]
    conditions = [(s, n) for n in NOISE for s in SPEEDS]
    work = Path(tempfile.mkdtemp(prefix="uavc-speech-bench-"))
    clips: list[tuple[Path, dict[str, Any], str, int, float | None]] = []
    t0 = time.perf_counter()
    for i, row in enumerate(utterances):
        for j, (speed, snr) in enumerate(conditions):
            voice = voices[(i + j) % len(voices)]
            path = work / f"u{i}_{j}.wav"
            synthesise(
                path, row["text"], voice=voice, speed=speed, snr_db=snr, seed=i * 31 + j, tts=tts
            )
            clips.append((path, row, voice, speed, snr))
    print(
        f"{len(clips)} clips: {len(utterances)} utterances x {len(conditions)} conditions, "
        f"{len({c[2] for c in clips})} {tts} voices, "
        f"synthesised in {time.perf_counter() - t0:.0f} s"
    )
    before = Recognizer(recognizer.model, recognizer.nlu, reuse=False, window_s=None, beams=1)
    runs: tuple[tuple[str, Recognizer, bool], ...] = (
        ("guided", recognizer, True),
        ("unguided (baseline)", recognizer, False),
        (BEFORE, before, True),
    )
    if rows == "guided":
        runs = runs[:1]
    results: dict[str, list[dict[str, Any]]] = {name: [] for name, _, _ in runs}
    # Seeded shuffle: any prefix of the run (an interrupted one too) is a fair sample of all
    # utterances, voices, speeds and noise levels.
    random.Random(1).shuffle(clips)
    recognizer.recognize(read_wav(clips[0][0].read_bytes()))  # warm-up, not counted
    progress = progress or Path(tempfile.gettempdir()) / "uavc-speech-bench-progress.jsonl"
    progress.write_text("")
    for k, (path, row, voice, speed, snr) in enumerate(clips):
        if k and k % 20 == 0:
            print(f"  {k}/{len(clips)} clips", file=sys.stderr, flush=True)
        samples = read_wav(path.read_bytes())
        dur = len(samples) / SAMPLE_RATE
        for name, rec_by, guided in runs:
            t = time.perf_counter()
            if via == "stream" and name == "guided":
                recs = stream_finals(rec_by, samples) or [Recognition("", 0.0)]
            else:
                recs = [rec_by.recognize(samples, guided=guided)]
            ms = (time.perf_counter() - t) * 1000
            executed, read_back, hover_ask = [], [], False
            for rec in recs:  # a stream may cut one clip into several utterances
                now = rec.commands if rec.confidence >= THRESHOLD else []
                # In flight, an emergency under its bar hovers and asks (server.dialog.confirm).
                if any(c["action"] == "emergency" for c in now) and (
                    rec.confidence < max(THRESHOLD, EMERGENCY_CONFIDENCE)
                ):
                    hover_ask, now = True, []
                executed += now
                # What the dialog reads back ("Did you say …?", server/dialog/confirm.py):
                # speech between the floor and the threshold the grammars understand whole.
                offered = to_read_back(
                    rec_by.nlu, rec.text, rec.confidence, THRESHOLD, CONFIRM_FLOOR
                )
                read_back += offered.commands if offered is not None else []
            if len(recs) > 1:
                rec = replace(
                    recs[0],
                    heard=" | ".join(r.heard for r in recs),
                    confidence=min(r.confidence for r in recs),
                    doubt="cut",
                )
            want = canon(row["commands"])
            results[name].append(
                {
                    "text": row["text"],
                    "heard": rec.heard,
                    "voice": voice,
                    "speed": speed,
                    "snr": snr,
                    "exact": canon(executed) == want,
                    "understood": canon(rec.commands) == want,
                    "wrong": bool(executed) and canon(executed) != want,
                    "wrong_flown": canon(executed) != want
                    and any(c["action"] not in NOT_FLOWN for c in executed),
                    "doubt": rec.doubt,
                    "hover_ask": hover_ask,
                    "read_back": bool(read_back),
                    "read_back_right": bool(read_back) and canon(read_back) == want,
                    "ms": ms,
                    "rtf": ms / 1000 / dur,
                    "confidence": rec.confidence,
                }
            )
            with progress.open("a") as f:  # partial results survive an interrupted run
                f.write(json.dumps({"recogniser": name, **results[name][-1]}) + "\n")
    summary = report(results)
    return {"summary": summary, "clips": len(clips)}


# ---------------------------------------------------------------------------------------------
async def _stream_once(
    rec: Recognizer, clip: Any, speech_end: int, mode: str, speculate: bool
) -> float:
    """Seconds from the end of speech to the final recognition, fed in real time (32 ms
    frames, as the page's worklet sends them), handled as the server's stream route does."""
    pool = DecoderPool(1, queue=4)
    # Without speculation (the baseline) the end-pointer decodes only at the end of the
    # utterance: hands-free's full 0.7 s of silence, push-to-talk's release.
    quiet = {} if speculate else {"settle_s": 10.0, "commit_s": 10.0, "end_silence_s": 10.0}
    if not speculate and mode == "handsfree":
        quiet = {"settle_s": 0.7, "commit_s": 0.7, "end_silence_s": 0.7}
    session = StreamSession(mode, score=SileroStream(), **quiet)
    hold = int(0.5 * SAMPLE_RATE)
    tail = hold if mode == "ptt" else int(1.5 * SAMPLE_RATE)
    audio = np.concatenate([clip[:speech_end], np.zeros(tail, np.float32)])
    pcm = (np.clip(audio, -1, 1) * 32767).astype("<i2").tobytes()
    chunk = 512
    lock = asyncio.Lock()
    finals: asyncio.Queue[Final] = asyncio.Queue()
    tasks: list[asyncio.Task[Any]] = []

    async def handle(events: list[Any]) -> None:
        for ev in events:
            if isinstance(ev, Speculation):
                tasks.append(asyncio.create_task(speculate_on(ev)))
            elif isinstance(ev, Final):
                finals.put_nowait(ev)

    async def speculate_on(ev: Speculation) -> None:
        r = await pool.run(rec.recognize, ev.samples, vad=False)
        async with lock:
            out = session.decided(ev.serial, decisive(r, rec.nlu, THRESHOLD))
        await handle(out)

    start = time.perf_counter()
    end_of_speech = start + speech_end / SAMPLE_RATE
    try:
        for i in range(0, len(audio), chunk):
            await asyncio.sleep(max(0.0, start + i / SAMPLE_RATE - time.perf_counter()))
            async with lock:
                events = await asyncio.to_thread(session.feed, pcm[2 * i : 2 * (i + chunk)])
                if mode == "ptt" and i + chunk >= len(audio):
                    events += session.end()
            await handle(events)
            if not finals.empty():
                break
        final = await asyncio.wait_for(finals.get(), 30)
        await pool.run(rec.recognize, final.samples, vad=not final.trimmed)
        return time.perf_counter() - end_of_speech
    finally:
        for t in tasks:
            t.cancel()
        pool.close()


def bench_stream(recognizer: Recognizer, quick: bool) -> dict[str, Any]:
    shared = Recognizer(recognizer.model, recognizer.nlu)  # reuse on (the product)
    utterances = pick_utterances(6 if quick else 12)
    work = Path(tempfile.mkdtemp(prefix="uavc-speech-stream-"))
    rows: dict[str, list[float]] = defaultdict(list)
    reused = 0
    for i, row in enumerate(utterances):
        wav = synthesise(work / f"s{i}.wav", row["text"], voice=VOICES[i % len(VOICES)], seed=i)
        clip = read_wav(wav.read_bytes())
        span = speech_span(clip, min_silence_ms=300)
        if span is None:
            continue
        speech_end = min(len(clip), span[1] - int(0.3 * SAMPLE_RATE))  # without the VAD pad
        for mode in ("ptt", "handsfree"):
            for speculate in (False, True):
                rec = shared if speculate else recognizer
                before = shared.shared.hits if shared.shared else 0
                latency = asyncio.run(_stream_once(rec, clip, speech_end, mode, speculate))
                reused += (shared.shared.hits if shared.shared else 0) - before
                rows[f"{mode}, {'speculative + reuse' if speculate else 'baseline'}"].append(
                    latency * 1000
                )
    print("\n## Microphone stream: end of speech -> final recognition (real-time feed)")
    print("| stream | clips | p50 ms | p95 ms |")
    print("|---|---|---|---|")
    out: dict[str, Any] = {}
    for name, xs in rows.items():
        out[name] = {"p50_ms": pct(xs, 0.5), "p95_ms": pct(xs, 0.95), "n": len(xs)}
        print(f"| {name} | {len(xs)} | {pct(xs, 0.5):.0f} | {pct(xs, 0.95):.0f} |")
    print(f"finals that reused a speculative decode: {reused}")
    out["reused"] = reused
    return out


# ---------------------------------------------------------------------------------------------
def bench_voice(repeats: int) -> dict[str, Any]:
    """Synthesis time of typical replies, per voice (the same sentences, one after another)."""
    import io
    import wave

    from server.speech.errors import SynthesisError
    from server.speech.synth import NeuralVoice, Voice, espeak

    voices: list[tuple[Voice, float]] = []
    t0 = time.perf_counter()
    try:
        voices.append((NeuralVoice.load(), time.perf_counter() - t0))
    except SynthesisError as exc:
        print(f"(hibari-tts not measured: {exc})")
    fallback = espeak()
    if fallback is not None:
        voices.append((fallback, 0.0))
    print("\n## Spoken replies: synthesis time per reply (one after another)")
    print("| voice | load s | replies | p50 ms | p95 ms | audio p50 s | x real time p50 |")
    print("|---|---|---|---|---|---|---|")
    out: dict[str, Any] = {}
    for voice, load_s in voices:
        ms: list[float] = []
        audio: list[float] = []
        for _ in range(repeats):
            for text in REPLIES:
                t = time.perf_counter()
                data = voice.wav(text)
                ms.append((time.perf_counter() - t) * 1000)
                with wave.open(io.BytesIO(data)) as w:  # espeak-ng's header has no length
                    frames = len(w.readframes(w.getnframes())) // w.getsampwidth()
                    audio.append(frames / w.getframerate())
        xrt = [a / (m / 1000) for a, m in zip(audio, ms, strict=True)]
        out[voice.name] = {
            "load_s": load_s,
            "p50_ms": pct(ms, 0.5),
            "p95_ms": pct(ms, 0.95),
            "audio_p50_s": pct(audio, 0.5),
            "xrt_p50": pct(xrt, 0.5),
        }
        print(
            f"| {voice.name} | {load_s:.1f} | {len(ms)} | {pct(ms, 0.5):.0f} | "
            f"{pct(ms, 0.95):.0f} | {pct(audio, 0.5):.1f} | {pct(xrt, 0.5):.0f} |"
        )
    return out


# ---------------------------------------------------------------------------------------------
class _State:
    x = y = 0.0
    z = 1.0
    yaw_rad = vx = vy = vz = 0.0


def _loop_while(seconds: float, busy: Any | None, **options: Any) -> LoopStats:
    pid, sp, st = PaperPID(), Setpoint(1.0, 0.5, 1.2, 0.3), _State()
    loop = ControlLoop(lambda now, dt: pid.step(st, sp, 0.01), period_s=0.01, **options)
    stop = threading.Event()
    worker = threading.Thread(target=busy, args=(stop,)) if busy else None
    if worker:
        worker.start()
        time.sleep(0.5)  # decoding under way before the loop is measured
    loop.start()
    time.sleep(seconds)
    loop.stop()
    stop.set()
    if worker:
        worker.join()
    return loop.stats()


def _loop_child(seconds: float, out: Any) -> None:
    """The loop as a vehicle process runs it (server/vehicles/host.py, drone/vehicle.py)."""
    sys.setswitchinterval(VEHICLE_SWITCH_INTERVAL_S)
    settings = Settings()
    raise_priority(settings.vehicle_nice, settings.vehicle_rt_priority)
    stats = _loop_while(
        seconds,
        None,
        yield_while_spinning=False,
        realtime_priority=settings.control_rt_priority,
    )
    out.put(stats.as_dict())


def _loop_in_process(seconds: float, busy: Any | None) -> dict[str, Any]:
    """The loop in a process of its own, as `serve` runs each drone's flight stack by default,
    while ``busy`` decodes in this one."""
    import multiprocessing

    ctx = multiprocessing.get_context("spawn")
    results = ctx.Queue()
    stop = threading.Event()
    worker = threading.Thread(target=busy, args=(stop,)) if busy else None
    if worker:
        worker.start()
        time.sleep(0.5)
    child = ctx.Process(target=_loop_child, args=(seconds, results))
    child.start()
    stats: dict[str, Any] = results.get(timeout=seconds + 60)
    child.join()
    stop.set()
    if worker:
        worker.join()
    return stats


def bench_loop(recognizer: Recognizer, model_dir: Path | None, seconds: float) -> dict[str, Any]:
    clip = read_wav(
        synthesise(
            Path(tempfile.mkdtemp()) / "c.wav", "take off and fly to marker three", seed=5
        ).read_bytes()
    )

    def streams(workers: int, rec: Recognizer) -> Any:
        def run(stop: threading.Event) -> None:
            async def main() -> int:
                pool = DecoderPool(workers, queue=8)
                done = 0

                async def stream() -> None:
                    nonlocal done
                    while not stop.is_set():
                        await pool.run(rec.recognize, clip)
                        done += 1

                await asyncio.gather(*(stream() for _ in range(3)))
                pool.close()
                return done

            counts.append(asyncio.run(main()))

        return run

    bounded = default_workers()
    wide = Recognizer(load_whisper(resolve(model_dir), workers=3), recognizer.nlu, reuse=False)
    rows = [
        ("idle (baseline)", None, False),
        (f"3 streams, bounded pool ({bounded} decoder)", streams(bounded, recognizer), False),
        ("3 streams, unbounded (3 decoders)", streams(3, wide), False),
        ("loop in its own process (serve's default), idle", None, True),
        (
            f"loop in its own process, 3 streams, bounded ({bounded})",
            streams(bounded, recognizer),
            True,
        ),
    ]
    print(f"\n## 100 Hz control loop while decoding ({seconds:g} s per row)")
    print("| condition | rate Hz | period err p50 µs | p99 µs | max µs | overruns | decodes |")
    print("|---|---|---|---|---|---|---|")
    out: dict[str, Any] = {}
    for name, busy, own_process in rows:
        counts: list[int] = []
        st = (
            _loop_in_process(seconds, busy) if own_process else _loop_while(seconds, busy).as_dict()
        )
        decodes = counts[0] if counts else 0
        out[name] = st | {"decodes": decodes}
        print(
            f"| {name} | {st['rate_hz']:.2f} | {st['period_error_p50_s'] * 1e6:.0f} | "
            f"{st['period_error_p99_s'] * 1e6:.0f} | {st['period_error_max_s'] * 1e6:.0f} | "
            f"{st['overruns']} | {decodes} |"
        )
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="108 clips, 5 s loop rows")
    ap.add_argument("--asr-model", type=Path, default=None)
    ap.add_argument("--window-s", type=float, default=MIN_S, help="shortest encoder window")
    ap.add_argument("--beams", type=int, default=BEAMS, help="beam width (n-best size)")
    ap.add_argument(
        "--threads", type=int, default=1, help="threads per decoder (threads_per_worker)"
    )
    ap.add_argument(
        "--tts",
        choices=list(TTS_VOICES),
        default="espeak-ng",
        help="voices of the accuracy clips: espeak-ng's (the accuracy set), flite's or hibari's",
    )
    ap.add_argument("--json", type=Path)
    ap.add_argument("--skip-loop", action="store_true")
    ap.add_argument("--skip-stream", action="store_true")
    ap.add_argument("--skip-accuracy", action="store_true")
    ap.add_argument("--skip-voice", action="store_true")
    ap.add_argument(
        "--rows", choices=["all", "guided"], default="all", help="section 1's recognisers"
    )
    ap.add_argument("--seed", type=int, default=15, help="which utterances (15: the tuning set)")
    ap.add_argument(
        "--via",
        choices=["whole", "stream"],
        default="whole",
        help="section 1's guided row: each clip whole, or through the hands-free stream's "
        "end-pointer as the page sends it (stream_finals)",
    )
    ap.add_argument("--progress", type=Path, help="section 1's per-clip results (JSONL)")
    ap.add_argument(
        "--report", type=Path, help="only print the tables of a (partial) progress file"
    )
    args = ap.parse_args(argv)
    if args.report:
        results: dict[str, list[dict[str, Any]]] = defaultdict(list)
        for line in args.report.read_text().splitlines():
            row = json.loads(line)
            results[row.pop("recogniser")].append(row)
        pairs = min(len(v) for v in results.values())
        print(f"{pairs} clips with every recogniser (from {args.report})")
        report({k: v[:pairs] for k, v in results.items()})
        return 0
    import os
    import shutil

    if not (shutil.which("espeak-ng") and shutil.which("sox")):
        print("bench/speech.py needs espeak-ng and sox (apt-get install espeak-ng sox)")
        return 1
    if args.tts == "flite" and not shutil.which("flite"):
        print("bench/speech.py --tts flite needs flite (apt-get install flite)")
        return 1
    load = os.getloadavg()
    cores = os.cpu_count()
    print(f"load average at start: {load[0]:.1f} {load[1]:.1f} {load[2]:.1f} on {cores} cores")
    print(f"decoder threads: {args.threads}; window {args.window_s:g} s, {args.beams} beams")
    whisper = load_whisper(resolve(args.asr_model), workers=1, threads_per_worker=args.threads)
    # every clip decoded, none shared
    rec = Recognizer(whisper, default_nlu(), reuse=False, window_s=args.window_s, beams=args.beams)
    out: dict[str, Any] = {}
    if not args.skip_accuracy:
        out["accuracy"] = bench_accuracy(
            rec, args.quick, args.tts, args.rows, args.seed, args.progress, args.via
        )
    if not args.skip_stream:
        out["stream"] = bench_stream(rec, args.quick)
    if not args.skip_voice:
        out["voice"] = bench_voice(2 if args.quick else 5)
    if not args.skip_loop:
        out["loop"] = bench_loop(rec, args.asr_model, 5.0 if args.quick else 20.0)
    load = os.getloadavg()
    print(f"\nload average at end: {load[0]:.1f} {load[1]:.1f} {load[2]:.1f}")
    if args.json:
        args.json.write_text(json.dumps(out, indent=2, default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
