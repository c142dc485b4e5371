"""Fuzz campaign over every parser of untrusted input; a benchmark, not a test.

    .venv/bin/python bench/fuzz.py               # 100 000 inputs per parser (the target)
    .venv/bin/python bench/fuzz.py --n 5000      # a quick pass
    .venv/bin/python bench/fuzz.py --only navdata --seed 7

Each target gets seeded, deterministic inputs: mutations of valid examples (bit flips, byte
replacement, insertion and in-place replacement of "interesting" tokens such as float32 NaN
and infinities, deletion, truncation, duplication, splicing of two examples) and, for one
input in eight, plain random bytes. An input **crashes** a parser when it raises anything but
the parser's documented errors, or (for the rosbridge protocol, which never raises) when it
reaches the defensive "frame could not be handled" branch, which exists to catch bugs. The
table gives per parser: inputs, accepted, rejected (documented error), crashes, the median
time per input and the slowest input (its time, the best of five re-runs of it — a slow input
that re-runs fast was the machine's load, not the input — and a ``repr``). Every crash is
written to ``--crash-dir`` (default ``$TMPDIR/uavc-fuzz-crashes/``) and becomes a test.

The targets: rosbridge JSON, CBOR and PNG frames, AT commands, navdata, PaVE video, XML
grammars, REST bodies, the MAVLink downlink (bytes from a vehicle up to the snapshot the fleet
reads), speech input (WAV bodies and the stream's PCM frames) and MCAP flight recordings (read
and decoded as replay does). A checksum anyone can compute would stop nearly every mutation
before the code behind it, so the MAVLink target recomputes frame CRCs for half its inputs
and the MCAP target has a seed whose chunks carry no CRC (both legal in their formats).

Adding a parser: define a :class:`Target` — a name, a few valid ``seeds`` (bytes) made by our
own writers and encoders, ``run(data)`` that parses one input, and ``errors`` (the exception
types its docstring documents) — and append it in :func:`targets`. Nothing else changes.
"""

from __future__ import annotations

import argparse
import base64
import contextlib
import json
import random
import statistics
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import cbor2
from pydantic import BaseModel, ValidationError

INTERESTING = [
    b"",
    b"\x00",
    b"\xff",
    b"\xff\xff\xff\xff",
    b"\x7f\xff\xff\xff",
    b"\x80\x00\x00\x00",
    b"-1",
    b"0",
    b"1e308",
    b"-1e308",
    b"NaN",
    b"Infinity",
    b"9223372036854775808",
    b"\\ud800",
    b'"',
    b"{",
    b"}",
    b"[",
    b"]",
    b",",
    b":",
    b"null",
    b"true",
    b"<",
    b">",
    b"&",
    b"<!DOCTYPE x [<!ENTITY a 'b'>]>",
    b"\r",
    b"\n",
    b"AT*REF=",
    b"PaVE",
    b"\x88\x77\x66\x55",
    b"(" * 50,
    b"*" * 20,
    b"\x00\x00\x80\x7f",  # float32 +inf, little-endian (MAVLink, navdata)
    b"\x00\x00\xc0\x7f",  # float32 NaN
    b"\x00\x00\x80\xff",  # float32 -inf
]


@dataclass
class Target:
    """One parser under fuzz: valid ``seeds``, ``run`` parses one input, ``errors`` are the
    exceptions it documents (anything else is a crash). ``crashed`` may flag a crash the
    parser swallowed (e.g. a defensive catch-all)."""

    name: str
    seeds: list[bytes]
    run: Callable[[bytes], object]
    errors: tuple[type[BaseException], ...] = ()
    crashed: Callable[[object], str | None] = lambda _result: None


@dataclass
class Result:
    name: str
    inputs: int = 0
    accepted: int = 0
    rejected: int = 0
    crashes: list[tuple[bytes, str]] = field(default_factory=list)
    times_us: list[float] = field(default_factory=list)
    slowest: tuple[float, bytes] = (0.0, b"")
    slowest_rerun_us: float = 0.0  # the slowest input timed again (best of 5): load or input?


