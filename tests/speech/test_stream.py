"""The microphone stream's session logic: push-to-talk and hands-free (no model, no socket)."""

from __future__ import annotations

import numpy as np
import pytest

from server.speech.audio import SAMPLE_RATE
from server.speech.stream import (
    FRAME,
    Final,
    Interim,
    Problem,
    Speculation,
    StreamSession,
    control_kind,
)


def pcm(seconds: float, loud: bool) -> bytes:
    n = int(seconds * SAMPLE_RATE)
    x = np.sin(np.arange(n) * 0.3) * (12000 if loud else 0)
    return x.astype("<i2").tobytes()


def energy(samples: np.ndarray) -> np.ndarray:
    """A stand-in scorer for unit tests: a frame is speech when loud (the server uses Silero
    VAD's probability)."""
    frames = samples[: len(samples) - len(samples) % FRAME].reshape(-1, FRAME)
    return (np.sqrt(np.mean(frames**2, axis=1)) > 0.05).astype(np.float32)


def feed(session: StreamSession, data: bytes, chunk_s: float = FRAME / SAMPLE_RATE) -> list[object]:
    step = round(chunk_s * SAMPLE_RATE) * 2
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
    s = StreamSession("handsfree", score=energy, end_silence_s=0.6, keep_s=0.5)
    events = feed(s, pcm(3.0, False))  # a quiet room: nothing, and only pre-roll kept
    assert events == [] and s.buffered_s <= 0.5 + 0.1  # keep_s=0.5 here
    events = feed(s, pcm(1.2, True) + pcm(1.0, False) + pcm(0.8, True) + pcm(1.0, False))
    finals = [e for e in events if isinstance(e, Final)]
    assert len(finals) == 2
    assert 1.2 <= len(finals[0].samples) / SAMPLE_RATE <= 1.2 + 0.5 + 1.0
    assert s.utterances == 2


def test_handsfree_long_speech_is_cut_at_the_limit() -> None:
    s = StreamSession("handsfree", score=energy, max_utterance_s=2.0)
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
    s = StreamSession("ptt", score=energy, interim_step_s=5.0, settle_s=0.2, pre_s=0.3)
    assert feed(s, pcm(0.5, False)) == []  # silence before any speech: nothing to decode
    assert feed(s, pcm(1.0, True)) == []  # speaking (no interim step reached)
    events = feed(s, pcm(0.8, False))  # the operator stops, still holding the button
    assert [type(e) for e in events] == [Speculation] and s.speculated == 1
    spec = events[0]
    assert isinstance(spec, Speculation)
    # The speech only: the pre-roll, the speech, settle_s of silence (frame-exact).
    spoken = len(spec.samples) / SAMPLE_RATE
    assert 0.3 + 1.0 + 0.2 - 0.07 <= spoken <= 0.3 + 1.0 + 0.2 + 0.07
    assert feed(s, pcm(0.5, False)) == []  # more silence: no second speculation
    assert s.decided(spec.serial, True) == []  # push-to-talk ends on release only
    (final,) = s.end()
    assert isinstance(final, Final) and final.trimmed
    assert np.array_equal(final.samples, spec.samples)  # the same speech: the decode is reused


def test_push_to_talk_speaking_again_voids_the_speculation() -> None:
    s = StreamSession("ptt", score=energy, interim_step_s=5.0)
    feed(s, pcm(0.6, True))
    (spec,) = feed(s, pcm(0.4, False))
    assert isinstance(spec, Speculation)
    feed(s, pcm(0.5, True))
    (final,) = s.end()  # released while speaking: all the speech, up to the release
    assert isinstance(final, Final) and final.trimmed
    assert len(final.samples) == int(1.5 * SAMPLE_RATE) > len(spec.samples)


def test_push_to_talk_without_a_detector_hands_over_everything() -> None:
    s = StreamSession("ptt", interim_step_s=5.0)
    feed(s, pcm(0.4, False) + pcm(0.4, True))
    (final,) = s.end()
    assert isinstance(final, Final) and not final.trimmed
    assert len(final.samples) == int(0.8 * SAMPLE_RATE)


def handsfree(**options: float) -> StreamSession:
    return StreamSession(
        "handsfree", score=energy, interim_step_s=5.0, settle_s=0.2, commit_s=0.3,
        end_silence_s=0.7, **options,
    )  # fmt: skip


