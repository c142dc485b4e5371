"""The encoder window (server/speech/window.py) and the choice among the beam's transcripts."""

from __future__ import annotations

import numpy as np
import pytest

from server.language.nlu import default_nlu
from server.speech.audio import read_wav
from server.speech.recognizer import BEAMS, Recognizer, choose, unrepeated
from server.speech.snap import Snapper
from server.speech.vocabulary import vocabulary
from server.speech.window import FULL_WINDOW_FRAMES, fits, window_frames
from tests.speech.conftest import Synth


def test_short_speech_gets_the_minimum_window() -> None:
    assert window_frames(0) == 1500
    assert window_frames(226) == 1500  # a 2.3 s command: 15 s, not 30 s
    assert window_frames(1400) == 1500  # 14 s + 1 s of pad


def test_longer_speech_gets_its_length_and_a_pad_in_whole_seconds_up_to_30_s() -> None:
    assert window_frames(1401) == 1600
    assert window_frames(2050) == 2200  # 20.5 s + 1 s -> 22 s
    assert window_frames(2900) == FULL_WINDOW_FRAMES
    assert window_frames(10_000) == FULL_WINDOW_FRAMES
    assert fits(2900) and not fits(2901)


def test_a_negative_length_is_an_error() -> None:
    with pytest.raises(ValueError, match="content_frames"):
        window_frames(-1)


@pytest.fixture(scope="module")
def snapper() -> Snapper:
    nlu = default_nlu()
    return Snapper(nlu, vocabulary(nlu.grammar))


def test_the_transcript_the_grammars_accept_beats_a_likelier_garbled_one(
    snapper: Snapper,
) -> None:
    rec = choose([("Take off in the hand man.", 0.62), ("Take off.", 0.58)], snapper)
    assert rec.commands == [{"action": "takeoff"}]
    assert rec.heard == "Take off." and rec.snap_distance == 0.0
    assert rec.confidence == pytest.approx(0.58 * 0.83)


def test_equal_support_keeps_the_decoders_order(snapper: Snapper) -> None:
    rec = choose([("Land.", 0.7), ("Land.", 0.7)], snapper)
    assert rec.commands == [{"action": "land"}] and rec.asr_confidence == 0.7


def test_a_sentence_the_decoder_repeated_is_flown_once(snapper: Snapper) -> None:
    # flite's voices, bench/speech.py: "Kill the motors. Kill the motors." ran two emergencies;
    # a repeated move would fly twice as far.
    rec = choose([("Fly forward 2 meters. Fly forward 2 meters.", 0.8)], snapper)
    assert rec.commands == [{"action": "move", "direction": "forward", "distance": 2}]
    assert rec.heard == "Fly forward 2 meters."
    assert unrepeated("Go land. go land") == "Go land."
    assert unrepeated("App you? App you.") == "App you?"
    for different in ("Take off. Land.", "Take off. Take off. Land.", "Land take off.", ""):
        assert unrepeated(different) == different


def test_an_answer_is_handed_on_as_heard(snapper: Snapper) -> None:
    # "Yes." answers the dialog's "Did you say …?": not snapped into a command ("Yaw." could
    # be), not dropped as a filler word.
    rec = choose([("Yes.", 0.7), ("Yaw.", 0.6)], snapper)
    assert rec.text == "Yes." and rec.commands == []
    assert rec.confidence == pytest.approx(0.7 * 0.83)
    rec = choose([("Take off.", 0.5), ("No.", 0.7)], snapper)
    assert rec.text == "No." and rec.commands == []


def test_no_transcript_means_nothing_heard(snapper: Snapper) -> None:
    for hypotheses in ([], [("", 0.0)], [("", 0.0), ("", 0.0)]):
        rec = choose(hypotheses, snapper)
        assert rec.text == "" and rec.commands == [] and rec.confidence == 0.0


def test_the_beam_gives_several_transcripts_best_first(
    recognizer: Recognizer, synth: Synth
) -> None:
    samples = read_wav(synth("take off", voice="en-us", speed=160).read_bytes())
    hypotheses = recognizer.hypotheses(samples)
    assert 1 < len(hypotheses) <= BEAMS
    assert hypotheses[0][0].strip(" .").lower() == "take off"
    assert all(0.0 <= conf <= 1.0 for _, conf in hypotheses)


def test_speech_longer_than_one_window_is_decoded_window_by_window(
    recognizer: Recognizer, synth: Synth
) -> None:
    clip = read_wav(synth("land", voice="en-us", speed=160).read_bytes())
    pause = np.zeros(16000 * 3, np.float32)
    long = np.concatenate([np.concatenate([clip, pause])] * 12)[: 16000 * 40]  # 40 s
    hypotheses = recognizer.hypotheses(long)
    assert len(hypotheses) == 1  # faster-whisper's own windowing: one transcript
    assert "land" in hypotheses[0][0].lower()


def test_a_reading_understood_whole_beats_a_more_confident_one_understood_in_part(
    snapper: Snapper,
) -> None:
    rec = choose([("Take off in the hand man.", 0.9), ("Land.", 0.4)], snapper)
    assert rec.commands == [{"action": "land"}]
    assert rec.confidence == pytest.approx(0.4 * 0.83)  # below the threshold: asked again


def test_with_nothing_understood_whole_the_most_confident_reading_is_kept(
    snapper: Snapper,
) -> None:
    garbled = "Wrong. Spin and pick like white 30-meg."
    rec = choose([(garbled, 0.3), ("Take off in the hand man.", 0.6)], snapper)
    assert rec.heard == "Take off in the hand man." and rec.commands == []
    assert rec.confidence == pytest.approx(0.6 * 0.83)


def test_window_and_beams_settings_are_checked_and_reach_the_recogniser() -> None:
    from server.settings import Settings, SettingsError
    from server.speech.service import SpeechConfig, SpeechService

    with pytest.raises(SettingsError, match=r"asr_window_s must be 0 \(default\) or 1 to 30"):
        Settings.from_env({"UAVC_ASR_WINDOW_S": "45"})
    with pytest.raises(SettingsError, match=r"asr_beams must be 0 \(default\) or 1 to 16"):
        Settings(asr_beams=17)
    s = Settings.from_env({"UAVC_ASR_WINDOW_S": "30", "UAVC_ASR_BEAMS": "1"})
    nlu = default_nlu()
    chosen = SpeechService(SpeechConfig(window_s=s.asr_window_s, beams=s.asr_beams), nlu).load()
    assert (chosen.window_s, chosen.beams) == (30.0, 1)
    default = SpeechService(SpeechConfig(), nlu).load()
    assert (default.window_s, default.beams) == (15.0, BEAMS)