def mutate(rng: random.Random, seeds: list[bytes]) -> bytes:
    """One fuzz input from ``seeds`` (see the module docstring)."""
    if rng.random() < 0.125:
        return rng.randbytes(rng.randrange(0, 256))
    data = bytearray(rng.choice(seeds))
    for _ in range(rng.choice((1, 1, 2, 3, 5, 8))):
        kind = rng.randrange(8)
        pos = rng.randrange(len(data) + 1)
        if kind == 0 and data:  # flip bits
            i = min(pos, len(data) - 1)
            data[i] ^= 1 << rng.randrange(8)
        elif kind == 1 and data:  # random byte
            data[min(pos, len(data) - 1)] = rng.randrange(256)
        elif kind == 2:  # insert an interesting token
            data[pos:pos] = rng.choice(INTERESTING)
        elif kind == 3 and data:  # delete a run
            del data[pos : pos + rng.randrange(1, 16)]
        elif kind == 4:  # truncate
            del data[pos:]
        elif kind == 7 and data:  # replace bytes with an interesting token (lengths kept)
            token = rng.choice(INTERESTING)
            data[pos : pos + len(token)] = token
        elif kind == 5 and data:  # duplicate a run
            end = min(len(data), pos + rng.randrange(1, 64))
            data[pos:pos] = data[pos:end] * rng.randrange(1, 4)
        else:  # splice with another seed
            other = rng.choice(seeds)
            cut = rng.randrange(len(other) + 1)
            data = data[:pos] + bytearray(other[cut:])
    return bytes(data)


def fuzz(target: Target, n: int, seed: int) -> Result:
    rng = random.Random(f"{seed}:{target.name}")
    res = Result(target.name)
    for data in _inputs(rng, target, n):
        t0 = time.perf_counter()
        try:
            out = target.run(data)
        except target.errors:
            res.rejected += 1
        except Exception as exc:  # a crash: anything undocumented
            res.crashes.append((data, f"{type(exc).__name__}: {exc}"[:200]))
        else:
            why = target.crashed(out)
            if why is not None:
                res.crashes.append((data, why[:200]))
            else:
                res.accepted += 1
        dt = (time.perf_counter() - t0) * 1e6
        res.inputs += 1
        res.times_us.append(dt)
        if dt > res.slowest[0]:
            res.slowest = (dt, data)
    res.slowest_rerun_us = min(_time_once(target, res.slowest[1]) for _ in range(5))
    return res


def _time_once(target: Target, data: bytes) -> float:
    t0 = time.perf_counter()
    with contextlib.suppress(Exception):
        target.run(data)
    return (time.perf_counter() - t0) * 1e6


def _inputs(rng: random.Random, target: Target, n: int) -> Iterator[bytes]:
    yield from target.seeds  # the valid examples themselves first
    for _ in range(n - len(target.seeds)):
        yield mutate(rng, target.seeds)


# -- targets -------------------------------------------------------------------------------
def _rosbridge_targets() -> list[Target]:
    from server.rosbridge.encode import png_frame
    from server.rosbridge.protocol import BridgeProtocol

    frames = [
        {"op": "auth", "token": "abc"},
        {"op": "subscribe", "id": "s1", "topic": "/ardrone/navdata", "throttle_rate": 100},
        {"op": "subscribe", "topic": "/a", "type": "std_msgs/String", "queue_length": 2},
        {"op": "publish", "topic": "/cmd_vel", "msg": {"linear": {"x": 0.1}, "angular": {}}},
        {"op": "advertise", "topic": "/t", "type": "geometry_msgs/Twist", "latch": True},
        {"op": "call_service", "id": "c", "service": "/rosapi/topics", "args": {}, "timeout": 2},
        {"op": "service_response", "id": "service_request:/x:1", "values": {}, "result": True},
        {"op": "fragment", "id": "f", "data": '{"op":', "num": 0, "total": 2},
        {"op": "set_level", "level": "warning"},
        {"op": "unsubscribe", "topic": "/a", "id": "s1"},
    ]
    texts = [json.dumps(f).encode() for f in frames]
    texts.append(png_frame(json.dumps(frames[1])).encode())

    def crashed(out: object) -> str | None:
        proto = out
        assert isinstance(proto, BridgeProtocol)
        for frame in proto.frames_to_send():
            if isinstance(frame, str) and "could not be handled" in frame:
                return str(json.loads(frame)["msg"])
        return None

    def run_text(data: bytes) -> BridgeProtocol:
        proto = BridgeProtocol(max_frame_bytes=1 << 20)
        proto.receive_text(data.decode("utf-8", "surrogateescape"), 0.0)
        return proto

    def run_cbor(data: bytes) -> BridgeProtocol:
        proto = BridgeProtocol(max_frame_bytes=1 << 20)
        proto.receive_bytes(data, 0.0)
        return proto

    return [
        Target("rosbridge JSON", texts, run_text, crashed=crashed),
        Target("rosbridge CBOR", [cbor2.dumps(f) for f in frames], run_cbor, crashed=crashed),
    ]