def test_handsfree_decisive_reading_ends_the_utterance_after_the_short_silence() -> None:
    s = handsfree()
    events = feed(s, pcm(0.5, False) + pcm(1.0, True) + pcm(0.25, False))
    (spec,) = [e for e in events if isinstance(e, Speculation)]
    assert not any(isinstance(e, Final) for e in events)
    # The reading comes back before commit_s of silence: the utterance ends at commit_s.
    assert s.decided(spec.serial, True) == []
    events = feed(s, pcm(0.1, False))
    (final,) = events
    assert isinstance(final, Final) and final.trimmed
    assert np.array_equal(final.samples, spec.samples)
    assert s.committed == 1 and s.utterances == 1


def test_handsfree_decisive_reading_after_the_short_silence_ends_it_at_once() -> None:
    s = handsfree()
    events = feed(s, pcm(1.0, True) + pcm(0.4, False))  # a slow decode: 0.4 s of silence
    (spec,) = [e for e in events if isinstance(e, Speculation)]
    (final,) = s.decided(spec.serial, True)
    assert isinstance(final, Final) and final.samples is spec.samples
    assert feed(s, pcm(1.0, False)) == []  # the utterance is over: nothing more
    assert s.utterances == 1


def test_handsfree_doubtful_reading_waits_for_the_full_silence() -> None:
    s = handsfree()
    events = feed(s, pcm(1.0, True) + pcm(0.3, False))
    (spec,) = [e for e in events if isinstance(e, Speculation)]
    assert s.decided(spec.serial, False) == []
    assert feed(s, pcm(0.3, False)) == []  # 0.6 s of silence: not yet
    (final,) = feed(s, pcm(0.15, False))
    assert isinstance(final, Final) and np.array_equal(final.samples, spec.samples)
    assert s.committed == 0


def test_handsfree_pause_mid_sentence_is_not_cut_even_if_the_first_half_reads_whole() -> None:
    """ "Take off … and go to marker three": the first half is decisive, but the operator
    speaks again before commit_s of silence; the utterance is the whole sentence."""
    s = handsfree()
    events = feed(s, pcm(0.8, True) + pcm(0.25, False))
    (spec,) = [e for e in events if isinstance(e, Speculation)]
    events = feed(s, pcm(0.8, True))  # speech resumes
    assert s.decided(spec.serial, True) == []  # stale: the speech went on
    events += feed(s, pcm(0.8, False))
    finals = [e for e in events if isinstance(e, Final)]
    assert len(finals) == 1 and s.speculated == 2
    assert len(finals[0].samples) >= (0.8 + 0.25 + 0.8) * SAMPLE_RATE


def test_handsfree_next_utterance_starts_clean_after_an_early_end() -> None:
    s = handsfree()
    events = feed(s, pcm(0.8, True) + pcm(0.35, False))
    (spec,) = [e for e in events if isinstance(e, Speculation)]
    (first,) = s.decided(spec.serial, True)
    events = feed(s, pcm(0.4, False) + pcm(0.6, True) + pcm(0.8, False))
    (second,) = [e for e in events if isinstance(e, Final)]
    assert isinstance(first, Final) and isinstance(second, Final)
    # The second has its own pre-roll of silence and none of the first's speech.
    lead = second.samples[: int(0.25 * SAMPLE_RATE)]
    assert not np.any(lead) and s.utterances == 2


def test_bad_end_pointing_options() -> None:
    with pytest.raises(ValueError, match="settle_s"):
        StreamSession("ptt", settle_s=0.5, commit_s=0.3)


def test_frames_that_queued_up_end_point_as_if_fed_one_by_one() -> None:
    """A server that fell behind feeds what queued up in one batch: the same utterances."""
    audio = pcm(0.4, False) + pcm(0.9, True) + pcm(0.9, False) + pcm(0.5, True) + pcm(1.0, False)
    one, batched = handsfree(), handsfree()
    a = [e for e in feed(one, audio) if isinstance(e, Final | Speculation)]
    b = [e for e in feed(batched, audio, chunk_s=0.7) if isinstance(e, Final | Speculation)]
    assert [type(e) for e in a] == [type(e) for e in b] == [Speculation, Final] * 2
    assert all(np.array_equal(x.samples, y.samples) for x, y in zip(a, b, strict=True))


def noise(seconds: float, level: float, seed: int) -> bytes:
    """Seeded white noise at ``level`` (0..1 full scale, RMS): a microphone's quiet room."""
    x = np.random.default_rng(seed).normal(0.0, level * 32767, int(seconds * SAMPLE_RATE))
    return np.clip(x, -32768, 32767).astype("<i2").tobytes()


