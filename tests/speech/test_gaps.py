"""Grammar gaps: transcripts heard plainly that the grammars cannot read whole are read back,
never flown as a guess, and logged (bounded) so the grammars can be widened from them."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from server.language.nlu import default_nlu
from server.speech.gaps import GapLog
from server.speech.recognizer import GAP_CONFIDENCE, Recognition, choose
from server.speech.snap import Snapper
from server.speech.vocabulary import vocabulary

_NLU = default_nlu()
_SNAPPER = Snapper(_NLU, vocabulary(_NLU.grammar))
CAP = 0.49  # just under Settings().confidence_threshold


def test_words_heard_plainly_and_bent_are_read_back_not_flown() -> None:
    # hibari-tts's "slow down a little", heard word for word (0.96): the snap's nearest
    # sentence is "down" (a move down), which the speaker never asked for.
    rec = choose([("Slow down a little.", 0.96)], _SNAPPER, cap=CAP)
    assert rec.gap == "Slow down a little."
    assert rec.confidence <= CAP
    assert rec.commands in ([], [{"action": "move", "direction": "down"}])


@pytest.mark.parametrize(
    ("beams", "gap"),
    [
        ([("Take a photo of the door.", 0.96)], "Take a photo of the door."),
        ([("Slow down a little.", 0.96), ("Slow down.", 0.5)], "Slow down a little."),
        ([("Take off.", 0.95)], ""),  # read whole as heard
        ([("Slow down a little.", GAP_CONFIDENCE - 0.05)], ""),  # not heard plainly
        ([("Yes.", 0.95)], ""),  # an answer
        ([("", 0.0)], ""),
    ],
)
def test_what_is_a_gap(beams: list[tuple[str, float]], gap: str) -> None:
    assert choose(beams, _SNAPPER, cap=CAP).gap == gap


def test_a_gap_log_keeps_entries_and_is_bounded(tmp_path: Path) -> None:
    log = GapLog(tmp_path / "gaps.jsonl", max_bytes=2000)
    rec = Recognition("down", 0.49, [{"action": "move", "direction": "down"}], gap="Slow down.")
    assert not log.record(Recognition("take off", 0.8), 1.0)  # no gap: nothing written
    for i in range(100):
        assert log.record(rec, 1000.0 + i)
    kept = log.read()
    assert kept[-1]["t"] == 1099.0 and kept[-1]["heard"] == "Slow down."
    assert kept[-1]["commands"] == [{"action": "move", "direction": "down"}]
    assert [e["t"] for e in kept] == sorted(e["t"] for e in kept)
    files = list(tmp_path.iterdir())
    assert sorted(p.name for p in files) == ["gaps.jsonl", "gaps.jsonl.1"]
    assert sum(p.stat().st_size for p in files) <= 2 * 2000


def test_an_unwritable_gap_log_is_not_an_error(tmp_path: Path) -> None:
    (tmp_path / "gaps.jsonl").mkdir()  # a directory where the file should be
    log = GapLog(tmp_path / "gaps.jsonl")
    assert not log.record(Recognition("x", 0.1, gap="Slow down."), 1.0)
    assert log.read() == []


def test_the_service_logs_the_gaps_of_whole_utterances(tmp_path: Path) -> None:
    """Real speech (hibari-tts's voice): a sentence the grammars do not know is logged."""
    pytest.importorskip("hibari")
    from server.speech.audio import read_wav
    from server.speech.service import SpeechConfig, SpeechService
    from tests.speech.conftest import HAVE_TTS, synthesise

    if not HAVE_TTS:
        pytest.skip("sox is needed")
    clip = synthesise(tmp_path / "gap.wav", "take a photo of the door", voice="heart", tts="hibari")
    samples = read_wav(clip.read_bytes())
    path = tmp_path / "data" / "speech-gaps.jsonl"
    service = SpeechService(SpeechConfig(workers=1, gap_log=path), _NLU, clock=lambda: 42.0)

    async def run() -> Recognition:
        await service.start(preload=False)
        try:
            return await service.recognize(samples)
        finally:
            await service.stop()

    rec = asyncio.run(run())
    assert rec.gap, rec
    assert not rec.commands or rec.confidence < 0.5  # not flown
    [logged] = GapLog(path).read()
    assert logged["t"] == 42.0 and "photo" in logged["heard"].lower()
    assert logged["asr_confidence"] >= GAP_CONFIDENCE


@settings(max_examples=50, deadline=None, derandomize=True)
@given(st.text(max_size=300))
def test_a_damaged_gap_log_is_read_without_error(junk: str) -> None:
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "gaps.jsonl"
        log = GapLog(path)
        assert log.record(Recognition("down", 0.4, gap="Slow down."), 1.0)
        with path.open("a", encoding="utf-8") as f:
            f.write(junk)
        kept = log.read()
        assert kept[0]["heard"] == "Slow down."
        assert all(isinstance(e, dict) for e in kept)
