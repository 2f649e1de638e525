"""Bags in rosbag2's MCAP layout, without ROS: writer, reader, metadata and QoS text.

A bag is a directory holding ``metadata.yaml`` (``rosbag2_bagfile_information`` version 9, as
rosbag2 Jazzy writes it) and ``<dirname>_0.mcap``. The MCAP file uses profile ``ros2``:
schemas ``ros2msg`` with the full definition text (see :mod:`rosbag_mcap.definitions`),
channels with message encoding ``cdr`` and metadata ``offered_qos_profiles`` (rosbag2's QoS
YAML) and ``topic_type_hash`` (``RIHS01_...``); payloads are the CDR bytes as received;
``log_time`` is the receive time [ns], ``publish_time`` the sender's source timestamp [ns].
Chunks are zstd-compressed (the mcap C++ writer's default, which rosbag2 uses) and indexed,
with a summary section, plus the ``rosbag2`` metadata record that rosbag2 writes on close.

The metadata and QoS text are in :mod:`rosbag_mcap.metadata` (its names are importable from
here too); reading is in :mod:`rosbag_mcap.reader` (``BagReader``), repair of unfinished or
damaged files in :mod:`rosbag_mcap.mcapfile` and :mod:`rosbag_mcap.reindex`.
"""

from __future__ import annotations

import os
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import yaml
from mcap.writer import CompressionType, Writer

from rosbag_mcap.metadata import (
    INFINITE_NS,
    MESSAGE_ENCODING,
    METADATA_FILE,
    METADATA_VERSION,
    PROFILE,
    RESERVE_FILE,
    ROS_DISTRO,
    SCHEMA_ENCODING,
    BagError,
    QosSpec,
    TopicInfo,
    dump_metadata,
    load_metadata,
    metadata_dict,
    parse_qos,
    qos_to_yaml,
    replay_qos,
)

__all__ = [
    'BagError',
    'BagWriteError',
    'BagWriter',
    'DEFAULT_CHUNK_SIZE',
    'INFINITE_NS',
    'LIBRARY',
    'MESSAGE_ENCODING',
    'METADATA_FILE',
    'METADATA_VERSION',
    'PROFILE',
    'QosSpec',
    'RESERVE_BYTES',
    'RESERVE_FILE',
    'ROS_DISTRO',
    'SCHEMA_ENCODING',
    'TopicInfo',
    'default_bag_name',
    'dump_metadata',
    'load_metadata',
    'metadata_dict',
    'parse_qos',
    'qos_to_yaml',
    'replay_qos',
]

LIBRARY = 'rosbag_mcap/0.1.0 (python mcap writer)'
DEFAULT_CHUNK_SIZE = 768 * 1024  # bytes, the mcap C++ writer's default (rosbag2's)
RESERVE_BYTES = 256 * 1024  # disk space held back to finish a bag when the disk fills up


class BagWriteError(BagError):
    """Writing the bag failed (e.g. the disk is full); nothing more can be written to it."""


# --------------------------------------------------------------------------- writer


@dataclass
class _WriterTopic:
    info: TopicInfo
    channel_id: int


