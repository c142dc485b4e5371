"""Decodes shared by identical speech (server/speech/memo.py), and the recogniser's use of it."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from server.speech.audio import read_wav
from server.speech.memo import SharedResults, digest
from server.speech.recognizer import Recognizer
from tests.speech.conftest import Synth


def test_a_second_caller_waits_for_the_running_computation_instead_of_repeating_it() -> None:
    shared: SharedResults[str] = SharedResults(size=4)
    started, release = threading.Event(), threading.Event()
    calls: list[str] = []

    def slow() -> str:
        calls.append("slow")
        started.set()
        release.wait(10)
        return "take off"

    first: list[tuple[str, bool]] = []
    worker = threading.Thread(target=lambda: first.append(shared.get("k", slow)))
    worker.start()
    assert started.wait(10)
    second: list[tuple[str, bool]] = []
    waiter = threading.Thread(target=lambda: second.append(shared.get("k", lambda: "other")))
    waiter.start()
    release.set()
    worker.join(10)
    waiter.join(10)
    assert first == [("take off", False)] and second == [("take off", True)]
    assert calls == ["slow"] and shared.hits == 1


def test_a_failure_reaches_the_caller_and_is_not_remembered() -> None:
    shared: SharedResults[int] = SharedResults(size=2)

    def broken() -> int:
        raise RuntimeError("decoder crashed")

    with pytest.raises(RuntimeError, match="decoder crashed"):
        shared.get("k", broken)
    assert shared.get("k", lambda: 7) == (7, False)


def test_only_the_most_recent_results_are_kept() -> None:
    shared: SharedResults[int] = SharedResults(size=2)
    for i in range(3):
        shared.get(i, lambda i=i: i)  # type: ignore[misc]
    assert shared.get(0, lambda: 100) == (100, False)  # evicted: computed again
    assert shared.get(2, lambda: -1) == (2, True)
    with pytest.raises(ValueError):
        SharedResults(size=0)


def test_the_digest_tells_values_and_lengths_apart() -> None:
    a = np.zeros(1600, np.float32)
    assert digest(a) == digest(a.copy()) != digest(np.zeros(1601, np.float32))
    b = a.copy()
    b[800] = 1e-6
    assert digest(a) != digest(b)


def test_the_final_reuses_the_speculative_decode_of_the_same_speech(
    recognizer: Recognizer, synth: Synth
) -> None:
    speech = read_wav(synth("land", voice="en-us", speed=160).read_bytes())
    silence = np.zeros(16000, np.float32)
    speculative = recognizer.recognize(np.concatenate([speech, silence[:8000]]))
    final = recognizer.recognize(np.concatenate([speech, silence]))  # only more silence
    assert final.reused and not speculative.reused
    assert final.commands == speculative.commands == [{"action": "land"}]
    assert final.confidence == speculative.confidence and final.audio_s > speculative.audio_s
    final.commands.append({"action": "takeoff"})  # a consumer's change stays its own
    assert recognizer.recognize(np.concatenate([speech, silence])).commands == [{"action": "land"}]
    other_state = recognizer.recognize(np.concatenate([speech, silence]), state="AIRBORNE_IDLE")
    assert not other_state.reused  # the dialog state changes what the snap may pick
