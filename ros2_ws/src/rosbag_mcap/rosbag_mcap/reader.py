"""Reading bags without ROS: a bag directory (also one written by rosbag2) or a lone .mcap.

A file with a readable summary is read chunk by chunk through its chunk index, in log-time
order. A file without one (truncated or unfinished recording, damaged footer) is walked
record by record (:mod:`rosbag_mcap.mcapfile`) up to where its structure is lost. In both
cases a damaged chunk (CRC mismatch, corrupt compressed data) is skipped with its messages and
reading goes on with the next chunk; :attr:`BagReader.problems` names the file, the byte
offset, the reason and how many messages were lost, and :attr:`BagReader.skipped_chunks` /
:attr:`BagReader.skipped_messages` count them.
"""

from __future__ import annotations

import heapq
import os
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import yaml
from mcap.exceptions import McapError
from mcap.reader import SeekingReader
from mcap.records import Channel, ChunkIndex, Message, Schema

from rosbag_mcap import mcapfile
from rosbag_mcap.metadata import (
    MESSAGE_ENCODING,
    METADATA_FILE,
    PROFILE,
    BagError,
    TopicInfo,
    load_metadata,
    parse_qos,
)


@dataclass(frozen=True)
class BagMessage:
    """One recorded message."""

    topic: str
    type: str
    data: bytes
    log_time: int
    publish_time: int
    file: Path


@dataclass
class _FileIndex:
    path: Path
    indexed: bool  # the summary could be read
    topics: dict[str, TopicInfo]
    schemas: dict[int, Schema]
    channels: dict[int, Channel]
    chunks: list[ChunkIndex]
    loose_messages: list[int]  # offsets of unchunked messages (scanned files only)
    start_time: int | None = None  # earliest log time [ns] of the readable messages


def topic_from_channel(channel: Channel, schema: Schema | None) -> TopicInfo:
    """A bag topic from an MCAP channel and its schema (QoS from the channel metadata)."""
    try:
        qos = parse_qos(channel.metadata.get('offered_qos_profiles', ''))
    except (ValueError, yaml.YAMLError):
        qos = []
    return TopicInfo(
        name=channel.topic,
        type=schema.name if schema else '',
        offered_qos=qos,
        type_hash=channel.metadata.get('topic_type_hash', ''),
        serialization_format=channel.message_encoding,
    )


def topics_of(
    schemas: dict[int, Schema], channels: dict[int, Channel], counts: dict[int, int]
) -> dict[str, TopicInfo]:
    topics: dict[str, TopicInfo] = {}
    for channel in channels.values():
        info = topics.get(channel.topic)
        if info is None:
            info = topics[channel.topic] = topic_from_channel(
                channel, schemas.get(channel.schema_id)
            )
        info.message_count += counts.get(channel.id, 0)
    return topics


