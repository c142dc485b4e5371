"""Hypothesis on the tolerant MCAP reader: any bytes read or raise CorruptRecording; and what
bench/fuzz.py's MCAP target found (issue 14), each now a test."""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

import pytest
import zstandard
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.writer import CompressionType, Writer

from server import msgs
from server.recorder.channels import format_for
from server.recorder.errors import CorruptRecording
from server.recorder.mcapfile import MAGIC, FlightFile, read_recording

from .conftest import NAVDATA, navdata


@pytest.fixture(scope="module")
def valid(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    path = tmp_path_factory.mktemp("fuzz") / "f.mcap"
    f = FlightFile(path, "f", 1, chunk_size=400)
    for i in range(30):
        f.write("/ardrone/navdata", NAVDATA, 10 + i, navdata(3, float(i)))
        f.write("/x", "vendor/Thing", 10 + i, {"i": i})
    f.finish(100, ["uav1"])
    return path.read_bytes()


def _read(tmp_path: Path, data: bytes, strict: bool) -> None:
    path = tmp_path / "in.mcap"
    path.write_bytes(data)
    try:
        rec = read_recording(path, strict=strict)
        list(rec.decoded())
    except CorruptRecording as exc:
        assert 0 <= exc.offset <= len(data)


SETTINGS = settings(
    max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)


@SETTINGS
@given(blob=st.binary(max_size=300), prefixed=st.booleans(), strict=st.booleans())
def test_arbitrary_bytes(tmp_path: Path, blob: bytes, prefixed: bool, strict: bool) -> None:
    _read(tmp_path, (MAGIC if prefixed else b"") + blob, strict)


@SETTINGS
@given(data=st.data(), strict=st.booleans())
def test_cut_and_flipped_recordings(
    tmp_path: Path, valid: bytes, data: st.DataObject, strict: bool
) -> None:
    blob = bytearray(valid[: data.draw(st.integers(0, len(valid)))])
    for _ in range(data.draw(st.integers(0, 3))):
        if blob:
            at = data.draw(st.integers(0, len(blob) - 1))
            blob[at] ^= data.draw(st.integers(1, 255))
    _read(tmp_path, bytes(blob), strict)


def test_a_chunk_claiming_an_absurd_size_is_corrupt_not_a_crash(
    tmp_path: Path, valid: bytes
) -> None:
    """Found by Hypothesis: a flipped byte in a chunk's uncompressed size (≥ 2^63) made
    zstandard raise OverflowError out of the reader."""
    at = 8  # walk the records (opcode u8, length u64, body) to the first chunk (0x06)
    while valid[at] != 0x06:
        at += 9 + int.from_bytes(valid[at + 1 : at + 9], "little")
    size_at = at + 1 + 8 + 16  # message start and end times (u64 each), then uncompressed size
    for claimed in (2**63 + 444, 300 << 20):
        blob = bytearray(valid)
        blob[size_at : size_at + 8] = claimed.to_bytes(8, "little")
        path = tmp_path / "big.mcap"
        path.write_bytes(bytes(blob))
        with pytest.raises(CorruptRecording, match="uncompressed") as info:
            read_recording(path, strict=False)
        assert info.value.offset == at


def _first_chunk(blob: bytes) -> int:
    at = 8  # walk the records (opcode u8, length u64, body) to the first chunk (0x06)
    while blob[at] != 0x06:
        at += 9 + int.from_bytes(blob[at + 1 : at + 9], "little")
    return at


def test_a_zstd_frame_declaring_exabytes_is_corrupt_not_a_memory_error(
    tmp_path: Path, valid: bytes
) -> None:
    """Found by bench/fuzz.py: a flipped bit in the zstd frame header (not the chunk's own
    size, which is checked) declared 2^62 bytes of content; zstandard tried to allocate them
    and raised MemoryError out of the reader."""
    at = _first_chunk(valid)
    body = at + 9
    records_at = body + 8 + 8 + 8 + 4  # start, end, uncompressed size, uncompressed CRC
    compression_len = int.from_bytes(valid[records_at : records_at + 4], "little")
    data_at = records_at + 4 + compression_len + 8  # compression string, then records length
    frame = valid[data_at:]
    assert zstandard.frame_content_size(frame) > 0  # our writer declares the size
    descriptor = frame[4]
    blob = bytearray(valid)
    blob[data_at + 4] = descriptor | 0xC0  # an 8-byte content size field…
    blob[data_at + 5 : data_at + 13] = (6402612339479479486).to_bytes(8, "little")  # …that big
    path = tmp_path / "bomb.mcap"
    path.write_bytes(bytes(blob))
    with pytest.raises(CorruptRecording, match="zstd frame declares") as info:
        read_recording(path, strict=False)
    assert info.value.offset == at


def _plain_recording(
    path: Path,
    channels: list[tuple[str, str, str, bytes, str, list[bytes]]],
    compression: CompressionType = CompressionType.NONE,
) -> Path:
    """An MCAP file as another tool may write it: (topic, schema name, schema encoding, schema
    data, message encoding, messages) per channel."""
    out = io.BytesIO()
    w = Writer(out, compression=compression)
    w.start()
    t = 10
    for topic, name, schema_encoding, schema_data, encoding, messages in channels:
        schema = w.register_schema(name, schema_encoding, schema_data)
        channel = w.register_channel(topic, encoding, schema)
        for data in messages:
            w.add_message(channel, t, data, t)
            t += 1
    w.finish()
    path.write_bytes(out.getvalue())
    return path


def _ros1(type_name: str, msg: dict[str, Any]) -> tuple[str, str, bytes, str, bytes]:
    fmt = format_for(type_name)
    return (
        fmt.schema_name,
        fmt.schema_encoding,
        fmt.schema_data,
        fmt.message_encoding,
        fmt.encode(msg),
    )


def test_a_channel_this_version_cannot_decode_is_corrupt_not_a_value_error(
    tmp_path: Path,
) -> None:
    """Found by bench/fuzz.py: ``Recording.decoded`` (what replay calls) let the ValueError of
    an unknown encoding or a changed ROS 1 definition out. A channel nothing was recorded on
    no longer matters at all."""
    name, enc, schema, msg_enc, data = _ros1(
        "geometry_msgs/Twist", msgs.default_message("geometry_msgs/Twist")
    )
    for bad in [
        ("/a", name, enc, schema.replace(b"float64 x", b"float32 x"), msg_enc, [data]),
        ("/b", "vendor/Thing", "protobuf", b"\x0a\x00", "protobuf", [b"\x08\x01"]),
    ]:
        path = _plain_recording(tmp_path / "bad.mcap", [bad])
        rec = read_recording(path)
        with pytest.raises(CorruptRecording, match=f"message 0 on {bad[0]}"):
            list(rec.decoded())
        path.unlink()
    unused = ("/b", "vendor/Thing", "protobuf", b"", "protobuf", [])
    path = _plain_recording(
        tmp_path / "ok.mcap", [unused, ("/a", name, enc, schema, msg_enc, [data])]
    )
    assert [(c.topic, m) for c, _, m in read_recording(path).decoded()] == [
        ("/a", msgs.default_message("geometry_msgs/Twist"))
    ]


def test_a_json_message_nested_too_deeply_is_corrupt_not_a_recursion_error(
    tmp_path: Path,
) -> None:
    fmt = format_for("vendor/Thing")
    deep = b"[" * 100_000 + b"]" * 100_000
    channel = ("/x", fmt.schema_name, fmt.schema_encoding, fmt.schema_data, fmt.message_encoding)
    path = _plain_recording(tmp_path / "deep.mcap", [(*channel, [b'{"a": 1}', deep])])
    with pytest.raises(CorruptRecording, match="message 1 on /x: a JSON message nested too"):
        list(read_recording(path).decoded())


def test_lz4_chunks_read_and_never_beyond_their_claimed_size(tmp_path: Path) -> None:
    """Another tool's lz4 chunks read; one that decompresses to more than its chunk says is
    corrupt (mcap's own reader decompresses lz4 with no bound at all)."""
    name, enc, schema, msg_enc, data = _ros1("std_msgs/String", {"data": "x" * 5000})
    path = _plain_recording(
        tmp_path / "lz4.mcap", [("/s", name, enc, schema, msg_enc, [data])], CompressionType.LZ4
    )
    assert [m["data"] for _, _, m in read_recording(path).decoded()] == ["x" * 5000]
    blob = bytearray(path.read_bytes())
    size_at = _first_chunk(blob) + 9 + 16
    size = int.from_bytes(blob[size_at : size_at + 8], "little")
    blob[size_at : size_at + 8] = (size - 1000).to_bytes(8, "little")
    path.write_bytes(bytes(blob))
    with pytest.raises(CorruptRecording, match="does not end within"):
        read_recording(path)