def _png_target() -> Target:
    from server.rosbridge.encode import png_decode, png_encode

    seeds = [
        png_encode('{"op":"publish","topic":"/a","msg":{"data":"' + "x" * k + '"}}')
        for k in (1, 50, 900)
    ]
    return Target("rosbridge PNG", seeds, lambda d: png_decode(d, 1 << 20), (ValueError,))


def _ardrone_targets() -> list[Target]:
    from drone.ardrone.at import Config, Ctrl, Pcmd, Ref, encode_command, parse_at
    from drone.ardrone.errors import ATParseError, NavdataError, VideoError
    from drone.ardrone.navdata import Demo, DroneState, Navdata, decode_navdata, encode_navdata
    from drone.ardrone.video import PaVEParser, encode_pave

    at_seeds = [
        encode_command(Ref.takeoff(), 1),
        encode_command(Pcmd(1, 0.1, -0.2, 0.3, 0.0), 7) + encode_command(Ref.land(), 8),
        encode_command(Config("general:navdata_demo", "TRUE"), 3),
        encode_command(Ctrl(5, 0), 4),
    ]
    nav_seeds = [
        encode_navdata(Navdata(state=DroneState(0x800), sequence=1)),
        encode_navdata(
            Navdata(state=DroneState(1), sequence=99, demo=Demo(ctrl_state=3 << 16, battery_pct=80))
        ),
    ]
    pave_seeds = [
        encode_pave(b"\x00\x00\x00\x01\x67" + b"\x11" * 40, frame_number=1, timestamp_ms=5),
        encode_pave(b"\x00\x00\x00\x01\x41" + b"\x22" * 200, frame_number=2, timestamp_ms=9),
    ]

    def run_pave(data: bytes) -> object:
        parser = PaVEParser(max_payload=1 << 20)
        half = len(data) // 2  # in two reads, as TCP may deliver it
        return parser.feed(data[:half]) + parser.feed(data[half:])

    return [
        Target("AT commands", at_seeds, parse_at, (ATParseError,)),
        Target("navdata", nav_seeds, decode_navdata, (NavdataError,)),
        Target("PaVE video", pave_seeds, run_pave, (VideoError,)),
    ]


def _grammar_target(workdir: Path) -> Target:
    from server.language.errors import GrammarError
    from server.language.grammar import load_grammar

    rules = (
        '<?xml version="1.0"?><rules><grammar name="g">'
        '<rule id="up" action="move" priority="5"><const name="direction" value="up"/>'
        "<pattern><![CDATA[go {DIRECTION} (?P<distance>\\d+) meters?]]></pattern></rule>"
        '<rule id="l" action="land"><pattern>land|come down</pattern></rule>'
        "</grammar></rules>"
    )
    states = '<states><state name="LANDED" refuse="No."><grammar ref="g"/></state></states>'
    mappings = (
        '<mappings><set name="DIRECTION"><item label="up">up, roof</item>'
        '<item label="down">down</item></set></mappings>'
    )
    files = {"rules.xml": rules, "states.xml": states, "mappings.xml": mappings}
    for name, text in files.items():
        (workdir / name).write_text(text)
    order = list(files)
    seeds = [f"{i}".encode() + text.encode() for i, text in enumerate(files.values())]

    def run(data: bytes) -> object:
        # The first byte picks the file this input replaces; the others stay valid.
        which = order[data[0] % 3] if data else order[0]
        for name, text in files.items():
            (workdir / name).write_bytes(data[1:] if name == which else text.encode())
        return load_grammar(workdir)

    return Target("XML grammars", seeds, run, (GrammarError,))


