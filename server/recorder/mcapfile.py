"""One flight's MCAP file: writing it, and reading it back even when a crash cut it short.

Writing (:class:`FlightFile`) uses the ``mcap`` library's writer with zstd chunks. Every
``flush()`` finishes the chunk in progress and hands it to the OS, so a ``kill -9`` loses at
most what arrived since the last flush (the recorder flushes every ``chunk_s`` seconds). The
file is created 0600: what the camera saw and what was said is private.

Reading (:func:`read_recording`) walks the records itself (MCAP spec, "Records": opcode u8,
length u64, body) so it knows the byte offset of every record: a complete file reads whole; a
file without footer (the writer was killed) reads up to its last complete record, and reports
where it stopped; anything that does not parse raises :class:`CorruptRecording` naming the
offset. Chunks are decompressed and their CRC checked (``mcap.stream_reader.breakup_chunk``).
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import mmap
import os
import struct
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Footer, Header, Message, Metadata, Schema
from mcap.stream_reader import CRCValidationError, breakup_chunk
from mcap.writer import CompressionType, Writer

from server import __version__
from server.recorder.channels import ChannelFormat, decoder_for, format_for
from server.recorder.errors import CorruptRecording
from server.ros1 import Ros1Error

MAGIC = b"\x89MCAP0\r\n"  # MCAP spec, "Magic"
# The writer cuts chunks at 1 MiB (a camera frame larger than that gets a chunk of its own);
# a chunk that claims more than this uncompressed is damage, not data.
MAX_CHUNK_BYTES = 256 << 20
PROFILE = ""  # ros1 channels plus JSON ones for types without a definition: no single profile
LIBRARY = f"uav-console {__version__} (mcap)"

Opener = Callable[[Path], BinaryIO]


def open_private(path: Path) -> BinaryIO:
    """Create ``path`` for writing, readable by its owner only; never overwrite."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    return os.fdopen(fd, "wb")


