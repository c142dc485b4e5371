"""Every operator input is in the flight recording, whatever its door, beside its reply.

A real ``serve`` (each drone in its own vehicle process, as by default) records a flight
commanded through REST (``POST /command``, with and without a stated confidence), speech
(``POST /speech``, a WAV spoken by espeak-ng and recognised by the bundled Whisper) and
rosbridge (a page's typed text, and a client that says no source). The downloaded MCAP, read
with the ``mcap`` library, holds each sentence once on ``/console/utterance`` with its source
and confidence, in the order said, each followed by exactly one reply to it on
``/console/reply``: the copy a REST door publishes is a record, no dialog acts on it again.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
import roslibpy
from mcap.reader import make_reader

from server.ros1 import codec_for
from tests.e2e.served import serve
from tests.speech.conftest import HAVE_TTS, synthesise
from tests.support.loopback import fresh_address
from tests.support.polling import wait_for

TOKEN = "utterance-pilot"


def _said(ros: roslibpy.Ros, replies: list[dict[str, Any]], msg: dict[str, Any]) -> None:
    """Publish an utterance over rosbridge and wait for its reply."""
    roslibpy.Topic(ros, "/console/utterance", "uav_console/Utterance").publish(
        roslibpy.Message(msg)
    )
    wait_for(lambda: [r["utterance"] for r in replies], lambda u: msg["text"] in u, 15, msg["text"])


@pytest.mark.timeout(240)
def test_a_recording_holds_every_input_with_source_and_confidence(tmp_path: Path) -> None:
    if not HAVE_TTS:
        pytest.skip("espeak-ng and sox are needed (.ci/run installs them)")
    wav = synthesise(tmp_path / "battery.wav", "how much battery is left").read_bytes()
    env = {
        "UAVC_SIM_BASE_ADDR": fresh_address(),
        "UAVC_RECORDER_IDLE_S": "2",
        "UAVC_RECORDER_CHUNK_S": "0.5",
        "UAVC_VEHICLES": "process",
    }
    with serve([], tmp_path, token=TOKEN, env=env) as srv:
        ros = roslibpy.Ros(srv.ws)
        ros.run(timeout=10)
        replies: list[dict[str, Any]] = []
        listener = roslibpy.Topic(ros, "/console/reply", "uav_console/Reply")
        listener.subscribe(replies.append)
        try:
            assert srv.say("take off")["accepted"]  # REST, no confidence: source rest
            srv.wait_truth(lambda t: t["flying"] and t["z"] > 0.5, 30, "airborne")
            # the page's typed text, then a client that says neither source nor confidence
            _said(ros, replies, {"text": "how high are you", "confidence": 1.0, "source": "text"})
            _said(ros, replies, {"text": "what is your battery"})
            wait_for(
                lambda: srv.http.get("/api/v1/speech/status").json()["status"],
                lambda st: st == "ready",
                120,
                "the speech model",
            )
            spoken = srv.http.post(
                "/api/v1/speech",
                content=wav,
                headers={"Content-Type": "audio/wav"},
                params={"take_over": "true"},  # the rosbridge connection holds the lease now
            ).json()
            assert spoken.get("reply", "").startswith("Battery is at"), spoken
            said = srv.say("land", confidence=0.93)  # REST with a confidence: recognised speech
            assert said["accepted"], said
            srv.wait_truth(lambda t: not t["flying"] and t["z"] < 0.05, 30, "landed")
            flights = wait_for(
                lambda: srv.http.get("/api/v1/flights").json()["flights"],
                lambda f: len(f) == 1 and f[0]["ended"] is not None,
                30,
                "the recording to end after landing",
            )
        finally:
            ros.close()
        path = tmp_path / "flight.mcap"
        path.write_bytes(srv.http.get(f"/api/v1/flights/{flights[0]['id']}").content)

    events: list[tuple[str, dict[str, Any]]] = []
    with path.open("rb") as f:
        reader = make_reader(f)
        for schema, channel, message in reader.iter_messages(
            topics=["/console/utterance", "/console/reply"], log_time_order=True
        ):
            assert schema is not None and channel.message_encoding == "ros1"
            events.append((channel.topic, codec_for(schema.name).decode(message.data)))
    heard = [
        (m["text"], m["source"], round(m["confidence"], 4), m["answered"])
        for topic, m in events
        if topic == "/console/utterance"
    ]
    assert heard == [
        ("take off", "rest", 1.0, True),
        ("how high are you", "text", 1.0, False),
        ("what is your battery", "rosbridge", 0.0, False),
        (spoken["text"], "speech", spoken["confidence"], True),
        ("land", "speech", 0.93, True),
    ], heard
    # each sentence, then its one reply (nothing answered twice), in the order said
    for text, *_ in heard:
        at = [i for i, (t, m) in enumerate(events) if m.get("text") == text and t.endswith("ance")]
        answers = [i for i, (t, m) in enumerate(events) if m.get("utterance") == text]
        assert len(at) == 1 and len(answers) == 1 and answers[0] > at[0], (text, events)
    replies_said = [m["text"] for t, m in events if t == "/console/reply" and m["utterance"]]
    assert replies_said[0] == "Taking off." and replies_said[-1] == "Landing."
    assert json.loads(next(m["commands"] for t, m in events if m.get("utterance") == "land")) == [
        {"action": "land"}
    ]
