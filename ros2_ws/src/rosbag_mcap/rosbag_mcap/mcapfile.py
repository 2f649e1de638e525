"""Damage-tolerant access to one MCAP file, without ROS.

:func:`scan` walks the data section record by record (each record is opcode, length, body),
so that a damaged chunk whose length field is intact is skipped and the chunks after it are
still found; it stops only where the record structure itself is lost (a truncated record, a
bad opcode). :func:`chunk_messages` decodes one chunk with its CRC checked.
:func:`finish` turns an unfinished or damaged file into a valid MCAP: it cuts the file after
the last intact record and appends DataEnd, a summary (schemas, channels, statistics, the
indexes of the intact chunks) and the footer, so that every MCAP reader opens it.
"""

from __future__ import annotations

import os
import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from io import BytesIO
from pathlib import Path
from typing import BinaryIO

from mcap.data_stream import ReadDataStream, RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    Message,
    MessageIndex,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)
from mcap.stream_reader import breakup_chunk, get_chunk_data_stream

MAGIC = b'\x89MCAP0\r\n'
_DATA_OPCODES = {
    Opcode.HEADER,
    Opcode.SCHEMA,
    Opcode.CHANNEL,
    Opcode.MESSAGE,
    Opcode.CHUNK,
    Opcode.MESSAGE_INDEX,
    Opcode.ATTACHMENT,
    Opcode.METADATA,
    Opcode.DATA_END,
    Opcode.FOOTER,
}


class McapFileError(Exception):
    """The file is not an MCAP file at all (or cannot be read); the message names it."""


@dataclass
class DamagedChunk:
    offset: int  # of the chunk record in the file [byte]
    reason: str
    messages: int | None  # lost messages, from the chunk's message indexes (None: unknown)


@dataclass
class ScanResult:
    """What a record-by-record walk found in one file."""

    path: Path
    profile: str = ''
    library: str = ''
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    chunks: list[ChunkIndex] = field(default_factory=list)  # intact chunks, file order
    loose_messages: list[int] = field(default_factory=list)  # offsets of unchunked messages
    metadata: list[tuple[int, int, Metadata]] = field(default_factory=list)  # offset, length
    channel_counts: dict[int, int] = field(default_factory=dict)
    message_count: int = 0
    start_time: int | None = None  # log time range of the readable messages [ns]
    end_time: int | None = None
    damaged: list[DamagedChunk] = field(default_factory=list)
    intact_end: int = 0  # offset just past the last intact data-section record
    data_end: bool = False  # the DataEnd record was reached: the data section is whole
    stop: str | None = None  # why the walk ended before DataEnd (truncation, corruption)

    @property
    def lost_messages(self) -> int:
        return sum(d.messages or 0 for d in self.damaged)

    def _count(self, message: Message) -> None:
        self.channel_counts[message.channel_id] = (
            self.channel_counts.get(message.channel_id, 0) + 1
        )
        self.message_count += 1
        t = message.log_time
        self.start_time = t if self.start_time is None else min(self.start_time, t)
        self.end_time = t if self.end_time is None else max(self.end_time, t)


def describe(exc: BaseException) -> str:
    """A short reason for a decoding failure (no traceback, no library internals)."""
    text = str(exc).strip()
    name = type(exc).__name__
    if name == 'EndOfFile' or isinstance(exc, struct.error):
        return 'the data ends in the middle of a record'
    if name == 'CRCValidationError':
        return f'CRC mismatch ({text})'
    if name == 'ZstdError':
        return f'zstd data corrupt ({text})'
    return f'{name}: {text}' if text else name


def _decode_chunk(body: bytes) -> tuple[Chunk, list]:
    chunk = Chunk.read(ReadDataStream(BytesIO(body)))
    if chunk.compression not in ('', 'zstd', 'lz4'):
        raise ValueError(f'unknown chunk compression {chunk.compression!r}')
    return chunk, breakup_chunk(chunk, validate_crc=True)


