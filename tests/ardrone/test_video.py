"""PaVE framing and H.264: golden bytes, Hypothesis round trips and fuzzing, codec round trip."""

from __future__ import annotations

import math
import struct

import cv2
import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from drone.ardrone.errors import VideoError
from drone.ardrone.video import (
    PAVE_HEADER_SIZE,
    FrameType,
    H264Decoder,
    H264Encoder,
    PaVEHeader,
    PaVEParser,
    VideoPacket,
    encode_pave,
)

# Worked out by hand from parrot_video_encapsulation_t (video_encapsulation.h), little-endian:
GOLDEN = bytes.fromhex(
    "50615645"  # signature "PaVE"
    "02"  # version (PAVE_CURRENT_VERSION)
    "04"  # video_codec CODEC_MPEG4_AVC
    "4000"  # header_size 64
    "03000000"  # payload_size 3
    "8002"
    "7001"  # encoded 640 x 368
    "8002"
    "6801"  # display 640 x 360
    "07000000"  # frame_number 7
    "d2040000"  # timestamp 1234 ms
    "01"
    "00"  # total_chunks 1, chunk_index 0
    "01"  # frame_type IDR
    "00"  # control
    "00000000"
    "00000000"  # stream_byte_position lw, uw
    "0100"  # stream_id 1 (H264_360p)
    "01"
    "00"  # total_slices 1, slice_index 0
    "00"
    "00"  # header1_size, header2_size
    "0000"  # reserved2
    "00000000"  # advertised_size
    + "00" * 12  # reserved3
    + "010203"  # payload
)


def test_golden_bytes() -> None:
    assert encode_pave(b"\x01\x02\x03", frame_number=7, timestamp_ms=1234, frame_type=1) == GOLDEN
    (pkt,) = PaVEParser().feed(GOLDEN)
    assert pkt.payload == b"\x01\x02\x03"
    h = pkt.header
    assert (h.version, h.video_codec, h.header_size, h.payload_size) == (2, 4, 64, 3)
    assert (h.encoded_width, h.encoded_height, h.display_width, h.display_height) == (
        640,
        368,
        640,
        360,
    )
    assert (h.frame_number, h.timestamp_ms, h.frame_type) == (7, 1234, FrameType.IDR)
    assert pkt.is_keyframe and pkt.to_bytes() == GOLDEN


def test_header_size_is_read_not_assumed() -> None:
    """A longer header (future version) and a 32-byte one (fields through ``control``)."""
    long = PaVEHeader(payload_size=2, header_size=76, frame_number=3).pack() + b"AB"
    assert len(long) == 78
    short = bytearray(GOLDEN[:32] + b"xyz")
    struct.pack_into("<H", short, 6, 32)
    p = PaVEParser()
    out = p.feed(long + bytes(short))
    assert [(q.header.header_size, q.payload) for q in out] == [(76, b"AB"), (32, b"xyz")]
    assert out[1].header.stream_id == 1  # beyond the short header: default
    assert p.bytes_skipped == 0 and p.buffered == 0


def test_stream_fed_byte_by_byte_and_garbage_resync() -> None:
    a = encode_pave(b"first", 1, 10, FrameType.IDR)
    b = encode_pave(b"second", 2, 20, FrameType.P)
    stream = b"\x00junk Pa" + a + b"more junk PaV" + b + b"trailing"
    p = PaVEParser()
    got: list[VideoPacket] = []
    for i in range(len(stream)):
        got += p.feed(stream[i : i + 1])
    assert [g.payload for g in got] == [b"first", b"second"]
    assert p.bytes_skipped == len(b"\x00junk Pa") + len(b"more junk PaV") + len(b"trailing")
    assert p.bad_headers == 0