def _rest_targets() -> list[Target]:
    from server.api.models import CommandRequest, FaultRequest, InterpretRequest
    from server.fleet.messages import MissionRequest

    bodies: list[tuple[type[BaseModel], list[bytes]]] = [
        (CommandRequest, [b'{"text": "take off and fly to marker 3", "confidence": 0.9}']),
        (InterpretRequest, [b'{"text": "go up two meters", "state": "FLYING"}']),
        (
            FaultRequest,
            [b'{"kind": "wind", "wind_mps": [1.5, -2]}', b'{"kind": "battery", "battery_pct": 20}'],
        ),
        (
            MissionRequest,
            [
                b'{"markers": [1, 4, 7], "altitude_m": 1.4, "name": "loop-1"}',
                b'{"waypoints": [{"lat": 47.1, "lon": 8.5}], "loop": false}',
            ],
        ),
    ]
    seeds = [bytes([i]) + b for i, (_, bs) in enumerate(bodies) for b in bs]

    def run(data: bytes) -> object:
        # What FastAPI does with a JSON body: json.loads (which accepts NaN), then the model.
        model = bodies[data[0] % len(bodies)][0] if data else CommandRequest
        obj = json.loads(data[1:].decode("utf-8"))
        validated = model.model_validate(obj)
        validated.model_dump_json()  # the response/audit must be able to carry it
        return validated

    return [Target("REST bodies", seeds, run, (ValidationError, ValueError))]


# A fixed signing key and timestamp (10 µs units since 2015): seeds and runs are deterministic.
MAVLINK_KEY = bytes(range(32))
MAVLINK_T0 = 3_000_000_000


def _mavlink_fix_crcs(data: bytearray) -> None:
    """Recompute the CRC of every MAVLink 2 frame in ``data`` of a message the dialect knows,
    as anyone on the link can: the CRC is no authentication, so a fuzzer that left it wrong
    would only ever test pymavlink's CRC check, never our handling of the decoded fields."""
    from drone.mavlink.codec import MAGIC_V2, mav

    i = 0
    while i + 12 <= len(data):
        if data[i] != MAGIC_V2:
            i += 1
            continue
        length, incompat = data[i + 1], data[i + 2]
        msg_id = int.from_bytes(data[i + 7 : i + 10], "little")
        end = i + 10 + length
        msg_type = mav.mavlink_map.get(msg_id)
        if msg_type is None or end + 2 > len(data):
            i += 1
            continue
        crc = mav.x25crc(bytes(data[i + 1 : end]) + bytes([msg_type.crc_extra]))
        data[end : end + 2] = crc.crc.to_bytes(2, "little")
        i = end + 2 + (13 if incompat & 1 else 0)