class BagReader:
    """Reads a bag directory (metadata.yaml + .mcap files) or a lone .mcap file.

    Opening checks every file: one with a readable summary is read through its index; one
    without is walked once to find what is readable. :attr:`problems` lists what was found,
    each naming the file. Raises BagError when nothing of the bag can be read.
    """

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        self.problems: list[str] = []
        self.metadata: dict | None = None
        self.skipped_chunks = 0
        self.skipped_messages = 0
        self._skipped_indexed = 0  # lost messages still in the summary's counts
        self._reported: set[tuple[Path, int]] = set()
        files = self._resolve_files()
        self._files = [self._index_file(f) for f in files]
        self.topics: dict[str, TopicInfo] = {}
        for index in self._files:
            for name, info in index.topics.items():
                if name not in self.topics:
                    self.topics[name] = replace(info, message_count=0)
                self.topics[name].message_count += info.message_count
        self._merge_metadata_topics()
        if not self.topics and self.problems:
            raise BagError('; '.join(self.problems))

    # -- opening

    def _resolve_files(self) -> list[Path]:
        path = self.path
        if path.is_file():
            if path.name == METADATA_FILE:
                self.path = path = path.parent
            else:
                return [path]
        if not path.exists():
            raise BagError(f'{path}: no such bag directory or file')
        if not path.is_dir():
            raise BagError(f'{path}: not a bag directory or .mcap file')
        meta_path = path / METADATA_FILE
        if meta_path.is_file():
            try:
                self.metadata = load_metadata(meta_path)
            except BagError as exc:
                self.problems.append(f'{exc}; reading the .mcap files of the directory instead')
        if self.metadata is not None:
            storage = self.metadata.get('storage_identifier')
            if storage != 'mcap':
                raise BagError(f'{meta_path}: storage {storage!r} is not supported (mcap only)')
            if (self.metadata.get('compression_mode') or '').lower() not in ('', 'none'):
                raise BagError(
                    f'{meta_path}: whole-file compression '
                    f'({self.metadata.get("compression_format")}) is not supported; '
                    'decompress the files first'
                )
            files = [path / Path(p).name for p in self.metadata['relative_file_paths']]
            missing = [str(f) for f in files if not f.is_file()]
            if missing:
                raise BagError(f'{meta_path}: bag file(s) missing: {", ".join(missing)}')
            return files
        files = sorted(path.glob('*.mcap'))
        if not files:
            raise BagError(f'{path}: no {METADATA_FILE} and no .mcap file in the directory')
        if not meta_path.is_file():
            self.problems.append(
                f'{meta_path}: missing (unfinished recording? bag_reindex rebuilds it); '
                f'reading {", ".join(f.name for f in files)} directly'
            )
        return files

    def _index_file(self, path: Path) -> _FileIndex:
        try:
            with open(path, 'rb') as stream:
                reader = SeekingReader(stream, validate_crcs=True)
                header = reader.get_header()
                summary = reader.get_summary()
            if summary is None or summary.statistics is None:
                raise McapError('no summary section')
            if summary.statistics.message_count and not summary.chunk_indexes:
                raise McapError('messages without a chunk index')
        except Exception as exc:  # noqa: BLE001 (damaged data fails in many ways)
            if isinstance(exc, OSError):
                raise BagError(f'{path}: cannot read: {exc.strerror or exc}') from None
            if type(exc).__name__ == 'InvalidMagic':
                raise BagError(f'{path}: not an MCAP file (bad magic bytes)') from None
            return self._scan_file(path, f'summary unreadable: {mcapfile.describe(exc)}')
        if header.profile not in (PROFILE, ''):
            self.problems.append(f'{path}: MCAP profile {header.profile!r}, expected ros2')
        counts = summary.statistics.channel_message_counts
        topics = topics_of(summary.schemas, summary.channels, counts)
        start = summary.statistics.message_start_time if summary.statistics.message_count else None
        return _FileIndex(
            path,
            True,
            topics,
            dict(summary.schemas),
            dict(summary.channels),
            list(summary.chunk_indexes),
            [],
            start,
        )

    def _scan_file(self, path: Path, why: str) -> _FileIndex:
        try:
            result = mcapfile.scan(path)
        except mcapfile.McapFileError as exc:
            raise BagError(str(exc)) from None
        topics = topics_of(result.schemas, result.channels, result.channel_counts)
        count = sum(t.message_count for t in topics.values())
        for damaged in result.damaged:
            self._skip(path, damaged.offset, damaged.reason, damaged.messages)
        if result.data_end:
            problem = f'{path}: {why}; all {count} messages are readable by a full scan'
        else:
            problem = (
                f'{path}: truncated or corrupt ({why}; reading stopped: {result.stop}); '
                f'{count} messages are readable'
            )
        if count == 0 and not topics:
            raise BagError(f'{path}: nothing readable ({problem.split("(", 1)[1]}')
        self.problems.append(problem)
        return _FileIndex(
            path,
            False,
            topics,
            result.schemas,
            result.channels,
            result.chunks,
            result.loose_messages,
            result.start_time,
        )

    def _skip(
        self, path: Path, offset: int, reason: str, messages: int | None, indexed: bool = False
    ) -> None:
        if (path, offset) in self._reported:
            return
        self._reported.add((path, offset))
        self.skipped_chunks += 1
        self.skipped_messages += messages or 0
        if indexed:
            self._skipped_indexed += messages or 0
        lost = f'{messages} messages' if messages is not None else 'an unknown number of messages'
        self.problems.append(
            f'{path}: corrupt chunk at byte {offset} ({reason}): skipped it with {lost}; '
            'reading goes on with the next chunk'
        )

    def _merge_metadata_topics(self) -> None:
        if self.metadata is None:
            return
        for entry in self.metadata.get('topics_with_message_count') or []:
            try:
                meta = entry['topic_metadata']
                name, type_name = meta['name'], meta['type']
            except (KeyError, TypeError):
                continue
            known = self.topics.get(name)
            try:
                qos = parse_qos(meta.get('offered_qos_profiles', ''))
            except (ValueError, yaml.YAMLError):
                qos = []
            if known is None:
                # Listed in metadata.yaml but no channel readable (lost in a damaged part).
                self.topics[name] = TopicInfo(
                    name=name,
                    type=type_name,
                    offered_qos=qos,
                    type_hash=meta.get('type_description_hash', '') or '',
                    message_count=0,
                    serialization_format=meta.get('serialization_format', MESSAGE_ENCODING),
                )
            else:
                if not known.offered_qos:
                    known.offered_qos = qos
                if not known.type:
                    known.type = type_name

    # -- queries

    @property
    def files(self) -> list[Path]:
        return [f.path for f in self._files]

    def definition(self, topic: str) -> str:
        """The full message definition ``topic`` was recorded with ('' when unknown)."""
        for index in self._files:
            for channel in index.channels.values():
                schema = index.schemas.get(channel.schema_id)
                if channel.topic == topic and schema is not None and schema.data:
                    return bytes(schema.data).decode('utf-8', errors='replace')
        return ''

    @property
    def complete(self) -> bool:
        """True when every file was read through its summary (nothing known to be missing)."""
        return all(f.indexed for f in self._files)

    @property
    def damaged(self) -> bool:
        """True when something recorded cannot be read (truncation or skipped chunks)."""
        return not self.complete or self.skipped_chunks > 0

    @property
    def expected_message_count(self) -> int | None:
        """The message count metadata.yaml promises, if there is one."""
        if self.metadata is None:
            return None
        try:
            return int(self.metadata['message_count'])
        except (KeyError, TypeError, ValueError):
            return None

    @property
    def readable_message_count(self) -> int:
        """Messages of the readable chunks (a chunk found damaged while reading is excluded
        once it was met)."""
        return sum(t.message_count for t in self.topics.values()) - self._skipped_indexed

    @property
    def start_time(self) -> int | None:
        """Earliest log time [ns] of the readable messages, None if there are none."""
        starts = [f.start_time for f in self._files if f.start_time is not None]
        return min(starts) if starts else None

    def messages(
        self, topics: Iterable[str] | None = None, start_time: int | None = None
    ) -> Iterator[BagMessage]:
        """Readable messages, file by file, in log-time order within a file.

        A damaged chunk is skipped (reported in :attr:`problems`), the chunks after it are read.
        """
        wanted = None if topics is None else set(topics)
        for index in self._files:
            yield from self._file_messages(index, wanted, start_time)

    def _file_messages(
        self, index: _FileIndex, wanted: set[str] | None, start_time: int | None
    ) -> Iterator[BagMessage]:
        path = index.path
        channels = {
            cid: (c.topic, index.schemas[c.schema_id].name if c.schema_id in index.schemas else '')
            for cid, c in index.channels.items()
            if wanted is None or c.topic in wanted
        }

        def keep(message: Message) -> bool:
            return message.channel_id in channels and (
                start_time is None or message.log_time >= start_time
            )

        def out(message: Message) -> BagMessage:
            topic, type_name = channels[message.channel_id]
            return BagMessage(
                topic, type_name, message.data, message.log_time, message.publish_time, path
            )

        try:
            stream = open(path, 'rb')  # noqa: SIM115 (closed below)
        except OSError as exc:
            self.problems.append(f'{path}: cannot read: {exc.strerror or exc}')
            return
        with stream:
            heap: list[tuple[int, int, int, Message]] = []
            if index.loose_messages:
                for n, message in enumerate(
                    mcapfile.iter_loose_messages(stream, index.loose_messages)
                ):
                    if keep(message):
                        heapq.heappush(heap, (message.log_time, -1, n, message))
            chunks = sorted(enumerate(index.chunks), key=lambda c: (c[1].message_start_time, c[0]))
            for order, chunk in chunks:
                if start_time is not None and chunk.message_end_time < start_time:
                    continue
                while heap and heap[0][0] < chunk.message_start_time:
                    yield out(heapq.heappop(heap)[3])
                try:
                    messages = mcapfile.chunk_messages(stream, chunk)
                except Exception as exc:  # noqa: BLE001 (damaged data fails in many ways)
                    lost = mcapfile.indexed_message_count(stream, chunk)
                    reason = mcapfile.describe(exc)
                    self._skip(path, chunk.chunk_start_offset, reason, lost, indexed=True)
                    continue
                for n, message in enumerate(messages):
                    if keep(message):
                        heapq.heappush(heap, (message.log_time, order, n, message))
            while heap:
                yield out(heapq.heappop(heap)[3])
