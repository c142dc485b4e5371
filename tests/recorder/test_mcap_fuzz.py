"""Hypothesis on the tolerant MCAP reader: any bytes read or raise CorruptRecording."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

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