def _mavlink_target() -> Target:
    """The console's MAVLink downlink: bytes from a vehicle through ``Codec`` (pymavlink's
    parser, MAVLink 2 only, signing) and ``GcsProtocol`` (discovery, telemetry, STATUSTEXT
    chunks, command and mission answers) to the ``MavlinkVehicle`` snapshot the fleet reads.

    The first byte picks the link: bit 0 signed (``MAVLINK_KEY``), bit 1 CRCs recomputed after
    mutation (:func:`_mavlink_fix_crcs`). Each run starts from a vehicle already discovered (a
    valid heartbeat first), so the input reaches the telemetry and command handling. The
    documented contract: ``receive`` never raises (bad frames are counted in
    ``codec.rejected``), and a snapshot holds finite numbers (the fleet needs them)."""
    import math
    from types import SimpleNamespace

    from drone.control.clock import VirtualClock
    from drone.mavlink.codec import Codec, Message
    from drone.mavlink.gcs.protocol import GcsProtocol
    from drone.mavlink.vehicle import MavlinkVehicle

    world = SimpleNamespace(gps_origin=SimpleNamespace(lat_deg=47.397, lon_deg=8.545, alt_m=488.0))
    px4, quad = 12, 2  # MAV_AUTOPILOT_PX4, MAV_TYPE_QUADROTOR

    def stream(codec: Codec, group: int) -> bytes:
        m = codec.mav
        msgs: list[list[Message]] = [
            [  # telemetry
                m.heartbeat_encode(quad, px4, 0x81, 6 << 16, 4),
                m.global_position_int_encode(
                    1000, 473971000, 85451000, 490500, 2500, 120, -40, 5, 9000
                ),
                m.local_position_ned_encode(1000, 1.5, -2.0, -2.5, 1.2, -0.4, 0.05),
                m.attitude_encode(1000, 0.01, -0.02, 1.57, 0.0, 0.0, 0.1),
                m.sys_status_encode(0x2F, 0x2F, 0x2F, 300, 12100, 850, 76, 0, 0, 0, 0, 0, 0),
                m.battery_status_encode(0, 3, 1, 3000, [4000] * 10, 850, 1200, 1300, 75),
                m.extended_sys_state_encode(0, 2),
                m.gps_raw_int_encode(1000, 3, 473970000, 85450000, 490500, 90, 120, 130, 9000, 12),
                m.home_position_encode(
                    473960000, 85440000, 488000, 0.0, 0.0, 0.0, [1, 0, 0, 0], 0, 0, 0
                ),
            ],
            [  # commands, parameters, texts
                m.command_ack_encode(400, 0),
                m.command_ack_encode(22, 5, 40),
                m.statustext_encode(
                    3, b"Preflight Fail: Accel Sensor 0 missing; check the w", 7, 0
                ),
                m.statustext_encode(3, b"iring", 7, 1),
                m.statustext_encode(6, b"Takeoff detected"),
                m.param_value_encode(b"NAV_DLL_ACT", 2.0, 6, 900, 1),
                m.param_value_encode(b"COM_DL_LOSS_T", 10.0, 9, 900, 2),
            ],
            [  # mission
                m.mission_request_int_encode(255, 190, 0),
                m.mission_request_encode(255, 190, 1),
                m.mission_current_encode(1),
                m.mission_item_reached_encode(0),
                m.mission_ack_encode(255, 190, 0),
                m.heartbeat_encode(quad, px4, 0x81, (4 << 16) | (4 << 24), 4),
            ],
        ]
        return b"".join(codec.encode(msg) for msg in msgs[group])

    def codec(signed: bool) -> Codec:
        key = MAVLINK_KEY if signed else None
        return Codec(1, 1, signing_key=key, initial_timestamp=MAVLINK_T0)

    def first_heartbeat(vehicle: Codec) -> bytes:
        return vehicle.encode(vehicle.mav.heartbeat_encode(quad, px4, 0x81, 0, 3))

    hello = {signed: first_heartbeat(codec(signed)) for signed in (False, True)}
    seeds = []
    for link in range(4):
        vehicle_codec = codec(bool(link & 1))
        first_heartbeat(vehicle_codec)  # = hello: the seeds' signing timestamps come after it
        for group in range(3):
            seeds.append(bytes([link]) + stream(vehicle_codec, group))

    def run(data: bytes) -> MavlinkVehicle:
        link = data[0] if data else 0
        signed = bool(link & 1)
        body = bytearray(data[1:])
        if link & 2:
            _mavlink_fix_crcs(body)
        protocol = GcsProtocol(signing_key=MAVLINK_KEY if signed else None)
        protocol.codec.mav.signing.timestamp = MAVLINK_T0
        clock = VirtualClock(1.0)
        vehicle = MavlinkVehicle("uav1", world, protocol, clock=clock)
        protocol.receive(hello[signed], 1.0)
        protocol.upload_mission([(47.3971, 8.5451, 5.0), (47.3972, 8.5452, 5.0)], 1.0)
        half = len(body) // 2  # in two reads, as TCP may deliver it
        for part, now in ((body[:half], 1.1), (body[half:], 1.2)):
            clock.set(now)
            protocol.receive(bytes(part), now)
            for event in protocol.events():
                vehicle.on_event(event)
        protocol.tick(1.3)
        vehicle.snapshot()
        return vehicle

    def crashed(out: object) -> str | None:
        assert isinstance(out, MavlinkVehicle)
        snap = out.snapshot()
        numbers = {
            k: getattr(snap, k)
            for k in ("battery_pct", "altitude_m", "x", "y", "z", "yaw_rad", "vx", "vy", "vz")
        }
        numbers["position_sigma_m"] = snap.position_sigma_m
        bad = {k: v for k, v in numbers.items() if not math.isfinite(v)}
        return f"snapshot holds non-finite numbers: {bad}" if bad else None

    return Target("MAVLink", seeds, run, crashed=crashed)


