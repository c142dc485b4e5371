"""AR.Drone 2.0 video: PaVE framing (sans-I/O) and H.264 encode/decode with PyAV.

The drone streams H.264 on TCP 5555; every frame is preceded by a PaVE header ("Parrot Video
Encapsulation", ARDroneLib ``Soft/Common/video_encapsulation.h``, ``PAVE_CURRENT_VERSION`` 2):
little-endian, 64 bytes in version 2, but readers must honour ``header_size``. The H.264 stream is
encoded at 640×368 (16-pixel macroblock rows) and displayed cropped to 640×360.

Header layout (byte offsets, ``parrot_video_encapsulation_t``)::

    0 signature "PaVE"     4 u8 version         5 u8 video_codec (4 = MPEG4_AVC, H.264)
    6 u16 header_size      8 u32 payload_size   12 u16 encoded_stream_width  14 u16 ..._height
   16 u16 display_width   18 u16 display_height 20 u32 frame_number          24 u32 timestamp (ms)
   28 u8 total_chunks     29 u8 chunk_index     30 u8 frame_type (1 IDR, 2 I, 3 P, 4 headers)
   31 u8 control          32 u32 stream_byte_position_lw   36 u32 stream_byte_position_uw
   40 u16 stream_id       42 u8 total_slices    43 u8 slice_index   44 u8 header1_size (SPS)
   45 u8 header2_size (PPS)   46 u8[2] reserved 48 u32 advertised_size   52 u8[12] reserved

Errors (:class:`drone.ardrone.errors.VideoError`, a ``ValueError``):

- :class:`PaVEParser` in ``strict`` mode raises ``VideoError`` on the first bad header: a
  ``header_size`` below 32 (the fields up to ``control``) or above 4096, or a ``payload_size``
  above ``max_payload`` (default 1 MiB; a real 640×360 frame is < 100 kB). Otherwise (default)
  it drops the bad header's signature, counts it in ``bad_headers`` and resynchronises on the next
  ``"PaVE"``; bytes outside packets are skipped and counted in ``bytes_skipped``.
- :meth:`H264Decoder.decode` raises ``VideoError`` when libavcodec rejects the data.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, replace
from enum import IntEnum
from fractions import Fraction

import av
import cv2
import numpy as np

from drone.ardrone.errors import VideoError

PAVE_SIGNATURE = b"PaVE"
PAVE_VERSION = 2  # PAVE_CURRENT_VERSION
PAVE_HEADER_SIZE = 64  # sizeof(parrot_video_encapsulation_t) for version 2
PAVE_MIN_HEADER_SIZE = 32  # fields through ``control`` (offset 31)
PAVE_MAX_HEADER_SIZE = 4096
DEFAULT_MAX_PAYLOAD = 1 << 20
CODEC_H264 = 4  # parrot_video_encapsulation_codecs_t: CODEC_MPEG4_AVC
STREAM_ID_H264_360P = 1  # PAVE_STREAM_ID_SUFFIX_H264_360p

ENCODED_WIDTH, ENCODED_HEIGHT = 640, 368
DISPLAY_WIDTH, DISPLAY_HEIGHT = 640, 360

_FMT = "<4sBBHIHHHHIIBBBBIIHBBBB2sI12s"
assert struct.calcsize(_FMT) == PAVE_HEADER_SIZE


class FrameType(IntEnum):
    """parrot_video_encapsulation_frametypes_t."""

    UNKNOWN = 0
    IDR = 1  # headers (SPS, PPS) followed by an I-frame
    I = 2  # noqa: E741 - the SDK's name
    P = 3
    HEADERS = 4


@dataclass(frozen=True)
class PaVEHeader:
    """A decoded PaVE header (field names as in ``video_encapsulation.h``, spelling fixed)."""

    payload_size: int
    frame_number: int = 0
    timestamp_ms: int = 0
    frame_type: int = FrameType.P
    version: int = PAVE_VERSION
    video_codec: int = CODEC_H264
    header_size: int = PAVE_HEADER_SIZE
    encoded_width: int = ENCODED_WIDTH
    encoded_height: int = ENCODED_HEIGHT
    display_width: int = DISPLAY_WIDTH
    display_height: int = DISPLAY_HEIGHT
    total_chunks: int = 1
    chunk_index: int = 0
    control: int = 0
    stream_byte_position: int = 0
    stream_id: int = STREAM_ID_H264_360P
    total_slices: int = 1
    slice_index: int = 0
    header1_size: int = 0  # SPS size inside the payload (0: none)
    header2_size: int = 0  # PPS size inside the payload (0: none)
    advertised_size: int = 0

    def pack(self) -> bytes:
        """The header bytes: the 64-byte v2 layout, zero-padded up to ``header_size``.

        Raises:
            VideoError: a field does not fit its wire type or ``header_size`` < 64.
        """
        if self.header_size < PAVE_HEADER_SIZE:
            raise VideoError(
                f"header_size {self.header_size} < {PAVE_HEADER_SIZE} cannot be written"
            )
        try:
            raw = struct.pack(
                _FMT,
                PAVE_SIGNATURE,
                self.version,
                self.video_codec,
                self.header_size,
                self.payload_size,
                self.encoded_width,
                self.encoded_height,
                self.display_width,
                self.display_height,
                self.frame_number,
                self.timestamp_ms,
                self.total_chunks,
                self.chunk_index,
                self.frame_type,
                self.control,
                self.stream_byte_position & 0xFFFFFFFF,
                self.stream_byte_position >> 32,
                self.stream_id,
                self.total_slices,
                self.slice_index,
                self.header1_size,
                self.header2_size,
                b"\0\0",
                self.advertised_size,
                b"\0" * 12,
            )
        except struct.error as e:
            raise VideoError(f"PaVE field out of range: {e}") from e
        return raw + b"\0" * (self.header_size - PAVE_HEADER_SIZE)

    @classmethod
    def unpack(cls, data: bytes, max_payload: int = DEFAULT_MAX_PAYLOAD) -> PaVEHeader:
        """Decode a header from the start of ``data`` (which holds at least ``header_size`` bytes).

        Fields beyond ``header_size`` (older, shorter headers) take their defaults.

        Raises:
            VideoError: wrong signature, truncated, ``header_size`` outside 32..4096, or
                ``payload_size`` above ``max_payload``.
        """
        if len(data) < 12:
            raise VideoError(f"PaVE header truncated: {len(data)} bytes")
        if data[:4] != PAVE_SIGNATURE:
            raise VideoError(f"bad PaVE signature {data[:4]!r}")
        header_size, payload_size = struct.unpack_from("<HI", data, 6)
        if not PAVE_MIN_HEADER_SIZE <= header_size <= PAVE_MAX_HEADER_SIZE:
            raise VideoError(
                f"PaVE header_size {header_size} outside "
                f"{PAVE_MIN_HEADER_SIZE}..{PAVE_MAX_HEADER_SIZE}"
            )
        if payload_size > max_payload:
            raise VideoError(f"PaVE payload_size {payload_size} exceeds the limit {max_payload}")
        if len(data) < header_size:
            raise VideoError(f"PaVE header truncated: {len(data)} of {header_size} bytes")
        buf = bytes(data[:header_size]).ljust(PAVE_HEADER_SIZE, b"\0")
        f = struct.unpack_from(_FMT, buf)
        hdr = cls(
            version=f[1],
            video_codec=f[2],
            header_size=f[3],
            payload_size=f[4],
            encoded_width=f[5],
            encoded_height=f[6],
            display_width=f[7],
            display_height=f[8],
            frame_number=f[9],
            timestamp_ms=f[10],
            total_chunks=f[11],
            chunk_index=f[12],
            frame_type=f[13],
            control=f[14],
            stream_byte_position=f[15] | (f[16] << 32),
            stream_id=f[17],
            total_slices=f[18],
            slice_index=f[19],
            header1_size=f[20],
            header2_size=f[21],
            advertised_size=f[23],
        )
        if header_size < PAVE_HEADER_SIZE:  # short header: later fields were padding, not data
            defaults = cls(payload_size=payload_size)
            hdr = replace(
                hdr,
                **{
                    name: getattr(defaults, name)
                    for name, end in _FIELD_ENDS.items()
                    if end > header_size
                },
            )
        return hdr


# end offset of each field after ``control`` (for headers shorter than 64 bytes)
_FIELD_ENDS = {
    "stream_byte_position": 40,
    "stream_id": 42,
    "total_slices": 43,
    "slice_index": 44,
    "header1_size": 45,
    "header2_size": 46,
    "advertised_size": 52,
}


@dataclass(frozen=True)
class VideoPacket:
    """One PaVE-framed unit: header and H.264 payload (an access unit: one frame)."""

    header: PaVEHeader
    payload: bytes

    @property
    def frame_type(self) -> int:
        return self.header.frame_type

    @property
    def frame_number(self) -> int:
        return self.header.frame_number

    @property
    def timestamp_ms(self) -> int:
        return self.header.timestamp_ms

    @property
    def is_keyframe(self) -> bool:
        """IDR or I frame: decoding can start here (IDR carries SPS/PPS too)."""
        return self.header.frame_type in (FrameType.IDR, FrameType.I)

    def to_bytes(self) -> bytes:
        """Header + payload as sent on TCP 5555."""
        return self.header.pack() + self.payload


def encode_pave(
    payload: bytes,
    frame_number: int,
    timestamp_ms: int,
    frame_type: int = FrameType.P,
    **fields: int,
) -> bytes:
    """PaVE header + payload bytes. ``fields`` override other header fields (e.g.
    ``header1_size``, ``stream_byte_position``, ``header_size``).

    Raises:
        VideoError: a field out of its wire range.
    """
    hdr = PaVEHeader(
        payload_size=len(payload),
        frame_number=frame_number,
        timestamp_ms=timestamp_ms,
        frame_type=frame_type,
        **fields,
    )
    return hdr.pack() + bytes(payload)


class PaVEParser:
    """Sans-I/O PaVE stream splitter: feed TCP bytes, get complete :class:`VideoPacket` s.

    Args:
        max_payload: the largest ``payload_size`` accepted (guards memory against a corrupt
            length).
        strict: raise :class:`VideoError` on a bad header instead of skipping it.

    Attributes:
        bytes_skipped: bytes dropped while searching for a signature (garbage, bad headers).
        bad_headers: headers rejected (non-strict mode).
    """

    def __init__(self, max_payload: int = DEFAULT_MAX_PAYLOAD, strict: bool = False) -> None:
        self.max_payload = max_payload
        self.strict = strict
        self._buf = bytearray()
        self.bytes_skipped = 0
        self.bad_headers = 0

    @property
    def buffered(self) -> int:
        """Bytes held waiting for the rest of a packet."""
        return len(self._buf)

    def feed(self, data: bytes) -> list[VideoPacket]:
        """Add bytes; return the packets completed by them (in stream order).

        Raises:
            VideoError: only in strict mode, on a bad header (the parser then skips that header's
                signature, so feeding more bytes continues after it).
        """
        self._buf += data
        out: list[VideoPacket] = []
        buf = self._buf
        while True:
            start = buf.find(PAVE_SIGNATURE)
            if start < 0:
                # keep a possible partial signature at the end
                keep = next((k for k in (3, 2, 1) if buf.endswith(PAVE_SIGNATURE[:k])), 0)
                self._drop(len(buf) - keep)
                break
            if start:
                self._drop(start)
            if len(buf) < 12:
                break
            header_size, payload_size = struct.unpack_from("<HI", buf, 6)
            bad = None
            if not PAVE_MIN_HEADER_SIZE <= header_size <= PAVE_MAX_HEADER_SIZE:
                bad = (
                    f"PaVE header_size {header_size} outside "
                    f"{PAVE_MIN_HEADER_SIZE}..{PAVE_MAX_HEADER_SIZE}"
                )
            elif payload_size > self.max_payload:
                bad = f"PaVE payload_size {payload_size} exceeds the limit {self.max_payload}"
            if bad is not None:
                self._drop(len(PAVE_SIGNATURE))
                self.bad_headers += 1
                if self.strict:
                    raise VideoError(bad)
                continue
            total = header_size + payload_size
            if len(buf) < total:
                break
            hdr = PaVEHeader.unpack(bytes(buf[:header_size]), self.max_payload)
            out.append(VideoPacket(hdr, bytes(buf[header_size:total])))
            del buf[:total]
        return out

    def _drop(self, n: int) -> None:
        if n > 0:
            del self._buf[:n]
            self.bytes_skipped += n


# ---------------------------------------------------------------------------------------------
# H.264


def _nal_units(data: bytes) -> list[tuple[int, int, int]]:
    """(nal_type, start incl. start code, end) of each Annex-B NAL unit."""
    starts = []
    i = data.find(b"\x00\x00\x01")
    while i >= 0:
        sc = i - 1 if i > 0 and data[i - 1] == 0 else i
        starts.append((sc, i + 3))
        i = data.find(b"\x00\x00\x01", i + 3)
    out = []
    for k, (sc, body) in enumerate(starts):
        end = starts[k + 1][0] if k + 1 < len(starts) else len(data)
        if body < len(data):
            out.append((data[body] & 0x1F, sc, end))
    return out


class H264Encoder:
    """BGR frames → PaVE-ready H.264 packets, the way the drone encodes them.

    libx264 (PyAV) with ``ultrafast``/``zerolatency`` (one packet out per frame in, no B-frames),
    an IDR every ``gop`` frames with SPS/PPS repeated in front of it (so a client can join the
    stream at any IDR), frames padded from 640×360 to 640×368 by repeating the last row.

    Args:
        width, height: display size of the input frames.
        fps: frame rate (timestamps and rate control).
        gop: frames between IDRs.
        crf: x264 constant rate factor (lower = better quality, bigger frames).
    """

    def __init__(
        self, width: int = 640, height: int = 360, fps: int = 15, gop: int = 15, crf: int = 23
    ) -> None:
        if width <= 0 or height <= 0 or width % 2 or height % 2:
            raise VideoError(f"frame size must be positive and even, got {width}×{height}")
        self.width, self.height, self.fps, self.gop = width, height, fps, gop
        self.encoded_width = (width + 15) // 16 * 16
        self.encoded_height = (height + 15) // 16 * 16
        ctx = av.CodecContext.create("libx264", "w")
        ctx.width = self.encoded_width
        ctx.height = self.encoded_height
        ctx.pix_fmt = "yuv420p"
        ctx.time_base = Fraction(1, fps)
        ctx.framerate = Fraction(fps, 1)
        ctx.options = {
            "preset": "ultrafast",
            "tune": "zerolatency",
            "crf": str(crf),
            "x264-params": f"keyint={gop}:min-keyint={gop}:scenecut=0:repeat-headers=1:bframes=0",
        }
        self._ctx = ctx
        self.frame_number = 0
        self._stream_pos = 0

    def encode(self, bgr: np.ndarray, timestamp_ms: int | None = None) -> list[VideoPacket]:
        """Encode one (height, width, 3) uint8 BGR frame.

        Returns:
            The packets produced (one with zerolatency), frame type IDR or P.

        Raises:
            VideoError: wrong shape or dtype.
        """
        if bgr.shape != (self.height, self.width, 3) or bgr.dtype != np.uint8:
            raise VideoError(
                f"expected a ({self.height}, {self.width}, 3) uint8 BGR frame, "
                f"got {bgr.shape} {bgr.dtype}"
            )
        pad = self.encoded_height - self.height
        padw = self.encoded_width - self.width
        img = bgr
        if pad or padw:
            img = cv2.copyMakeBorder(bgr, 0, pad, 0, padw, cv2.BORDER_REPLICATE)
        yuv = cv2.cvtColor(img, cv2.COLOR_BGR2YUV_I420)
        frame = av.VideoFrame.from_ndarray(yuv, format="yuv420p")  # type: ignore[arg-type]
        frame.pts = self.frame_number
        ts = (
            timestamp_ms if timestamp_ms is not None else round(self.frame_number * 1000 / self.fps)
        )
        out = [self._packet(bytes(p), bool(p.is_keyframe), ts) for p in self._ctx.encode(frame)]
        self.frame_number += 1
        return out

    def _packet(self, data: bytes, key: bool, ts: int) -> VideoPacket:
        sps = pps = 0
        for nal_type, s, e in _nal_units(data[:512]) if key else []:
            if nal_type == 7:
                sps = min(e - s, 255)
            elif nal_type == 8:
                pps = min(e - s, 255)
        hdr = PaVEHeader(
            payload_size=len(data),
            frame_number=self.frame_number,
            timestamp_ms=ts & 0xFFFFFFFF,
            frame_type=FrameType.IDR if key else FrameType.P,
            encoded_width=self.encoded_width,
            encoded_height=self.encoded_height,
            display_width=self.width,
            display_height=self.height,
            stream_byte_position=self._stream_pos,
            header1_size=sps,
            header2_size=pps,
        )
        self._stream_pos += len(data)
        return VideoPacket(hdr, data)


class H264Decoder:
    """H.264 access units → BGR frames cropped to the display size (libavcodec via PyAV).

    P-frames before the first IDR cannot be decoded; they yield no frame (``skipped`` counts
    them). Args: ``width``, ``height``: the default display size to crop to.
    """

    def __init__(self, width: int = DISPLAY_WIDTH, height: int = DISPLAY_HEIGHT) -> None:
        self.width, self.height = width, height
        self._ctx = av.CodecContext.create("h264", "r")
        self._have_key = False
        self.skipped = 0

    def decode(
        self, payload: bytes, display: tuple[int, int] | None = None, keyframe: bool | None = None
    ) -> list[np.ndarray]:
        """Decode one payload; returns 0 or more (height, width, 3) uint8 BGR frames.

        Args:
            payload: an H.264 access unit (Annex B), e.g. ``VideoPacket.payload``.
            display: (width, height) to crop to (default the decoder's).
            keyframe: whether the payload starts with an IDR (found from its NAL units if None).

        Raises:
            VideoError: libavcodec rejects the data.
        """
        if keyframe is None:
            keyframe = any(t in (5, 7) for t, _, _ in _nal_units(bytes(payload[:4096])))
        if keyframe:
            self._have_key = True
        if not self._have_key:
            self.skipped += 1
            return []
        w, h = display or (self.width, self.height)
        try:
            frames = self._ctx.decode(av.Packet(bytes(payload)))
        except av.error.FFmpegError as e:
            raise VideoError(f"H.264 decode failed: {e}") from e
        return [np.ascontiguousarray(f.to_ndarray(format="bgr24")[:h, :w]) for f in frames]

    def decode_packet(self, packet: VideoPacket) -> list[np.ndarray]:
        """Decode a PaVE packet, cropping to its display size."""
        hdr = packet.header
        return self.decode(
            packet.payload,
            display=(hdr.display_width, hdr.display_height),
            keyframe=hdr.frame_type in (FrameType.IDR, FrameType.I) or None,
        )