class BagWriter:
    """Writes one bag directory. Not thread-safe: call from one thread (the node's executor).

    ``close()`` finishes the MCAP (summary, indexes, footer) and writes metadata.yaml; it is
    idempotent. ``flush()`` ends the current chunk so that a recording killed without a clean
    close keeps everything written up to the last flush readable.

    A failed write (a full disk, an I/O error) raises :class:`BagWriteError` and ends the
    recording: :attr:`failure` says why and later writes raise at once. ``close()`` then keeps
    what reached the disk: it cuts the MCAP after its last intact record, finishes it (summary,
    footer) and writes metadata.yaml, in the ``reserve`` bytes held back in a placeholder file
    from the start. It raises BagWriteError only if even that is impossible.
    """

    def __init__(
        self,
        directory: str | os.PathLike,
        *,
        compression: str = 'zstd',
        chunk_size: int = DEFAULT_CHUNK_SIZE,
        custom_data: dict[str, str] | None = None,
        reserve: int = RESERVE_BYTES,
    ) -> None:
        self.directory = Path(directory)
        if self.directory.exists() and (
            not self.directory.is_dir() or any(self.directory.iterdir())
        ):
            raise BagError(f'{self.directory}: output exists and is not an empty directory')
        compressions = {
            'zstd': CompressionType.ZSTD,
            'lz4': CompressionType.LZ4,
            'none': CompressionType.NONE,
            '': CompressionType.NONE,
        }
        if compression not in compressions:
            raise BagError(f'unknown chunk compression {compression!r} (zstd, lz4, none)')
        self.directory.mkdir(parents=True, exist_ok=True)
        self.file_name = f'{self.directory.name}_0.mcap'
        self.path = self.directory / self.file_name
        self._custom_data = custom_data
        self._reserve = self.directory / RESERVE_FILE
        self.failure: str | None = None
        self._closed_info: dict | None = None
        try:
            with open(self._reserve, 'wb') as placeholder:
                placeholder.write(bytes(reserve))
        except OSError as exc:
            self._reserve.unlink(missing_ok=True)
            raise BagError(
                f'{self.directory}: cannot reserve {reserve} bytes to finish the bag: '
                f'{exc.strerror or exc}'
            ) from None
        self._stream = open(self.path, 'wb')  # noqa: SIM115 (closed in close())
        self._mcap = Writer(
            self._stream, chunk_size=chunk_size, compression=compressions[compression]
        )
        self._mcap.start(profile=PROFILE, library=LIBRARY)
        self._topics: dict[str, _WriterTopic] = {}
        self._schemas: dict[str, int] = {}
        self._first_ns: int | None = None
        self._last_ns: int | None = None
        self.message_count = 0
        self.closed = False

    @property
    def topics(self) -> dict[str, TopicInfo]:
        return {name: t.info for name, t in self._topics.items()}

    def has_topic(self, name: str) -> bool:
        return name in self._topics

    def add_topic(
        self,
        name: str,
        type_name: str,
        definition: str,
        offered_qos: Sequence[QosSpec] = (),
        type_hash: str = '',
    ) -> None:
        """Register a topic (one channel); its schema is shared by all topics of the type."""
        if name in self._topics:
            raise BagError(f'{self.path}: topic {name} added twice')
        self._check()
        try:
            self._add_topic(name, type_name, definition, offered_qos, type_hash)
        except OSError as exc:
            raise self._fail(exc) from None

    def _add_topic(
        self,
        name: str,
        type_name: str,
        definition: str,
        offered_qos: Sequence[QosSpec],
        type_hash: str,
    ) -> None:
        schema_id = self._schemas.get(type_name)
        if schema_id is None:
            schema_id = self._mcap.register_schema(
                name=type_name, encoding=SCHEMA_ENCODING, data=definition.encode('utf-8')
            )
            self._schemas[type_name] = schema_id
        info = TopicInfo(
            name=name, type=type_name, offered_qos=list(offered_qos), type_hash=type_hash
        )
        channel_id = self._mcap.register_channel(
            topic=name,
            message_encoding=MESSAGE_ENCODING,
            schema_id=schema_id,
            metadata={
                'offered_qos_profiles': qos_to_yaml(info.offered_qos),
                'topic_type_hash': type_hash,
            },
        )
        self._topics[name] = _WriterTopic(info, channel_id)

    def write(
        self,
        topic: str,
        data: bytes,
        log_time: int,
        publish_time: int | None = None,
        sequence: int = 0,
    ) -> None:
        """Append one serialized message (``log_time``/``publish_time`` in ns)."""
        entry = self._topics[topic]
        self._check()
        try:
            self._mcap.add_message(
                channel_id=entry.channel_id,
                log_time=log_time,
                data=data,
                publish_time=log_time if publish_time is None else publish_time,
                sequence=sequence & 0xFFFFFFFF,
            )
        except OSError as exc:
            raise self._fail(exc) from None
        entry.info.message_count += 1
        self.message_count += 1
        if self._first_ns is None or log_time < self._first_ns:
            self._first_ns = log_time
        if self._last_ns is None or log_time > self._last_ns:
            self._last_ns = log_time

    def flush(self) -> None:
        """End the current chunk and hand it to the operating system."""
        if self.closed or self.failure is not None:
            return
        try:
            self._mcap.flush()
        except OSError as exc:
            raise self._fail(exc) from None

    def _check(self) -> None:
        if self.failure is not None:
            raise BagWriteError(self.failure)
        if self.closed:
            raise BagWriteError(f'{self.path}: the bag is closed')

    def _fail(self, exc: OSError) -> BagWriteError:
        if self.failure is None:
            self.failure = f'{self.path}: writing failed: {exc.strerror or exc}'
        return BagWriteError(self.failure)

    def metadata(self) -> dict:
        start = self._first_ns or 0
        files = [
            {
                'path': self.file_name,
                'starting_time': {'nanoseconds_since_epoch': start},
                'duration': {'nanoseconds': (self._last_ns - start) if self._last_ns else 0},
                'message_count': self.message_count,
            }
        ]
        return metadata_dict(
            files=files,
            topics=[t.info for t in self._topics.values()],
            custom_data=self._custom_data,
        )

    def close(self) -> dict:
        """Finish the MCAP and write metadata.yaml; returns the metadata mapping.

        After a write failure the metadata describes what was kept (see the class).
        """
        info = self.metadata()
        if self.closed:
            return self._closed_info or info
        self.closed = True
        if self.failure is None:
            try:
                self._reserve.unlink(missing_ok=True)  # room for the summary
                # As rosbag2_storage_mcap: the BagMetadata mapping itself, without the root key.
                serialized = yaml.safe_dump(
                    info, sort_keys=False, default_flow_style=False, allow_unicode=True, width=1000
                )
                self._mcap.add_metadata('rosbag2', {'serialized_metadata': serialized})
                self._mcap.finish()
                self._stream.close()
                tmp = self.directory / (METADATA_FILE + '.tmp')
                tmp.write_text(dump_metadata(info), encoding='utf-8')
                tmp.replace(self.directory / METADATA_FILE)
                self._closed_info = info
                return info
            except OSError as exc:
                self._fail(exc)
        self._closed_info = self._keep_written_part()
        return self._closed_info

    def _keep_written_part(self) -> dict:
        """After a failed write: make what reached the disk a finished, readable bag."""
        try:
            self._stream.close()  # flushing the rest fails again on a full disk; it is closed
        except OSError:
            pass
        self._reserve.unlink(missing_ok=True)
        (self.directory / (METADATA_FILE + '.tmp')).unlink(missing_ok=True)
        from rosbag_mcap.reindex import repair_file, write_metadata  # needs the reader

        try:
            if self.path.stat().st_size < 16:  # not even the MCAP header reached the disk
                self._write_empty_mcap()
            result, _ = repair_file(self.path)
            return write_metadata(self.directory, [result])
        except (BagError, OSError) as exc:
            raise BagWriteError(
                f'{self.failure}; the bag could not be finished either ({exc}); free some '
                f'space, then run: bag_reindex {self.directory}'
            ) from None

    def _write_empty_mcap(self) -> None:
        with open(self.path, 'wb') as stream:
            writer = Writer(stream)
            writer.start(profile=PROFILE, library=LIBRARY)
            writer.finish()

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def default_bag_name(now: float | None = None) -> str:
    """'rosbag2_YYYY_MM_DD-HH_MM_SS' (rosbag2's default bag directory name), local time."""
    return time.strftime('rosbag2_%Y_%m_%d-%H_%M_%S', time.localtime(now))