def _wav_target() -> Target:
    """Speech input (``server.speech``): the first byte picks a WAV body for REST
    ``POST /api/v1/speech`` (``audio.read_wav``, documented errors: ``AudioError``), PCM
    frames of the browser stream (``audio.pcm16_to_float`` through a push-to-talk
    ``StreamSession``: never raises) or one of the stream's text frames
    (``stream.control_kind``: never raises)."""
    import io
    import wave

    import numpy as np

    from server.speech.audio import read_wav, to_wav
    from server.speech.errors import AudioError
    from server.speech.stream import StreamSession, control_kind

    t = np.arange(160) / 16_000
    tone = (0.5 * np.sin(2 * np.pi * 440.0 * t)).astype(np.float32)
    buf = io.BytesIO()
    with wave.open(buf, "wb") as w:  # stereo: to_wav writes mono only
        w.setnchannels(2)
        w.setsampwidth(2)
        w.setframerate(44_100)
        w.writeframes(np.repeat((tone * 20000).astype("<i2"), 2).tobytes())
    wavs = [to_wav(tone), to_wav(tone[:80], 8000), to_wav(tone, 48_000), buf.getvalue()]
    pcm = (tone * 20000).astype("<i2").tobytes()
    seeds = [b"\x00" + w for w in wavs] + [b"\x01" + pcm, b"\x01" + pcm[:33]]
    seeds += [b'\x02{"type": "end"}', b'\x02{"type":"cancel"}']

    def run(data: bytes) -> object:
        if not data or data[0] % 3 == 0:
            return read_wav(data[1:])
        if data[0] % 3 == 2:
            return control_kind(data[1:].decode("utf-8", "replace"))
        session = StreamSession("ptt", interim_step_s=0.004)
        half = len(data) // 2
        return session.feed(data[1:half]) + session.feed(data[half:]) + session.end()

    return Target("WAV / PCM / text", seeds, run, (AudioError,))