class FlightFile:
    """An MCAP file being written; one per flight session (see ``server.recorder.sessions``).

    Raises:
        OSError: from the constructor, :meth:`write`, :meth:`flush` or :meth:`finish` when the
            disk is full or the file cannot be written (the recorder stops on it).
    """

    def __init__(
        self,
        path: Path,
        flight_id: str,
        started_ns: int,
        *,
        chunk_size: int = 1024 * 1024,
        opener: Opener = open_private,
        metadata: dict[str, str] | None = None,
    ) -> None:
        self.path = path
        self.flight_id = flight_id
        self.started_ns = started_ns
        self.last_ns = started_ns
        self.messages = 0
        self.encode_errors = 0
        self.topics: dict[str, str] = {}
        self._stream = opener(path)
        self._bytes = 0
        self._channels: dict[tuple[str, str], tuple[int, ChannelFormat]] = {}
        self._schemas: dict[str, int] = {}
        self._writer = Writer(self._stream, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        self._writer.start(profile=PROFILE, library=LIBRARY)
        self._writer.add_metadata(
            "flight",
            {
                **(metadata or {}),
                "id": flight_id,
                "started_ns": str(started_ns),
                "recorder": LIBRARY,
            },
        )
        self._finished = False

    @property
    def bytes(self) -> int:
        """Bytes handed to the OS so far (the chunk in progress is not counted)."""
        if not self._stream.closed:
            self._bytes = int(self._stream.tell())
        return self._bytes

    def _channel(self, topic: str, type_name: str) -> tuple[int, ChannelFormat]:
        key = (topic, type_name)
        found = self._channels.get(key)
        if found is not None:
            return found
        fmt = format_for(type_name)
        schema_id = self._schemas.get(type_name)
        if schema_id is None:
            schema_id = self._writer.register_schema(
                fmt.schema_name, fmt.schema_encoding, fmt.schema_data
            )
            self._schemas[type_name] = schema_id
        channel_id = self._writer.register_channel(topic, fmt.message_encoding, schema_id)
        self._channels[key] = (channel_id, fmt)
        self.topics[topic] = type_name
        return channel_id, fmt

    def write(self, topic: str, type_name: str, log_time_ns: int, msg: dict[str, Any]) -> bool:
        """Add one message; False (counted in ``encode_errors``) if it does not fit its type."""
        channel_id, fmt = self._channel(topic, type_name)
        try:
            data = fmt.encode(msg)
        except (Ros1Error, TypeError, ValueError):
            self.encode_errors += 1
            return False
        self._writer.add_message(channel_id, log_time_ns, data, log_time_ns, self.messages)
        self.messages += 1
        self.last_ns = max(self.last_ns, log_time_ns)
        return True

    def flush(self) -> None:
        """Finish the chunk in progress and hand it to the OS (survives ``kill -9``)."""
        self._writer.flush()  # type: ignore[no-untyped-call]

    def finish(self, ended_ns: int, drones: list[str]) -> None:
        """Write the end metadata, the summary and the footer, and close the file."""
        if self._finished:
            return
        self._finished = True
        try:
            self._writer.add_metadata(
                "flight_end",
                {
                    "ended_ns": str(ended_ns),
                    "drones": ",".join(sorted(drones)),
                    "messages": str(self.messages),
                },
            )
            self._writer.finish()  # type: ignore[no-untyped-call]
            self._bytes = int(self._stream.tell())
        finally:
            self._stream.close()

    def abandon(self) -> None:
        """Close without a summary (after a write error); the file reads up to its last chunk."""
        self._finished = True
        with contextlib.suppress(OSError):
            self._stream.close()


# -- reading ------------------------------------------------------------------------------
@dataclass(frozen=True)
class RecordedChannel:
    id: int
    topic: str
    type: str
    schema_encoding: str
    schema_data: bytes
    message_encoding: str


@dataclass(frozen=True)
class RecordedMessage:
    channel: int
    log_time_ns: int
    data: bytes


@dataclass
class Recording:
    """What :func:`read_recording` found in a file."""

    path: Path
    size: int
    channels: dict[int, RecordedChannel] = field(default_factory=dict)
    messages: list[RecordedMessage] = field(default_factory=list)
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    complete: bool = False  # footer and closing magic present
    good_until: int = 0  # offset just after the last record read
    stopped: CorruptRecording | None = None  # why reading stopped early (incomplete file)
    keep_messages: bool = True  # False: count the messages and their times, keep none
    message_count: int = 0
    first_ns: int | None = None
    last_ns: int | None = None

    def decoders(self) -> dict[int, Callable[[bytes], dict[str, Any]]]:
        """A decoder per channel (raises ``ValueError`` for an encoding it cannot read)."""
        return {
            c.id: decoder_for(c.type, c.schema_encoding, c.schema_data, c.message_encoding)
            for c in self.channels.values()
        }

    def decoded(self) -> Iterator[tuple[RecordedChannel, int, dict[str, Any]]]:
        """(channel, log time ns, graph message) of every message, in file order.

        Raises:
            CorruptRecording: a message does not decode, or its channel has an encoding or a
                ROS 1 definition this version cannot read (the record's offset is not kept,
                so the error names the message's index instead).
        """
        # A channel's decoder is made at its first message: a channel nothing was recorded on
        # does not stop a replay, whatever its schema says.
        decoders: dict[int, Callable[[bytes], dict[str, Any]]] = {}
        for n, m in enumerate(self.messages):
            channel = self.channels[m.channel]
            try:
                decode = decoders.get(m.channel)
                if decode is None:
                    decode = decoders[m.channel] = decoder_for(
                        channel.type,
                        channel.schema_encoding,
                        channel.schema_data,
                        channel.message_encoding,
                    )
                msg = decode(m.data)
            except (Ros1Error, ValueError) as exc:
                raise CorruptRecording(
                    str(self.path), self.good_until, f"message {n} on {channel.topic}: {exc}"
                ) from exc
            yield channel, m.log_time_ns, msg

    @property
    def topics(self) -> dict[str, str]:
        return {c.topic: c.type for c in self.channels.values()}

    @property
    def start_ns(self) -> int:
        return self.first_ns or 0

    @property
    def end_ns(self) -> int:
        return self.last_ns or 0


_HEAD = struct.Struct("<BQ")


def read_recording(
    path: Path | str, *, strict: bool = True, keep_messages: bool = True
) -> Recording:
    """Read every message of an MCAP file.

    Args:
        strict: raise on a file cut short (no footer); False reads up to the last complete
            record and keeps why it stopped in ``Recording.stopped``.
        keep_messages: False counts the messages and their times but keeps none, in constant
            memory (a listing row of a 2 GiB recording without a summary: kept, its
            decompressed messages took the console's 20 GB of memory).

    Raises:
        CorruptRecording: not an MCAP file, a record that does not parse, a chunk whose CRC
            is wrong, or (``strict``) a truncated file; the error names the byte offset.
        OSError: the file cannot be read.
    """
    path = Path(path)
    with _mapped(path) as (data, size):
        rec = _parse(path, data, size, keep_messages)
    if strict and rec.stopped is not None:
        raise rec.stopped
    return rec


def stream_messages(path: Path | str) -> Iterator[RecordedMessage]:
    """Every message of an MCAP file in file order, read one chunk at a time: memory stays
    bounded whatever the file's size (a rewrite of a 2 GiB recording). Tolerant of a file cut
    short, as ``read_recording(strict=False)``: it ends at the last complete record.

    Raises:
        CorruptRecording: not an MCAP file, or a record that does not parse (offset named).
        OSError: the file cannot be read.
    """
    path = Path(path)
    with _mapped(path) as (data, size):
        yield from _walk(Recording(path, size, keep_messages=False), data)


@contextlib.contextmanager
def _mapped(path: Path) -> Iterator[tuple[mmap.mmap, int]]:
    """The file mapped read-only, with its size.

    Raises:
        CorruptRecording: the file is empty.
        OSError: the file cannot be read.
    """
    with path.open("rb") as f:
        size = os.fstat(f.fileno()).st_size
        if size == 0:
            raise CorruptRecording(str(path), 0, "empty file, not an MCAP recording")
        with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as data:
            yield data, size


def _parse(path: Path, data: mmap.mmap, size: int, keep_messages: bool = True) -> Recording:
    rec = Recording(path, size, keep_messages=keep_messages)
    for message in _walk(rec, data):
        if keep_messages:
            rec.messages.append(message)
    return rec


def _walk(rec: Recording, data: mmap.mmap) -> Iterator[RecordedMessage]:
    """Walk the records of ``data`` into ``rec`` (channels, metadata, counts, where it stopped)
    and yield each message as it is read: at most one chunk's records are held at a time."""
    name, size = str(rec.path), rec.size
    if data[:8] != MAGIC:
        raise CorruptRecording(name, 0, "not an MCAP file (bad magic)")
    schemas: dict[int, Schema] = {}
    pos = rec.good_until = 8
    while pos < size:
        if size - pos < _HEAD.size:
            rec.stopped = CorruptRecording(name, pos, "file truncated inside a record header")
            return
        opcode, length = _HEAD.unpack_from(data, pos)
        body_at = pos + _HEAD.size
        if length > size - body_at:
            what = _opcode_name(opcode)
            rec.stopped = CorruptRecording(
                name, pos, f"file truncated: {what} record of {length} bytes runs past the end"
            )
            return
        body = data[body_at : body_at + length]
        try:
            messages: list[RecordedMessage] = []
            done = _record(rec, schemas, opcode, body, length, messages)
        except (
            McapError,
            CRCValidationError,
            zstandard.ZstdError,
            struct.error,
            ValueError,
            KeyError,
            OverflowError,
        ) as exc:
            raise CorruptRecording(
                name, pos, f"{_opcode_name(opcode)} record does not parse ({exc})"
            ) from exc
        pos = rec.good_until = body_at + length
        del body
        yield from messages
        if done:
            if data[pos : pos + 8] != MAGIC:
                raise CorruptRecording(name, pos, "no closing magic after the footer")
            rec.complete = True
            return
    rec.stopped = CorruptRecording(name, pos, "file truncated: no footer (writer did not finish)")


def _opcode_name(opcode: int) -> str:
    try:
        return Opcode(opcode).name.lower()
    except ValueError:
        return f"opcode 0x{opcode:02x}"


def _record(
    rec: Recording,
    schemas: dict[int, Schema],
    opcode: int,
    body: bytes,
    length: int,
    messages: list[RecordedMessage],
) -> bool:
    """Take in one top-level record, its messages into ``messages``; True at the footer."""
    stream = ReadDataStream(io.BytesIO(body))
    if opcode == Opcode.FOOTER:
        Footer.read(stream)
        return True
    if opcode == Opcode.HEADER:
        Header.read(stream)
    elif opcode == Opcode.CHUNK:
        for inner in breakup_chunk(_uncompressed(Chunk.read(stream)), validate_crc=True):
            _inner(rec, schemas, inner, messages)
    elif opcode == Opcode.MESSAGE:
        _inner(rec, schemas, Message.read(stream, length), messages)
    elif opcode == Opcode.SCHEMA:
        _inner(rec, schemas, Schema.read(stream), messages)
    elif opcode == Opcode.CHANNEL:
        _inner(rec, schemas, Channel.read(stream), messages)
    elif opcode == Opcode.METADATA:
        meta = Metadata.read(stream)
        rec.metadata[meta.name] = dict(meta.metadata)
    # indexes, statistics, summary offsets, attachments, data end: nothing to take in
    return False


def _uncompressed(chunk: Chunk) -> Chunk:
    """``chunk`` with its records decompressed, never into more memory than it claims.

    ``mcap``'s own ``breakup_chunk`` trusts the sizes: zstd allocates what the frame header
    says (a flipped byte there asked for exabytes: MemoryError), and lz4 has no bound at all.
    Here the chunk's ``uncompressed_size`` must be at most ``MAX_CHUNK_BYTES``, a zstd frame
    must declare that size (or none), and neither codec may produce more.

    Raises:
        ValueError: sizes that disagree, an unknown compression, or lz4 data that does not
            decompress (zstd's own errors are ``zstandard.ZstdError``).
    """
    size = chunk.uncompressed_size
    if size > MAX_CHUNK_BYTES:
        raise ValueError(
            f"chunk claims {size} bytes uncompressed "
            f"(over the {MAX_CHUNK_BYTES >> 20} MiB this reader accepts)"
        )
    if chunk.compression == "zstd":
        declared = zstandard.frame_content_size(chunk.data)
        if declared not in (-1, size):  # -1: the frame does not say
            raise ValueError(f"zstd frame declares {declared} bytes, the chunk {size}")
        data = zstandard.ZstdDecompressor().decompress(chunk.data, max_output_size=size)
    elif chunk.compression == "lz4":
        import lz4.frame  # mcap's own dependency; only other tools write lz4 chunks

        lz4_frame = lz4.frame.LZ4FrameDecompressor()
        try:
            data = lz4_frame.decompress(chunk.data, max_length=size)
        except RuntimeError as exc:  # lz4's error for data that is not an lz4 frame
            raise ValueError(f"lz4: {exc}") from exc
        if not lz4_frame.eof:
            raise ValueError(f"lz4 frame does not end within the {size} bytes the chunk claims")
    elif chunk.compression == "":
        data = chunk.data
    else:
        raise ValueError(f"unknown chunk compression {chunk.compression!r}")
    if len(data) != size:
        raise ValueError(f"chunk decompresses to {len(data)} bytes, not the {size} it claims")
    return dataclasses.replace(chunk, compression="", data=data)


def _inner(
    rec: Recording, schemas: dict[int, Schema], record: Any, messages: list[RecordedMessage]
) -> None:
    if isinstance(record, Schema):
        schemas[record.id] = record
    elif isinstance(record, Channel):
        schema = schemas.get(record.schema_id)
        if schema is None:
            raise ValueError(f"channel {record.id} names unknown schema {record.schema_id}")
        rec.channels[record.id] = RecordedChannel(
            record.id,
            record.topic,
            schema.name,
            schema.encoding,
            bytes(schema.data),
            record.message_encoding,
        )
    elif isinstance(record, Message):
        if record.channel_id not in rec.channels:
            raise ValueError(f"message on unknown channel {record.channel_id}")
        t = record.log_time
        rec.message_count += 1
        rec.first_ns = t if rec.first_ns is None else min(rec.first_ns, t)
        rec.last_ns = t if rec.last_ns is None else max(rec.last_ns, t)
        messages.append(RecordedMessage(record.channel_id, t, record.data))
