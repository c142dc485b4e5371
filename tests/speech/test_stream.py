"""The microphone stream's session logic: push-to-talk and hands-free (no model, no socket)."""

from __future__ import annotations

import numpy as np
import pytest

from server.speech.audio import SAMPLE_RATE
from server.speech.stream import Final, Interim, Problem, StreamSession, control_kind


def pcm(seconds: float, loud: bool) -> bytes:
    n = int(seconds * SAMPLE_RATE)
    x = np.sin(np.arange(n) * 0.3) * (12000 if loud else 0)
    return x.astype("<i2").tobytes()


def energy(samples: np.ndarray) -> bool:
    """A stand-in detector for unit tests: speech = loud (the server uses Silero VAD)."""
    return float(np.sqrt(np.mean(samples**2))) > 0.05


def feed(session: StreamSession, data: bytes, chunk_s: float = 0.1) -> list[object]:
    step = int(chunk_s * SAMPLE_RATE) * 2
    events: list[object] = []
    for i in range(0, len(data), step):
        events += session.feed(data[i : i + step])
    return events


def test_push_to_talk_interims_then_final_on_release() -> None:
    s = StreamSession("ptt", interim_step_s=0.5)
    events = feed(s, pcm(1.6, True))
    assert [type(e) for e in events] == [Interim, Interim, Interim]
    final = s.end()
    assert len(final) == 1 and isinstance(final[0], Final)
    assert len(final[0].samples) == int(1.6 * SAMPLE_RATE)
    assert s.buffered_s == 0 and s.end() == []


def test_push_to_talk_over_the_limit_is_discarded_and_memory_stays_bounded() -> None:
    s = StreamSession("ptt", max_utterance_s=2.0)
    events = feed(s, pcm(5.0, True))
    problems = [e for e in events if isinstance(e, Problem)]
    assert len(problems) == 1 and "discarded" in problems[0].message
    assert s.buffered_s == 0  # nothing kept while the key stays held
    assert s.end() == []


def test_cancel_drops_the_utterance() -> None:
    s = StreamSession("ptt")
    feed(s, pcm(0.5, True))
    s.cancel()
    assert s.end() == []


def test_odd_byte_frames_and_empty_frames_are_harmless() -> None:
    s = StreamSession("ptt")
    assert s.feed(b"") == [] and s.feed(b"\x01") == []


def test_handsfree_cuts_utterances_at_silence_and_drops_silence() -> None:
    s = StreamSession("handsfree", detect=energy, end_silence_s=0.6, keep_s=0.5)
    events = feed(s, pcm(3.0, False))  # a quiet room: nothing, and only pre-roll kept
    assert events == [] and s.buffered_s <= 0.5 + 0.1  # keep_s=0.5 here
    events = feed(s, pcm(1.2, True) + pcm(1.0, False) + pcm(0.8, True) + pcm(1.0, False))
    finals = [e for e in events if isinstance(e, Final)]
    assert len(finals) == 2
    assert 1.2 <= len(finals[0].samples) / SAMPLE_RATE <= 1.2 + 0.5 + 1.0
    assert s.utterances == 2


def test_handsfree_long_speech_is_cut_at_the_limit() -> None:
    s = StreamSession("handsfree", detect=energy, max_utterance_s=2.0)
    events = feed(s, pcm(5.0, True))
    finals = [e for e in events if isinstance(e, Final)]
    assert finals and all(len(f.samples) <= 2.0 * SAMPLE_RATE for f in finals)
    assert s.buffered_s <= 2.0


def test_bad_mode() -> None:
    with pytest.raises(ValueError, match="mode"):
        StreamSession("always")
    with pytest.raises(ValueError, match="voice activity"):
        StreamSession("handsfree")


@pytest.mark.parametrize(
    ("text", "kind"),
    [
        ('{"type": "end"}', "end"),
        ('{"type": "cancel", "x": [1]}', "cancel"),
        ("not json", None),
        ("[1, 2]", None),
        ('{"type": 3}', None),
        ("[" * 100_000, None),  # json raises RecursionError, which the stream did not catch
        ('{"a":' * 100_000, None),
    ],
)
def test_text_frames_name_a_control_or_nothing(text: str, kind: str | None) -> None:
    assert control_kind(text) == kind


def test_push_to_talk_decodes_speculatively_when_speech_falls_silent() -> None:
    s = StreamSession("ptt", detect=energy, interim_step_s=5.0, settle_s=0.4)
    assert feed(s, pcm(0.3, False)) == []  # silence before any speech: nothing to decode
    assert feed(s, pcm(1.0, True)) == []  # speaking (no interim step reached)
    events = feed(s, pcm(0.8, False))  # the operator stops, still holding the button
    assert [type(e) for e in events] == [Interim] and s.speculated == 1
    spoken = len(events[0].samples) / SAMPLE_RATE  # type: ignore[attr-defined]
    assert 1.7 - 1e-9 <= spoken <= 2.1  # all the speech and >= settle_s of silence after it
    assert feed(s, pcm(0.5, False)) == []  # more silence: no second speculation
    feed(s, pcm(0.5, True))
    assert [type(e) for e in feed(s, pcm(0.6, False))] == [Interim]  # spoke again, fell silent
    assert [type(e) for e in s.end()] == [Final] and s.speculated == 2


def test_handsfree_decodes_speculatively_before_the_end_of_the_utterance() -> None:
    s = StreamSession("handsfree", detect=energy, end_silence_s=0.7, settle_s=0.4)
    events = feed(s, pcm(1.2, True) + pcm(1.2, False))
    kinds = [type(e) for e in events]
    assert kinds.count(Final) == 1 and s.speculated == 1
    speculative = [e for e in events if isinstance(e, Interim)][-1]
    final = next(e for e in events if isinstance(e, Final))
    assert kinds.index(Final) > kinds.index(Interim)
    # The final only adds silence to what the speculative decode had.
    n = len(speculative.samples)
    assert np.array_equal(final.samples[:n], speculative.samples)
    assert not np.any(final.samples[n:])