def _mcap_target(workdir: Path) -> Target:
    """Flight recordings (``server.recorder.mcapfile.read_recording``, tolerant, then every
    message decoded, as replay does); documented error: ``CorruptRecording``."""
    import io

    from mcap.writer import CompressionType, Writer

    from server import msgs
    from server.recorder.channels import format_for
    from server.recorder.errors import CorruptRecording
    from server.recorder.mcapfile import FlightFile, read_recording

    def recording(name: str, n: int, chunk_size: int, finish: bool) -> bytes:
        path = workdir / f"seed-{name}.mcap"
        f = FlightFile(path, name, 1, chunk_size=chunk_size)
        for i in range(n):
            nav = msgs.default_message("ardrone_autonomy/Navdata")
            nav["batteryPercent"] = 80.0 - i
            f.write("/ardrone/navdata", "ardrone_autonomy/Navdata", 10 + i, nav)
            f.write("/utterance", "vendor/Thing", 10 + i, {"text": f"go up {i}", "i": i})
            f.write(
                "/cmd_vel",
                "geometry_msgs/Twist",
                10 + i,
                msgs.default_message("geometry_msgs/Twist"),
            )
            f.flush()
        if finish:
            f.finish(100, ["uav1"])
        else:
            f.abandon()
        return path.read_bytes()

    def plain() -> bytes:
        # As another tool may write it: chunks neither compressed nor CRC-checked (the reader
        # accepts both), so mutations reach the records inside chunks, not only zstd's checks.
        out = io.BytesIO()
        w = Writer(out, chunk_size=300, compression=CompressionType.NONE, enable_crcs=False)
        w.start()
        for i, (topic, type_name, msg) in enumerate(
            [
                ("/cmd_vel", "geometry_msgs/Twist", msgs.default_message("geometry_msgs/Twist")),
                ("/utterance", "vendor/Thing", {"text": "land", "n": [1, 2.5, None]}),
                ("/rosout_agg", "std_msgs/String", {"data": "hello"}),
            ]
        ):
            fmt = format_for(type_name)
            schema = w.register_schema(fmt.schema_name, fmt.schema_encoding, fmt.schema_data)
            channel = w.register_channel(topic, fmt.message_encoding, schema)
            w.add_message(channel, 10 + i, fmt.encode(msg), 10 + i)
        w.finish()
        return out.getvalue()

    seeds = [
        recording("a", 1, 1 << 20, True),
        recording("b", 3, 200, True),
        recording("c", 2, 1 << 20, False),
        plain(),
    ]
    path = workdir / "in.mcap"

    def run(data: bytes) -> object:
        path.write_bytes(data)
        rec = read_recording(path, strict=False)
        return list(rec.decoded())

    return Target("MCAP recording", seeds, run, (CorruptRecording,))


def targets(workdir: Path) -> list[Target]:
    """Every fuzz target. Append new parsers here (see the module docstring)."""
    return [
        *_rosbridge_targets(),
        _png_target(),
        *_ardrone_targets(),
        _grammar_target(workdir),
        *_rest_targets(),
        _mavlink_target(),
        _wav_target(),
        _mcap_target(workdir),
    ]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=100_000, help="inputs per parser")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--only", help="run the targets whose name contains this")
    ap.add_argument("--quick", action="store_true", help="5000 inputs per parser")
    ap.add_argument(
        "--crash-dir", type=Path, default=Path(tempfile.gettempdir()) / "uavc-fuzz-crashes"
    )
    args = ap.parse_args(argv)
    n = 5000 if args.quick else args.n
    print(f"fuzz: {n} inputs per parser, seed {args.seed}")
    print(
        f"{'parser':<16} {'inputs':>8} {'accepted':>9} {'rejected':>9} {'crashes':>8} "
        f"{'median µs':>10} {'slowest µs':>11} {'re-run µs':>10}  slowest input"
    )
    total_crashes = 0
    with tempfile.TemporaryDirectory(prefix="uavc-fuzz-") as tmp:
        for target in targets(Path(tmp)):
            if args.only and args.only.lower() not in target.name.lower():
                continue
            res = fuzz(target, n, args.seed)
            total_crashes += len(res.crashes)
            shown = repr(res.slowest[1][:40]) + ("…" if len(res.slowest[1]) > 40 else "")
            print(
                f"{res.name:<16} {res.inputs:>8} {res.accepted:>9} {res.rejected:>9} "
                f"{len(res.crashes):>8} {statistics.median(res.times_us):>10.1f} "
                f"{res.slowest[0]:>11.0f} {res.slowest_rerun_us:>10.0f}  {shown}",
                flush=True,
            )
            for i, (data, why) in enumerate(res.crashes[:20]):
                args.crash_dir.mkdir(parents=True, exist_ok=True)
                slug = res.name.replace(" ", "_")
                (args.crash_dir / f"{slug}-{i}.bin").write_bytes(data)
                print(f"  crash {i}: {why}  input (base64) {base64.b64encode(data[:200]).decode()}")
    return 1 if total_crashes else 0


if __name__ == "__main__":
    raise SystemExit(main())