@pytest.mark.parametrize(
    ("offset", "fmt", "value", "why"),
    [
        (6, "<H", 12, "header_size 12"),
        (6, "<H", 60000, "header_size 60000"),
        (8, "<I", 0xFFFFFFF0, "payload_size 4294967280 exceeds"),
    ],
)
def test_bad_header_skipped_or_raised(offset: int, fmt: str, value: int, why: str) -> None:
    bad = bytearray(encode_pave(b"bad!", 1, 0))
    struct.pack_into(fmt, bad, offset, value)
    good = encode_pave(b"good", 2, 0)
    p = PaVEParser()
    assert [q.payload for q in p.feed(bytes(bad) + good)] == [b"good"]
    assert p.bad_headers == 1
    strict = PaVEParser(strict=True)
    with pytest.raises(VideoError, match=why):
        strict.feed(bytes(bad) + good)
    # after the error the parser has moved past the bad signature and carries on
    assert [q.payload for q in strict.feed(b"")] == [b"good"]


def test_payload_limit_is_configurable() -> None:
    pkt = encode_pave(bytes(2000), 1, 0)
    assert PaVEParser(max_payload=4096).feed(pkt)[0].header.payload_size == 2000
    with pytest.raises(VideoError, match="exceeds the limit 1000"):
        PaVEParser(max_payload=1000, strict=True).feed(pkt)


def test_header_unpack_and_pack_errors() -> None:
    with pytest.raises(VideoError, match="signature"):
        PaVEHeader.unpack(b"PAVE" + GOLDEN[4:])
    with pytest.raises(VideoError, match="truncated"):
        PaVEHeader.unpack(GOLDEN[:8])
    with pytest.raises(VideoError, match="truncated"):
        PaVEHeader.unpack(GOLDEN[:40])
    with pytest.raises(VideoError, match="out of range"):
        PaVEHeader(payload_size=1, frame_type=300).pack()
    with pytest.raises(VideoError, match="cannot be written"):
        PaVEHeader(payload_size=1, header_size=40).pack()


# -------------------------------------------------------------------------- Hypothesis

u8 = st.integers(0, 255)
u16 = st.integers(0, 0xFFFF)
u32 = st.integers(0, 0xFFFFFFFF)

headers = st.builds(
    PaVEHeader,
    payload_size=st.just(0),
    frame_number=u32,
    timestamp_ms=u32,
    frame_type=st.integers(0, 4),
    version=u8,
    video_codec=u8,
    header_size=st.integers(PAVE_HEADER_SIZE, 200),
    encoded_width=u16,
    encoded_height=u16,
    display_width=u16,
    display_height=u16,
    total_chunks=u8,
    chunk_index=u8,
    control=u8,
    stream_byte_position=st.integers(0, 2**64 - 1),
    stream_id=u16,
    total_slices=u8,
    slice_index=u8,
    header1_size=u8,
    header2_size=u8,
    advertised_size=u32,
)


@settings(max_examples=200, deadline=None)
@given(
    st.lists(st.tuples(headers, st.binary(max_size=300)), min_size=1, max_size=5),
    st.binary(max_size=40),
    st.lists(st.integers(1, 97), min_size=1, max_size=20),
)
def test_encode_then_parse_is_identity(items, garbage, cuts) -> None:
    assume(b"PaVE" not in garbage and not garbage.endswith((b"P", b"Pa", b"PaV")))
    pkts = []
    for hdr, payload in items:
        full = PaVEHeader(**{**hdr.__dict__, "payload_size": len(payload)})
        pkts.append(VideoPacket(full, payload))
    stream = garbage + b"".join(p.to_bytes() for p in pkts)
    parser = PaVEParser(strict=True)
    got: list[VideoPacket] = []
    pos, k = 0, 0
    while pos < len(stream):
        n = cuts[k % len(cuts)]
        got += parser.feed(stream[pos : pos + n])
        pos, k = pos + n, k + 1
    assert got == pkts
    assert parser.bytes_skipped == len(garbage) and parser.buffered == 0


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=600), st.booleans())
def test_arbitrary_bytes_parse_or_raise_video_error(data: bytes, sprinkle: bool) -> None:
    if sprinkle:  # make signatures likely so the header checks get exercised
        data = data.replace(b"\x00", b"PaVE", 3)
    lenient = PaVEParser(max_payload=1 << 16)
    for pkt in lenient.feed(data):
        assert len(pkt.payload) == pkt.header.payload_size
    assert lenient.buffered <= len(data)
    strict = PaVEParser(max_payload=1 << 16, strict=True)
    try:
        strict.feed(data)
    except VideoError as e:
        assert strict.bad_headers == 1 and "PaVE" in str(e)
    else:
        assert strict.bad_headers == 0