def scan(path: str | os.PathLike) -> ScanResult:
    """Walk the data section of ``path``; McapFileError if it is not an MCAP file."""
    result = ScanResult(Path(path))
    try:
        size = os.path.getsize(path)
        stream = open(path, 'rb')  # noqa: SIM115 (closed below)
    except OSError as exc:
        raise McapFileError(f'{path}: cannot read: {exc.strerror or exc}') from None
    with stream:
        if stream.read(8) != MAGIC:
            raise McapFileError(f'{path}: not an MCAP file (bad magic bytes)')
        result.intact_end = 8
        last_chunk: ChunkIndex | None = None
        last_damaged: DamagedChunk | None = None
        while True:
            offset = stream.tell()
            head = stream.read(9)
            if len(head) < 9:
                result.stop = (
                    'the file ends without its summary (unfinished recording)'
                    if not head
                    else f'the file ends in the middle of a record at byte {offset}'
                )
                break
            opcode, length = struct.unpack('<BQ', head)
            if opcode not in _DATA_OPCODES and opcode < 0x80:
                result.stop = f'corrupt record at byte {offset} (opcode 0x{opcode:02x})'
                break
            if length > size - offset - 9:
                result.stop = f'the file ends in the middle of a record at byte {offset}'
                break
            body = stream.read(length)
            if opcode == Opcode.DATA_END:
                result.data_end = True
                break
            if opcode == Opcode.FOOTER:
                result.stop = f'footer at byte {offset} without a DataEnd record'
                break
            try:
                if opcode == Opcode.CHUNK:
                    last_chunk = last_damaged = None
                    try:
                        chunk, records = _decode_chunk(body)
                    except Exception as exc:  # noqa: BLE001 (damage takes many forms)
                        last_damaged = DamagedChunk(offset, describe(exc), None)
                        result.damaged.append(last_damaged)
                    else:
                        last_chunk = _add_chunk(result, chunk, records, offset, 9 + length)
                elif opcode == Opcode.MESSAGE_INDEX:
                    index = MessageIndex.read(ReadDataStream(BytesIO(body)))
                    if last_chunk is not None:
                        last_chunk.message_index_offsets[index.channel_id] = offset
                        last_chunk.message_index_length = (
                            offset
                            + 9
                            + length
                            - (last_chunk.chunk_start_offset + last_chunk.chunk_length)
                        )
                    elif last_damaged is not None:
                        last_damaged.messages = (last_damaged.messages or 0) + len(index.records)
                else:
                    last_chunk = last_damaged = None
                    _add_record(result, opcode, body, offset, length)
            except Exception as exc:  # noqa: BLE001
                result.stop = f'corrupt record at byte {offset} ({describe(exc)})'
                break
            result.intact_end = offset + 9 + length
    return result


def _add_chunk(
    result: ScanResult, chunk: Chunk, records: list, offset: int, length: int
) -> ChunkIndex:
    start = end = None
    for record in records:
        if isinstance(record, Schema):
            result.schemas.setdefault(record.id, record)
        elif isinstance(record, Channel):
            result.channels.setdefault(record.id, record)
        elif isinstance(record, Message):
            result._count(record)
            start = record.log_time if start is None else min(start, record.log_time)
            end = record.log_time if end is None else max(end, record.log_time)
    index = ChunkIndex(
        message_start_time=chunk.message_start_time if start is None else start,
        message_end_time=chunk.message_end_time if end is None else end,
        chunk_start_offset=offset,
        chunk_length=length,
        message_index_offsets={},
        message_index_length=0,
        compression=chunk.compression,
        compressed_size=len(chunk.data),
        uncompressed_size=chunk.uncompressed_size,
    )
    result.chunks.append(index)
    return index


def _add_record(result: ScanResult, opcode: int, body: bytes, offset: int, length: int) -> None:
    data = ReadDataStream(BytesIO(body))
    if opcode == Opcode.HEADER:
        header = Header.read(data)
        result.profile, result.library = header.profile, header.library
    elif opcode == Opcode.SCHEMA:
        schema = Schema.read(data)
        result.schemas.setdefault(schema.id, schema)
    elif opcode == Opcode.CHANNEL:
        channel = Channel.read(data)
        result.channels.setdefault(channel.id, channel)
    elif opcode == Opcode.MESSAGE:
        result._count(Message.read(data, length))
        result.loose_messages.append(offset)
    elif opcode == Opcode.METADATA:
        result.metadata.append((offset, 9 + length, Metadata.read(data)))


def read_record(stream: BinaryIO, offset: int, expected: int) -> bytes:
    """The body of the record at ``offset``; ValueError if it is not of opcode ``expected``."""
    stream.seek(offset)
    head = stream.read(9)
    if len(head) < 9:
        raise ValueError('the data ends in the middle of a record')
    opcode, length = struct.unpack('<BQ', head)
    if opcode != expected:
        raise ValueError(
            f'expected opcode 0x{expected:02x} at byte {offset}, found 0x{opcode:02x}'
        )
    body = stream.read(length)
    if len(body) < length:
        raise ValueError('the data ends in the middle of a record')
    return body


def chunk_messages(stream: BinaryIO, index: ChunkIndex) -> list[Message]:
    """The messages of one chunk, CRC checked; raises on any damage (see :func:`describe`)."""
    _, records = _decode_chunk(read_record(stream, index.chunk_start_offset, Opcode.CHUNK))
    return [r for r in records if isinstance(r, Message)]