def frames_until(s: StreamSession, data: bytes, kind: type) -> tuple[list[object], int]:
    """Feed ``data`` frame by frame up to the first event of ``kind``: (the events, the
    samples fed by then)."""
    step = FRAME * 2
    for i in range(0, len(data), step):
        events = s.feed(data[i : i + step])
        if any(isinstance(e, kind) for e in events):
            return events, (i + step) // 2
    raise AssertionError(f"no {kind.__name__} in {len(data) // 2} samples")


def test_handsfree_speculates_after_listen_s_with_the_heard_silence_repeated() -> None:
    """The decode starts after listen_s of silence, not settle_s; the pad not heard yet is
    the silence heard, repeated, so the speculation is as long as one after settle_s."""
    s = StreamSession("handsfree", score=energy, interim_step_s=5.0, pre_s=0.3, settle_s=0.3)
    stream = pcm(0.5, False) + pcm(1.0, True) + noise(1.0, 0.002, seed=3)
    events, fed = frames_until(s, stream, Speculation)
    (spec,) = [e for e in events if isinstance(e, Speculation)]
    assert isinstance(spec, Speculation)
    # The first frame the scorer hears as silence: the one after the last loud sample.
    quiet_from = -(-int(1.5 * SAMPLE_RATE) // FRAME) * FRAME
    assert fed - quiet_from == s.listen < s.settle  # asked after listen_s of silence
    samples = np.frombuffer(stream, "<i2").astype(np.float32) / 32768
    heard = samples[quiet_from : quiet_from + s.listen]
    pad = spec.samples[-(s.settle - s.listen) :]
    assert np.array_equal(pad, np.resize(heard, len(pad)))
    start = int(0.5 * SAMPLE_RATE) // FRAME * FRAME - s.pre  # pre-roll before the first loud frame
    assert np.array_equal(spec.samples[: -len(pad)], samples[start : quiet_from + s.listen])


def test_handsfree_a_quiet_pad_keeps_the_early_speculation_and_its_decisive_end() -> None:
    s = StreamSession(
        "handsfree", score=energy, interim_step_s=5.0, settle_s=0.3, commit_s=0.3,
        end_silence_s=0.7,
    )  # fmt: skip
    events, _ = frames_until(s, pcm(1.0, True) + noise(1.0, 0.002, seed=4), Speculation)
    (spec,) = [e for e in events if isinstance(e, Speculation)]
    assert isinstance(spec, Speculation)
    assert s.decided(spec.serial, True) == []  # decisive before commit_s of silence
    events = feed(s, noise(0.3, 0.002, seed=5))  # the same quiet room: no sound in the pad
    (final,) = [e for e in events if isinstance(e, Final)]
    assert isinstance(final, Final) and final.samples is spec.samples
    assert s.speculated == 1 and s.committed == 1


def test_handsfree_a_sound_in_the_pad_asks_again_with_the_pad_as_heard() -> None:
    """A soft sound after listen_s that the detector scores as silence (a trailing consonant)
    voids the early speculation: the pad as heard is decoded, and the early reading, even a
    decisive one, ends nothing."""
    s = StreamSession(
        "handsfree", score=energy, interim_step_s=5.0, settle_s=0.3, commit_s=0.3,
        end_silence_s=0.7,
    )  # fmt: skip
    quiet = noise(0.16, 0.002, seed=6)
    soft = noise(0.1, 0.02, seed=7)  # under the energy scorer's 0.05, 10x the room's level
    stream = pcm(1.0, True) + quiet + soft + noise(0.5, 0.002, seed=8)
    events, fed = frames_until(s, stream, Speculation)
    (first,) = [e for e in events if isinstance(e, Speculation)]
    assert isinstance(first, Speculation)
    events = feed(s, stream[fed * 2 :])
    respec = [e for e in events if isinstance(e, Speculation)]
    assert len(respec) == 1 and respec[0].serial > first.serial
    assert s.decided(first.serial, True) == []  # stale: the pad was louder than its stand-in
    spoken = np.frombuffer(stream, "<i2").astype(np.float32) / 32768
    tail = respec[0].samples[-s.settle :]
    quiet_from = -(-int(1.0 * SAMPLE_RATE) // FRAME) * FRAME
    assert np.array_equal(tail, spoken[quiet_from : quiet_from + s.settle])
    finals = [e for e in events if isinstance(e, Final)]  # no decisive reading: full silence
    assert len(finals) == 1 and finals[0].samples is respec[0].samples
    assert s.committed == 0


def test_early_speculation_options() -> None:
    with pytest.raises(ValueError, match="listen_s"):
        StreamSession("ptt", listen_s=0.4, settle_s=0.3)
    with pytest.raises(ValueError, match="listen_s"):
        StreamSession("ptt", listen_s=0.0)