# -------------------------------------------------------------------------- H.264


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return math.inf if mse == 0 else 10 * math.log10(255.0**2 / mse)


@pytest.fixture(scope="module")
def frames() -> list[np.ndarray]:
    """A short flight past the markers of the indoor room, rendered by the simulator."""
    from drone.sim.camera import Renderer
    from drone.sim.world import load_world

    r = Renderer(load_world("indoor"), seed=0)
    return [
        r.render((2.0 + 0.05 * i, 1.0, 1.4, 0.0, 0.0, -math.pi / 2 + 0.02 * i), frame=i)
        for i in range(20)
    ]


def test_h264_round_trip_through_pave(frames) -> None:
    enc = H264Encoder(fps=15, gop=8)
    wire = b"".join(p.to_bytes() for f in frames for p in enc.encode(f))
    packets = PaVEParser().feed(wire)
    assert len(packets) == len(frames)
    types = [p.frame_type for p in packets]
    assert types[0] == FrameType.IDR and types[8] == FrameType.IDR and types[16] == FrameType.IDR
    assert all(t == FrameType.P for i, t in enumerate(types) if i % 8)
    first = packets[0].header
    assert (first.encoded_width, first.encoded_height) == (640, 368)
    assert (first.display_width, first.display_height) == (640, 360)
    assert first.header1_size > 0 and first.header2_size > 0  # SPS, PPS in front of the IDR
    assert [p.frame_number for p in packets] == list(range(20))
    assert [p.timestamp_ms for p in packets][:4] == [0, 67, 133, 200]
    assert packets[1].header.stream_byte_position == len(packets[0].payload)
    dec = H264Decoder()
    out = [img for p in packets for img in dec.decode_packet(p)]
    assert len(out) == len(frames)
    for a, b in zip(frames, out, strict=True):
        assert b.shape == (360, 640, 3) and b.dtype == np.uint8
        assert _psnr(a, b) > 30.0


def test_markers_survive_the_codec(frames) -> None:
    enc, dec = H264Encoder(), H264Decoder()
    (pkt,) = enc.encode(frames[0])
    (img,) = dec.decode_packet(pkt)
    det = cv2.aruco.ArucoDetector(
        cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50), cv2.aruco.DetectorParameters()
    )
    _, raw_ids, _ = det.detectMarkers(frames[0])
    _, ids, _ = det.detectMarkers(img)
    assert raw_ids is not None and set(ids.ravel()) == set(raw_ids.ravel())


def test_decoder_joins_at_the_next_idr(frames) -> None:
    enc = H264Encoder(gop=5)
    packets = [p for f in frames[:12] for p in enc.encode(f)]
    dec = H264Decoder()
    got = [len(dec.decode_packet(p)) for p in packets[2:]]
    assert got == [0, 0, 0] + [1] * 7  # P-frames 2-4 skipped, decoding from IDR 5 on
    assert dec.skipped == 3


def test_bad_input_to_the_codec() -> None:
    enc = H264Encoder()
    with pytest.raises(VideoError, match="expected a \\(360, 640, 3\\) uint8"):
        enc.encode(np.zeros((368, 640, 3), np.uint8))
    with pytest.raises(VideoError, match="uint8"):
        enc.encode(np.zeros((360, 640, 3), np.float32))
    with pytest.raises(VideoError, match="even"):
        H264Encoder(width=641)
    dec = H264Decoder()
    assert dec.decode(b"\x00\x00\x01\x41garbage") == []  # a P-slice before any IDR: skipped
    with pytest.raises(VideoError, match="decode failed"):
        dec.decode(b"\x00\x00\x01\x65" + bytes(range(256)) * 4)  # IDR NAL with junk in it