def indexed_message_count(stream: BinaryIO, index: ChunkIndex) -> int | None:
    """How many messages a chunk holds, from its message index records (None: unreadable)."""
    total = 0
    try:
        for offset in index.message_index_offsets.values():
            body = read_record(stream, offset, Opcode.MESSAGE_INDEX)
            total += len(MessageIndex.read(ReadDataStream(BytesIO(body))).records)
    except Exception:  # noqa: BLE001
        return None
    return total if index.message_index_offsets else None


def _message_indexes(stream: BinaryIO, index: ChunkIndex) -> list[MessageIndex]:
    """The message index records of a chunk, rebuilt from its records."""
    chunk, _ = _decode_chunk(read_record(stream, index.chunk_start_offset, Opcode.CHUNK))
    data_stream, size = get_chunk_data_stream(chunk, validate_crc=True)
    entries: dict[int, list[tuple[int, int]]] = {}
    while data_stream.count < size:
        offset = data_stream.count
        opcode = data_stream.read1()
        length = data_stream.read8()
        body = data_stream.read(length)
        if opcode == Opcode.MESSAGE:
            channel_id, _, log_time = struct.unpack_from('<HIQ', body)
            entries.setdefault(channel_id, []).append((log_time, offset))
    return [MessageIndex(cid, sorted(records)) for cid, records in sorted(entries.items())]


def finish(result: ScanResult) -> None:
    """Make ``result.path`` a complete MCAP: cut after the last intact record, then append
    DataEnd, a summary indexing the intact chunks only, and the footer.

    Nothing intact is lost; the cut part is what no reader could decode (a record cut short
    by the end of the file). Damaged chunks before the cut stay in the file but are left out
    of the index, so indexed readers skip them.
    """
    builder = RecordBuilder()
    last = result.chunks[-1] if result.chunks else None
    if (
        last is not None
        and not last.message_index_offsets
        and last.chunk_start_offset + last.chunk_length == result.intact_end
    ):
        # The cut took the last chunk's message indexes (some readers need them): rebuild.
        with open(result.path, 'rb') as stream:
            for index in _message_indexes(stream, last):
                last.message_index_offsets[index.channel_id] = result.intact_end + builder.count
                index.write(builder)
        last.message_index_length = builder.count
    DataEnd(0).write(builder)
    summary_start = result.intact_end + builder.count
    summary = RecordBuilder()
    offsets: list[SummaryOffset] = []

    def group(opcode: Opcode, records: list) -> None:
        start = summary.count
        for record in records:
            record.write(summary)
        if records:
            offsets.append(SummaryOffset(opcode, summary_start + start, summary.count - start))

    group(Opcode.SCHEMA, list(result.schemas.values()))
    group(Opcode.CHANNEL, list(result.channels.values()))
    group(
        Opcode.STATISTICS,
        [
            Statistics(
                message_count=result.message_count,
                schema_count=len(result.schemas),
                channel_count=len(result.channels),
                attachment_count=0,
                metadata_count=len(result.metadata),
                chunk_count=len(result.chunks),
                message_start_time=result.start_time or 0,
                message_end_time=result.end_time or 0,
                channel_message_counts=dict(result.channel_counts),
            )
        ],
    )
    group(Opcode.CHUNK_INDEX, list(result.chunks))
    group(
        Opcode.METADATA_INDEX,
        [MetadataIndex(offset, length, meta.name) for offset, length, meta in result.metadata],
    )
    summary_offset_start = summary_start + summary.count
    for offset in offsets:
        offset.write(summary)
    summary_data = summary.end()
    crc = zlib.crc32(summary_data)
    crc = zlib.crc32(
        struct.pack('<BQQQ', Opcode.FOOTER, 20, summary_start, summary_offset_start), crc
    )
    Footer(summary_start, summary_offset_start, crc).write(summary)
    tail = builder.end() + summary_data + summary.end() + MAGIC
    with open(result.path, 'r+b') as stream:
        stream.truncate(result.intact_end)
        stream.seek(result.intact_end)
        stream.write(tail)
        stream.flush()
        os.fsync(stream.fileno())
    result.data_end = True
    result.stop = None


def iter_loose_messages(stream: BinaryIO, offsets: list[int]) -> Iterator[Message]:
    """Unchunked messages at the given offsets (files written without chunks)."""
    for offset in offsets:
        body = read_record(stream, offset, Opcode.MESSAGE)
        yield Message.read(ReadDataStream(BytesIO(body)), len(body))
